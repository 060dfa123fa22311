"""How long the territory rule lets a target wait on a site: the filter's rule 12 ``auto``
deadline (:mod:`sb3_pm.policies.visit_deadline`).

The territory rule (:mod:`sb3_pm.baselines.territory_patrol`) plays ``episodes`` calibration
episodes on the site with the team's size and environment settings, from env seeds of their own
(apart from the sweeps' evaluation seeds, ``1,000,000 + 1,000 · seed``), and a rule's figure is
the worst ``max_neglect`` among them. It plays on the split (``territory_patrol``) and, for a
team told planned territories, on the team's own groups too (``planned_patrol`` or
``planned_tour_patrol``); the deadline is the lower figure below the episode's length, none where
both are that length (:func:`site_deadline`). A team under it then lets no target wait longer than
the better rule let one, unless two targets of one agent fall due together. The rules read the
site's road network and target list and their own maps, as a team with a known map does; they
read no learned team.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sb3_pm.baselines.territory_patrol import PlannedPatrolTeam, PlannedTourPatrolTeam, TerritoryPatrolTeam
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphLike, resolve_graph

#: Calibration episodes of the territory rule.
CALIBRATION_EPISODES = 10
#: Episode ``e`` of the calibration runs from env seed ``CALIBRATION_SEED + e``: apart from the
#: evaluation seeds of the sweeps, so a setting is never fitted to the episodes it is measured on.
CALIBRATION_SEED = 9_000_000
#: Env settings a calibration leaves out: it is for the team as deployed, not as its agents fail.
NOT_CALIBRATED = ("failures", "failure_rate")


def rule_worst(
    metric: str,
    graph: GraphLike,
    n_agents: int,
    env_kwargs: Mapping[str, Any] | None = None,
    max_cycles: int = 500,
    episodes: int = CALIBRATION_EPISODES,
    seed: int = CALIBRATION_SEED,
    rule: type[TerritoryPatrolTeam] = TerritoryPatrolTeam,
    ceiling: float = float("inf"),
) -> float:
    """The largest episode ``metric`` of ``rule`` over ``episodes`` calibration episodes (at
    least 1), episode ``e`` from env seed ``seed + e``: the loop both calibrations share (rule 12's
    deadline here, rule 8's bound in :mod:`sb3_pm.evaluation.neglect_calibration`).

    :param metric: an episode metric, e.g. ``max_neglect`` or ``peak_uncertainty``.
    :param env_kwargs: the environment settings, passed as they are.
    :param ceiling: the metric's largest possible value: reaching it ends the calibration, since no
        later episode can be worse.
    :raises InputError: for ``episodes < 1``.
    """
    from sb3_pm.envs import persistent_monitoring_v0

    if episodes < 1:
        raise InputError(f"calibration episodes must be at least 1, got {episodes}")
    env = persistent_monitoring_v0.parallel_env(
        graph=resolve_graph(graph), n_agents=n_agents, max_cycles=max_cycles, **dict(env_kwargs or {})
    )
    team, worst = rule(), float("-inf")
    try:
        for episode in range(episodes):
            observations, _ = env.reset(seed=seed + episode)
            team.reset(env, seed=seed + episode)
            while env.agents:
                observations, *_ = env.step(team.predict_dict(observations))
            worst = max(worst, float(env.unwrapped.episode_metrics()[metric]))
            if worst >= ceiling:
                break
    finally:
        env.close()
    return worst


def rule_worst_neglect(
    graph: GraphLike,
    n_agents: int,
    env_kwargs: Mapping[str, Any] | None = None,
    max_cycles: int = 500,
    episodes: int = CALIBRATION_EPISODES,
    seed: int = CALIBRATION_SEED,
    rule: type[TerritoryPatrolTeam] = TerritoryPatrolTeam,
) -> int:
    """The worst ``max_neglect`` of ``rule`` over ``episodes`` episodes (:func:`rule_worst`; at
    least 1).

    :param graph: the site; ``n_agents``: the team size (the rule's groups follow it).
    :param env_kwargs: the deployment's environment settings; agent failures are left out.
    :param rule: ``territory_patrol`` (the default) or one of its planned variants.
    :raises InputError: for ``episodes < 1``.
    """
    kwargs = {key: value for key, value in (env_kwargs or {}).items() if key not in NOT_CALIBRATED}
    worst = rule_worst("max_neglect", graph, n_agents, kwargs, max_cycles, episodes, seed, rule, max_cycles)
    return max(1, int(worst))


def calibration_rules(env_kwargs: Mapping[str, Any] | None = None) -> list[type[TerritoryPatrolTeam]]:
    """The rules ``auto`` calibrates on: ``territory_patrol``, and the same rule on the team's own
    groups where its env is told planned territories (``territories: planned`` or
    ``planned_tours``)."""
    own = (env_kwargs or {}).get("territories", TerritoryPatrolTeam.convention)
    planned = {rule.convention: rule for rule in (PlannedPatrolTeam, PlannedTourPatrolTeam)}
    return [TerritoryPatrolTeam] + ([planned[own]] if own in planned else [])


def site_deadline(
    graph: GraphLike, n_agents: int, env_kwargs: Mapping[str, Any] | None = None, max_cycles: int = 500
) -> int | None:
    """``visit_deadline: auto`` on a site: the lowest :func:`rule_worst_neglect` of the
    :func:`calibration_rules` below the episode's length, or ``None`` (no deadline) where each rule
    left some target unvisited for a whole calibration episode: a deadline of the episode's length
    asks for nothing, as the neglect bound's ``auto`` deploys no bound where the rule let a target
    reach ``u_max``."""
    worst = [
        rule_worst_neglect(graph, n_agents, env_kwargs, max_cycles, rule=rule)
        for rule in calibration_rules(env_kwargs)
    ]
    below = [value for value in worst if value < max_cycles]
    return min(below) if below else None


__all__ = [
    "CALIBRATION_EPISODES",
    "CALIBRATION_SEED",
    "NOT_CALIBRATED",
    "calibration_rules",
    "rule_worst",
    "rule_worst_neglect",
    "site_deadline",
]
