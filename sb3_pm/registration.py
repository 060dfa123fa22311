"""Gymnasium ids for the single-agent view: after ``import sb3_pm``, ``gym.make`` builds it by name.

Registered ids (namespace ``sb3_pm``)::

    sb3_pm/PersistentMonitoring-v0            graph given by the ``graph=`` kwarg (default paper-50)
    sb3_pm/PersistentMonitoring-paper50-v0    the paper-50 preset (the paper's published 50-node graph)
    sb3_pm/PersistentMonitoring-paper100-v0   the paper-100 preset
    sb3_pm/PersistentMonitoring-paper200-v0   the paper-200 preset

Each id is a :class:`~sb3_pm.envs.single_agent.SingleAgentMonitoringEnv`: one learner (``agent``,
default ``agent_0``) with its mental-map ``Dict`` observation and ``Discrete(N)`` actions, and
``action_masks()`` for sb3-contrib's MaskablePPO. The other agents are driven by a fixed team::

    gym.make("sb3_pm/PersistentMonitoring-paper50-v0")                        # random teammates
    gym.make("sb3_pm/PersistentMonitoring-paper50-v0", teammates="local_greedy", n_agents=6)
    gym.make("sb3_pm/PersistentMonitoring-v0", graph="my_graph.graphml", max_cycles=200)
    gym.make("sb3_pm/PersistentMonitoring-paper50-v0", teammates="runs/my_team")  # a saved team

``teammates`` is a baseline name (:data:`sb3_pm.baselines.BASELINES`), the folder of a saved
trained team, a :class:`~sb3_pm.team_interface.Team` instance, or ``None`` (uniform random moves
inside each teammate's reachable set; the same as ``"random"`` in spirit, without a Team object).
A saved team brings its own team size and env options (observation radius, reward, ...), which
explicit keyword arguments override. Every other keyword is an argument of the environment
(:mod:`sb3_pm.envs.persistent_monitoring`).

Episode length: the env truncates by itself after ``max_cycles`` steps (``truncated=True``), so
the specs carry no ``max_episode_steps`` and ``gym.make`` adds no ``TimeLimit``: a registered
step limit would disagree with ``max_cycles=...`` passed at make time and cut episodes early.

This module imports neither torch nor the environment: the ids point at
:func:`make_single_agent_env` by its ``"module:function"`` string, loaded on the first ``gym.make``.
It sits at the top of the package, beside ``sb3_pm/__init__.py``, because resolving
``teammates`` reaches every layer up to evaluation (baselines by name, saved trained teams).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: Gymnasium namespace of every id registered here.
NAMESPACE = "sb3_pm"
#: The entry point of every id (a string, so that registering imports nothing heavy).
ENTRY_POINT = "sb3_pm.registration:make_single_agent_env"
#: Registered id -> the graph it defaults to.
ENV_IDS: dict[str, str] = {
    f"{NAMESPACE}/PersistentMonitoring-v0": "paper-50",
    f"{NAMESPACE}/PersistentMonitoring-paper50-v0": "paper-50",
    f"{NAMESPACE}/PersistentMonitoring-paper100-v0": "paper-100",
    f"{NAMESPACE}/PersistentMonitoring-paper200-v0": "paper-200",
}
#: The teammates a made env gets when ``teammates`` is not given.
DEFAULT_TEAMMATES = "random"


def make_single_agent_env(
    graph: Any = "paper-50",
    teammates: Any = DEFAULT_TEAMMATES,
    agent: str = "agent_0",
    **env_kwargs: Any,
) -> Any:
    """The entry point of the registered ids: a single-agent view with ``teammates`` resolved.

    :param graph: a preset name, a ``.graphml`` path or a :class:`~sb3_pm.graphs.GraphSpec`.
    :param teammates: a baseline name, a saved team's folder, a ``Team`` or ``None`` (see the
        module docstring).
    :param agent: the learner, ``agent_i``.
    :param env_kwargs: arguments of :class:`~sb3_pm.envs.single_agent.SingleAgentMonitoringEnv`
        (``n_agents``, ``max_cycles``, ``reward``, ``render_mode`` ...).
    :raises ValueError: for an unknown baseline name or an unloadable team folder.
    """
    from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
    from sb3_pm.evaluation.teams import resolve_team
    from sb3_pm.team_interface import Team

    team: Team | None
    if teammates is None or isinstance(teammates, Team):
        team = teammates
    elif isinstance(teammates, (str, Path)):
        # Baselines by name; anything else is a saved team, checked against this graph on load.
        team = resolve_team(teammates, graph=graph)
        if team.n_agents is not None:
            # A trained team fixes the team size and its training env options; the caller's
            # explicit kwargs still win (a mismatch then fails loudly in the team's checks).
            env_kwargs = {"n_agents": int(team.n_agents), **team.env_settings(), **env_kwargs}
    else:
        raise TypeError(
            "teammates must be a baseline name, a saved team folder, a Team or None; "
            f"got {type(teammates).__name__}"
        )
    return SingleAgentMonitoringEnv(graph=graph, agent=agent, teammates=team, **env_kwargs)


# gym.make reads the creator's metadata to validate render_mode; mirror the env's own.
make_single_agent_env.metadata = {  # type: ignore[attr-defined]
    "render_modes": ["human", "rgb_array", "ansi"],
    "render_fps": 4,
}


def register_envs() -> list[str]:
    """Register every id of :data:`ENV_IDS` with Gymnasium (idempotent); return the ids.

    Called by ``import sb3_pm``. Re-registering an id that already points at our entry point is
    skipped, so reloading the package does not trigger Gymnasium's "overriding" warning.
    """
    import gymnasium as gym

    for env_id, graph in ENV_IDS.items():
        existing = gym.envs.registry.get(env_id)
        if existing is not None and existing.entry_point == ENTRY_POINT:
            continue
        gym.register(
            id=env_id,
            entry_point=ENTRY_POINT,
            kwargs={"graph": graph},
            max_episode_steps=None,  # the env truncates at max_cycles itself (module docstring)
            # The env decides by itself when an episode ends, and its mask-based API is checked by
            # SB3's check_env in the tests; Gymnasium's passive checker stays on (default).
        )
    return list(ENV_IDS)


__all__ = [
    "DEFAULT_TEAMMATES",
    "ENTRY_POINT",
    "ENV_IDS",
    "NAMESPACE",
    "make_single_agent_env",
    "register_envs",
]
