"""``optimal_planner``: the best centralized schedule the library finds (docs/PLANNING.md).

An omniscient, centralized team. At every reset it reads the episode's start positions and
uncertainties, plans with :func:`sb3_pm.planning.team_plan.plan_team` (groups of targets per
agent, matched to the agents by the Hungarian method, improved by local search, exact schedules
for two-target groups, refined by joint simulation) and tries openings
(:func:`sb3_pm.planning.openings.plan_with_openings`: the first two steps played exactly, then a
fresh plan), then acts each step by the plan with the true uncertainties. Its
``avg_uncertainty`` is an upper bound on the optimum; ``sb3-pm bound`` gives the lower one.

A planner that scores worse than ``territory_patrol`` would be a bug of the search, not a fact
about the site, so at an episode's first step the planner also plays ``territory_patrol`` on a copy
of the env and, where the rule scores lower, acts as the rule for that episode (``acting``). The
comparison is skipped where it would compare unlike things: with agent failures configured (the
plan assumes every agent lasts, and it does not re-plan after a failure) and without map
observations (the rule reads them).

It is the reference an optimality gap is measured against, not a deployable team: it reads the
whole state and needs the episode's starts before the first step.
"""

from __future__ import annotations

import copy
from typing import Any

from sb3_pm.baselines._common import agent_positions, env_graph
from sb3_pm.baselines.territory_patrol import TerritoryPatrolTeam
from sb3_pm.errors import InputError
from sb3_pm.planning.openings import plan_with_openings
from sb3_pm.planning.planner import DEFAULT_SEARCH_SECONDS
from sb3_pm.planning.team_plan import TeamPlan
from sb3_pm.team_interface import Observation, Team

#: The largest site the planner acts on: its schedules and openings read the ``(N, N)`` tables,
#: which above this size take gigabytes (a 5,000-node site passed 10 GB). The groups alone scale:
#: ``planned_patrol`` plans them on the large sites.
MAX_PLANNER_NODES = 2_000


class OptimalPlannerTeam(Team):
    """Centralized planning on the true state.

    :param search_seconds: the plan search's wall-clock budget per episode (the openings take half
        as much again).
    """

    name = "optimal_planner"
    omniscient = True

    def __init__(self, search_seconds: float = DEFAULT_SEARCH_SECONDS) -> None:
        if search_seconds <= 0:
            raise InputError(f"search_seconds must be positive, got {search_seconds}")
        self.search_seconds = float(search_seconds)

    def reset(self, env: Any, seed: int | None = None) -> None:
        super().reset(env, seed)
        state = env.unwrapped
        graph = env_graph(env)
        if graph.n_nodes > MAX_PLANNER_NODES:
            raise InputError(
                f"optimal_planner plans on sites of up to {MAX_PLANNER_NODES} nodes and {graph.name} has "
                f"{graph.n_nodes}: use planned_patrol, whose plan of groups scales"
            )
        self.plan: TeamPlan = plan_with_openings(
            graph, state.positions, state.max_cycles, state.u_max, state.uncertainty, self.search_seconds
        )
        distances = graph.hop_distances.astype(int).tolist()
        next_hop = graph.next_hop.astype(int).tolist()
        self._controllers = self.plan.controllers(distances, next_hop)
        self._index = {agent: i for i, agent in enumerate(state.possible_agents)}
        #: ``"plan"``, or ``"territory_patrol"`` where the rule scores lower on this episode (decided
        #: at the first step, from the observations the rule reads)
        self.acting = "plan"
        self._rule: TerritoryPatrolTeam | None = None
        self._rule_checked = False
        self._seed = seed

    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        state = self.env.unwrapped
        if not self._rule_checked:
            self._rule_checked = True
            # The plan's score assumes no agent fails, and the rule reads map observations: compare
            # only where both hold.
            comparable = state.observation_mode == "map" and not (state.failures or state.failure_rate > 0)
            if (
                comparable
                and state.step_count == 0
                and _territory_patrol_score(self.env, observations, self._seed) < self.plan.simulated
            ):
                self.acting, self._rule = "territory_patrol", TerritoryPatrolTeam()
                self._rule.reset(self.env, self._seed)
        if self._rule is not None:
            return self._rule.predict_dict(observations, deterministic)
        uncertainty = state.uncertainty
        remaining = state.max_cycles - state.step_count
        agents, positions = agent_positions(observations)
        return {
            agent: int(self._controllers[self._index[agent]].move(int(position), uncertainty, remaining))
            for agent, position in zip(agents, positions)
        }


def _territory_patrol_score(env: Any, observations: dict[str, Observation], seed: int | None) -> float:
    """``territory_patrol``'s ``avg_uncertainty`` from the env's current state (an episode's
    start, with these observations), played on a copy of the env."""
    trial = copy.deepcopy(env)
    trial.unwrapped.render_mode = None  # the trial must not draw
    rule = TerritoryPatrolTeam()
    rule.reset(trial, seed)
    observations = copy.deepcopy(observations)
    while trial.agents:
        observations, *_ = trial.step(rule.predict_dict(observations))
    return float(trial.unwrapped.episode_metrics()["avg_uncertainty"])
