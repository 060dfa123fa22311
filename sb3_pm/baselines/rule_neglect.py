"""How long the territory rule lets a target wait on a site: the filter's rule 12 ``auto``
deadline (:mod:`sb3_pm.policies.visit_deadline`).

``territory_patrol`` (:mod:`sb3_pm.baselines.territory_patrol`) plays ``episodes`` calibration
episodes on the site with the team's size and environment settings, from env seeds of their own
(apart from the sweeps' evaluation seeds, ``1,000,000 + 1,000 · seed``), and the deadline is the
worst ``max_neglect`` among them; none where that is the episode's length
(:func:`site_deadline`). A team under it then lets no target wait longer than the rule let
one, unless two targets of one agent fall due together. The rule reads the site's road network and
target list and its own map, as a team with a known map does; it reads no learned team.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sb3_pm.baselines.territory_patrol import TerritoryPatrolTeam
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphLike, resolve_graph

#: Calibration episodes of the territory rule.
CALIBRATION_EPISODES = 10
#: Episode ``e`` of the calibration runs from env seed ``CALIBRATION_SEED + e``: apart from the
#: evaluation seeds of the sweeps, so a setting is never fitted to the episodes it is measured on.
CALIBRATION_SEED = 9_000_000
#: Env settings a calibration leaves out: it is for the team as deployed, not as its agents fail.
NOT_CALIBRATED = ("failures", "failure_rate")


def rule_worst_neglect(
    graph: GraphLike,
    n_agents: int,
    env_kwargs: Mapping[str, Any] | None = None,
    max_cycles: int = 500,
    episodes: int = CALIBRATION_EPISODES,
    seed: int = CALIBRATION_SEED,
) -> int:
    """The worst ``max_neglect`` of ``territory_patrol`` over ``episodes`` episodes (at least 1).

    :param graph: the site; ``n_agents``: the team size (the rule's split follows it).
    :param env_kwargs: the deployment's environment settings; agent failures are left out.
    :raises InputError: for ``episodes < 1``.
    """
    from sb3_pm.envs import persistent_monitoring_v0

    if episodes < 1:
        raise InputError(f"calibration episodes must be at least 1, got {episodes}")
    kwargs = {key: value for key, value in (env_kwargs or {}).items() if key not in NOT_CALIBRATED}
    env = persistent_monitoring_v0.parallel_env(
        graph=resolve_graph(graph), n_agents=n_agents, max_cycles=max_cycles, **kwargs
    )
    rule, worst = TerritoryPatrolTeam(), 1
    try:
        for episode in range(episodes):
            observations, _ = env.reset(seed=seed + episode)
            rule.reset(env, seed=seed + episode)
            while env.agents:
                observations, *_ = env.step(rule.predict_dict(observations))
            worst = max(worst, int(env.unwrapped.episode_metrics()["max_neglect"]))
            if worst >= max_cycles:  # a target never visited: no later episode can be worse
                break
    finally:
        env.close()
    return worst


def site_deadline(
    graph: GraphLike, n_agents: int, env_kwargs: Mapping[str, Any] | None = None, max_cycles: int = 500
) -> int | None:
    """``visit_deadline: auto`` on a site: :func:`rule_worst_neglect`, or ``None`` (no deadline)
    where the rule left some target unvisited for a whole calibration episode: a deadline of the
    episode's length asks for nothing, as the neglect bound's ``auto`` deploys no bound where the
    rule let a target reach ``u_max``."""
    worst = rule_worst_neglect(graph, n_agents, env_kwargs, max_cycles)
    return None if worst >= max_cycles else worst


__all__ = [
    "CALIBRATION_EPISODES",
    "CALIBRATION_SEED",
    "NOT_CALIBRATED",
    "rule_worst_neglect",
    "site_deadline",
]
