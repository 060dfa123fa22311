"""``territory_patrol``: each agent keeps to its own territory's targets (docs/METHOD.md "Baselines").

Territories are the fixed, balanced split of the targets among the agents that every agent derives
from the site and its own index (:mod:`sb3_pm.graphs.territories`); agent ``agent_i`` owns
territory ``i``. No agent reads another's state and nothing is communicated: the split is a
convention fixed before the mission, so the team is not ``omniscient``.

Rule, per agent and step, on the agent's own view:

1. On one of its targets whose observed ``u`` is positive: dwell.
2. Else keep heading for the goal chosen earlier until it is reached; otherwise choose, among its
   territory's other targets, the one with the highest own-map estimate ``min(u_last + age, u_max)``
   (``u`` grows by at most one per unobserved step; ties: nearest, then lowest index) and take one
   step along a shortest path of the site's road network.
3. An agent whose territory holds one target stays there once it has arrived; an agent with no
   territory (fewer targets than agents) acts as ``local_greedy`` does.

Without a teammate's territory in its rule, an agent leaves a failed teammate's targets to nobody.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_pm.baselines._common import env_graph, nearest_first, own_uncertainty
from sb3_pm.baselines.local_greedy import LocalGreedyTeam
from sb3_pm.envs.mental_map import AGE, U
from sb3_pm.errors import InputError
from sb3_pm.graphs.territories import target_territories
from sb3_pm.team_interface import Observation, Team


class TerritoryPatrolTeam(Team):
    """Each agent patrols the targets of its own territory, most stale first; decentralized."""

    name = "territory_patrol"
    omniscient = False

    def __init__(self) -> None:
        self._fallback = LocalGreedyTeam()
        #: ``(graph fingerprint, team size)`` -> each target's territory (the split depends on nothing
        #: else, so it is computed once per graph, as ``tour_patrol`` caches its tour).
        self._owners: dict[tuple[str, int], np.ndarray] = {}

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self._fallback.reset(env, seed)
        graph = env_graph(env)
        agents = list(env.unwrapped.possible_agents)
        key = (graph.fingerprint, len(agents))
        if key not in self._owners:
            self._owners[key] = target_territories(graph.hop_distances, graph.target_indices, len(agents))
        owner = self._owners[key]
        #: Each agent's own targets, ``(T_i,)`` int node indices.
        self.territory = {agent: graph.target_indices[owner == i] for i, agent in enumerate(agents)}
        self.distances = graph.hop_distances
        self.next_hop = graph.next_hop
        self.u_max = float(env.unwrapped.u_max)
        self._goals: dict[str, int] = {}

    def act(self, agent: str, obs: Observation) -> int:
        """One agent's destination from its own observation."""
        if "nodes" not in obs:
            raise InputError(
                "territory_patrol needs mental-map observations: create the env with observation='map'"
            )
        own = self.territory[agent]
        if own.size == 0:
            return self._fallback.act(agent, obs)
        position = int(obs["position"])
        if position in own and own_uncertainty(obs, position) > 0:
            self._goals.pop(agent, None)
            return position
        goal = self._goals.get(agent)
        if goal is None or goal == position:
            others = own[own != position]
            if others.size == 0:
                return position  # a territory of one target: hold it
            nodes = np.asarray(obs["nodes"])
            estimate = np.minimum(nodes[:, U] + nodes[:, AGE], self.u_max)
            goal = int(nearest_first(others, self.distances[position], estimate)[0])
            self._goals[agent] = goal
        return int(self.next_hop[position, goal])

    def predict(self, observations: dict[str, Observation], deterministic: bool = True) -> dict[str, int]:
        return {agent: self.act(agent, obs) for agent, obs in observations.items()}
