"""``tour_patrol``: agents spread along one closed tour of the targets (docs/METHOD.md "Baselines").

The tour is an approximate travelling-salesman tour of the targets on hop distances: a
nearest-neighbour tour from the lowest-index target, improved by 2-opt until no reversal
shortens it. It depends on the graph only, so it is computed once per graph and cached.

At the first :meth:`predict_dict` of an episode the agents are spread evenly: the tour is cut into
``n_agents`` equally spaced slots (slot ``j`` at tour position ``floor(j * T / n)``), and agents
are matched to slots minimizing the total hop distance (``scipy.optimize.linear_sum_assignment``).
Then every agent walks the tour in the same direction: shortest path to its next tour target,
dwell there while the ``u`` it observes on its own node is positive, then move on to the next
one. The dwell test reads the agent's own observation, not the true state; positions come from
the observations too, so the team is not ``omniscient`` (the spreading step is one coordinated
assignment before the episode, as in ``sit_on_nodes``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from sb3_pm.baselines._common import agent_positions, env_graph, own_uncertainty
from sb3_pm.graphs import GraphSpec
from sb3_pm.graphs.tours import approximate_tour
from sb3_pm.team_interface import Observation, Team


class TourPatrolTeam(Team):
    """Agents evenly spaced on one target tour, all walking it the same way."""

    name = "tour_patrol"
    omniscient = False

    def __init__(self) -> None:
        self._tours: dict[str, np.ndarray] = {}

    def tour_for(self, graph: GraphSpec) -> np.ndarray:
        """The cached tour of ``graph``'s targets."""
        key = graph.fingerprint
        if key not in self._tours:
            # the tour of the targets' rows of the (T, T) distances: no all-pairs table on a large site
            rows = approximate_tour(np.arange(graph.n_targets), graph.routes.between_targets())
            self._tours[key] = graph.target_indices[rows]
        return self._tours[key]

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self.graph = env_graph(env)
        self.tour = self.tour_for(self.graph)
        self.pointer: dict[str, int] | None = None  # index into the tour of each agent's next target

    def spread(self, agents: list[str], positions: np.ndarray) -> dict[str, int]:
        """Match agents to evenly spaced tour slots, minimizing the total hop distance."""
        t, n = len(self.tour), len(agents)
        slots = (np.arange(n) * t) // n
        columns = np.searchsorted(self.graph.target_indices, self.tour[slots])  # the slots' targets
        cost = self.graph.routes.to_targets(positions)[:, columns]
        rows, cols = linear_sum_assignment(cost)
        return {agents[r]: int(slots[c]) for r, c in zip(rows, cols)}

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        agents, positions = agent_positions(observations)
        if self.pointer is None:
            self.pointer = self.spread(agents, positions)
        actions: dict[str, int] = {}
        for agent, position in zip(agents, positions):
            goal = int(self.tour[self.pointer[agent]])
            if position == goal:
                if own_uncertainty(observations[agent], position) > 0:
                    actions[agent] = int(position)  # dwell until the target is clean
                    continue
                self.pointer[agent] = (self.pointer[agent] + 1) % len(self.tour)
                goal = int(self.tour[self.pointer[agent]])
            actions[agent] = self.graph.routes.next_hop(int(position), goal)
        return actions
