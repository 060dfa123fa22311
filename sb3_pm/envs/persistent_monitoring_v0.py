"""Persistent monitoring on a graph, version 0 (PettingZoo parallel API).

``n_agents`` agents move along the edges of an undirected, connected graph. Some nodes are
targets; a target's uncertainty ``u`` grows by one each step nobody is on it and falls by one
each step somebody is (docs/METHOD.md "Dynamics", the paper's eq. 1), capped at ``u_max``. Agents see
only their own neighbourhood and never communicate.

Usage::

    from sb3_pm.envs import persistent_monitoring_v0
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4)
    observations, infos = env.reset(seed=0)

Arguments
---------
graph (``"paper-50"``)
    A preset name (``paper-50``, ``paper-100``, ``paper-200``: the paper's published graphs;
    ``er-50``, ``er-100``, ``er-200``: seeded Erdős–Rényi draws), a ``.graphml`` path, or a
    :class:`~sb3_pm.graphs.GraphSpec`.
n_agents (``4``)
    Team size, at most the number of nodes. Agents are named ``agent_0 ... agent_{n-1}``.
max_cycles (``500``)
    Episode length K. Episodes end by truncation after K steps, never by termination.
u_max (``100``)
    Cap on every target's uncertainty.
obs_radius (``1``)
    An agent observes the nodes within this many hops of its node (their ``u``, target flag and
    whether another agent is there) and the edges incident to nodes strictly inside that ball
    (radius 1: the edges at its own node).
initial_positions (``None``)
    A list of ``n_agents`` nodes; ``None`` draws distinct nodes uniformly from the reset seed.
    ``reset(options={"initial_positions": [...]})`` overrides it for one episode.
    ``reset(options={"new_lifetime": True})`` also forgets every map's discovered edges and the
    ``change`` reward's past episodes, as if the agents were new.
initial_uncertainty (``"zero"``)
    ``"zero"`` or ``"random"`` (uniform integers in ``[0, u_max]`` on targets, from the seed).
reward (``"paper"``)
    A preset (``"paper"``: eq. 5-8; ``"reduction"``) or a ``{term: weight}`` mapping over the
    terms ``collision``, ``momentum``, ``change``, ``reduction``, ``clearing`` (see
    :mod:`sb3_pm.envs.rewards`).
observation (``"map"``)
    ``"map"``: each agent's mental map (what learners and decentralized baselines use);
    ``"local"``: only this step's raw local observation.
graph_knowledge (``"discovered"``)
    ``"discovered"``: a map's adjacency gains edges as its agent observes them and keeps them for
    the environment's lifetime; ``"known"``: the whole topology is known from the start.
illegal_action (``"raise"``)
    ``"raise"``: a move outside the reachable set raises ``ValueError`` naming the agent, its node
    and the reachable set; ``"stay"``: the agent stays and ``infos[agent]["illegal_action"]``
    records the request.
shared_map (``False``)
    ``True`` feeds every agent's mental map with the union of all agents' observations: the
    *centralized* setting (docs/METHOD.md "Baselines": centralized). Never used by decentralized teams.
render_mode (``None``)
    ``"rgb_array"`` (a matplotlib frame), ``"human"`` (a window) or ``"ansi"`` (text).

Spaces
------
Action: ``Discrete(N)``, the destination node; legal destinations are the agent's node and its
neighbours, given by ``obs["action_mask"]``.

Observation with ``observation="map"`` (a ``Dict``):

``nodes``        ``Box(N, 5) float32``: per node ``[u, age, target, occupied, self]`` from the mental
                 map (:mod:`sb3_pm.envs.mental_map`).
``adjacency``    ``Box(N, N) int8``: the known adjacency.
``position``     ``Discrete(N)``: the agent's node.
``dwell``        ``Box(1,) float32``: steps the agent has stayed on its node (0 on arrival).
``action_mask``  ``Box(N,) int8``: 1 on the reachable set.

Observation with ``observation="local"``: ``position``; ``observed``, ``target``, ``occupied`` and
``action_mask`` as ``Box(N,) int8``; ``uncertainty`` as ``Box(N,) float32`` (0 where unobserved);
``edges`` as ``Box(N, N) int8``.

Rewards are per agent (see :mod:`sb3_pm.envs.rewards`). When an episode ends, every agent's info
holds ``"metrics"``: ``avg_uncertainty``, ``max_neglect``, ``collisions``, ``peak_uncertainty``,
``saturated_fraction``, ``idle_fraction`` and ``steps`` (:mod:`sb3_pm.envs.metrics`);
``env.episode_metrics()`` returns them at any time. ``env.unwrapped.uncertainty`` and
``env.unwrapped.positions`` expose the true state for tests and omniscient baselines.

Version history
---------------
v0: first release.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv

raw_env = PersistentMonitoringEnv


def parallel_env(**kwargs: Any) -> PersistentMonitoringEnv:
    """The environment with the parallel API (every agent acts each step)."""
    return PersistentMonitoringEnv(**kwargs)


def env(**kwargs: Any) -> Any:
    """The environment with the AEC API (agents act in turn), order-enforced."""
    return wrappers.OrderEnforcingWrapper(parallel_to_aec(PersistentMonitoringEnv(**kwargs)))


__all__ = ["env", "parallel_env", "raw_env"]
