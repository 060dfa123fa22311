"""``grazing``: omniscient greedy patrol (docs/METHOD.md "Baselines", the paper's §IV.C).

Every step, with the true uncertainties and all positions read through ``env.unwrapped``:

* an agent on a target with ``u > 0`` dwells there;
* an agent that still has a goal (a target it is walking to) keeps walking to it;
* any other agent picks the target with the highest ``u`` among those no other agent occupies or
  is heading to (ties: nearest in hops, then lowest index), and takes the next step of a shortest
  path to it. Agents choose in agent order, so later agents see earlier agents' new goals.

Goals are kept until reached (option ``commit=True``) because re-targeting every step lets two
agents trade goals back and forth as the ``u`` ranking shifts; ``commit=False`` re-plans every
step, the literal reading of the paper. An agent with no free target stays where it is.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_pm.baselines._common import agent_positions, env_graph, nearest_target
from sb3_pm.team_interface import Observation, Team


class GrazingTeam(Team):
    """Greedy on the true global state.

    :param commit: keep a goal until reaching it (default) instead of re-planning every step.
    """

    name = "grazing"
    omniscient = True

    def __init__(self, commit: bool = True) -> None:
        self.commit = commit

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        self.graph = env_graph(env)
        self.goals: dict[str, int] = {}

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        state = self.env.unwrapped
        u = state.uncertainty
        # Agents that failed (the env's ``failures``) stand nowhere, and their goals are free again.
        active = getattr(state, "active", None)
        all_positions = state.positions if active is None else state.positions[active]
        agents, positions = agent_positions(observations)
        if active is not None and not active.all():
            live = set(state.agents)
            self.goals = {a: g for a, g in self.goals.items() if a in live}
        targets = self.graph.target_indices
        is_target = self.graph.targets
        if not self.commit:
            self.goals = {}
        # Occupancy by *other* agents, for every agent of the team (not only those asked here).
        counts = np.bincount(all_positions, minlength=self.graph.n_nodes)
        actions: dict[str, int] = {}
        for agent, position in zip(agents, positions):
            goal = self.goals.get(agent)
            if goal == position:  # arrived: the goal is fulfilled, dwelling takes over
                goal = None
            if is_target[position] and u[position] > 0:
                self.goals.pop(agent, None)
                actions[agent] = int(position)
                continue
            if goal is None:
                counts[position] -= 1
                taken = {g for a, g in self.goals.items() if a != agent}
                free = targets[(counts[targets] == 0) & (targets != position)]
                free = np.array([t for t in free if int(t) not in taken], dtype=np.int64)
                counts[position] += 1
                if len(free) == 0:
                    self.goals.pop(agent, None)
                    actions[agent] = int(position)
                    continue
                goal = nearest_target(self.graph.routes, int(position), free, u.astype(float))
            self.goals[agent] = goal
            actions[agent] = self.graph.routes.next_hop(int(position), goal)
        return actions
