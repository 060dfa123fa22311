"""``sit_on_nodes``: go to the nearest unclaimed target and stay there (docs/METHOD.md "Baselines").

Claims are made once per episode, at the first :meth:`predict_dict` after :meth:`reset`, in agent
order: each agent claims the nearest (in hops) target that no earlier agent has claimed, ties
going to the lower node index. An agent left without a free target (more agents than targets)
claims the nearest target anyway, so it still sits on one.

Decision (documented in the README): the claim step pools the agents' *start positions*, one
coordinated assignment made before the episode starts, as a dispatcher would. It reads no true
state through the env (only the static topology) and never coordinates again, so the team is
not ``omniscient``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_pm.baselines._common import agent_positions, env_graph, nearest_target
from sb3_pm.team_interface import Observation, Team


class SitOnNodesTeam(Team):
    """Each agent walks a shortest path to its claimed target, then stays there forever."""

    name = "sit_on_nodes"
    omniscient = False

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self.graph = env_graph(env)
        self.claims: dict[str, int] | None = None

    def claim(self, agents: list[str], positions: np.ndarray) -> dict[str, int]:
        """Assign one target per agent, greedily in agent order."""
        targets = self.graph.target_indices
        free = np.ones(len(targets), dtype=bool)
        claims: dict[str, int] = {}
        for agent, position in zip(agents, positions):
            pool = targets[free] if free.any() else targets
            choice = nearest_target(self.graph.routes, int(position), pool)
            claims[agent] = choice
            free &= targets != choice
        return claims

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        agents, positions = agent_positions(observations)
        if self.claims is None:
            self.claims = self.claim(agents, positions)
        goals = [self.claims[a] for a in agents]
        routes = self.graph.routes  # the claims are targets: no all-pairs table on a large site
        return {agent: routes.next_hop(int(p), goal) for agent, p, goal in zip(agents, positions, goals)}
