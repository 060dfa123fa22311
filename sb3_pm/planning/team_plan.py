"""From a plan of groups to the team's controllers, refined by joint simulation (docs/PLANNING.md).

:func:`~sb3_pm.planning.planner.plan_patrol` prices each agent alone on its group. Acting together,
agents also cross each other's targets, and a crossing early in an episode lowers a target's
``u`` for good. So the plan is turned into controllers and refined jointly:

1. a two-target group takes its exact schedule (:class:`~sb3_pm.planning.pair_schedule.PairSchedule`)
   where that prices below the group rule;
2. each agent in turn may first walk through another target on its way (a waypoint costing at most
   one extra step), kept when the whole team's simulated ``avg_uncertainty`` falls.

The team's figure is the joint simulation's, which equals the env's replay.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec
from sb3_pm.planning.controllers import (
    Controller,
    GroupController,
    OpeningController,
    PairController,
    ViaController,
    simulate,
)
from sb3_pm.planning.group_patrol import solo_cost
from sb3_pm.planning.pair_schedule import MAX_PATH_HOPS, PairSchedule
from sb3_pm.planning.planner import DEFAULT_SEARCH_SECONDS, PatrolPlan, plan_both_ways, uncertainty_at_reset

__all__ = ["AgentOrders", "TeamPlan", "plan_team"]

#: The most extra steps a waypoint may add to an agent's walk to its group.
WAYPOINT_SLACK = 1


@dataclass(frozen=True)
class AgentOrders:
    """What one agent does: its group (in its rule's order), its group rule, whether it follows the
    exact pair schedule instead, and the waypoints of its walk there."""

    group: tuple[int, ...]
    rule: str = "stalest"
    exact_pair: bool = False
    entry_node: int | None = None
    waypoints: tuple[int, ...] = ()


@dataclass
class TeamPlan:
    """A plan ready to act: each agent's orders and the team's simulated ``avg_uncertainty``."""

    orders: list[AgentOrders]
    dropped: tuple[int, ...]
    simulated: float
    groups_plan: PatrolPlan
    schedules: dict[tuple[int, int], PairSchedule] = field(default_factory=dict)
    #: ``(steps, n)`` nodes every agent moves to first, before its orders (``None``: none); the
    #: orders were then planned from where the opening ends (:mod:`sb3_pm.planning.openings`)
    opening: np.ndarray | None = None

    def controllers(self, distances: list[list[int]], next_hop: list[list[int]]) -> list[Controller]:
        """Fresh controllers for an episode (they keep state, so one set per run)."""
        made: list[Controller] = []
        for orders in self.orders:
            acting: Controller
            if orders.exact_pair:
                acting = PairController(self.schedules[orders.group], orders.entry_node)  # type: ignore[index]
            else:
                acting = GroupController(orders.group, distances, next_hop, orders.rule)
            made.append(ViaController(orders.waypoints, acting, next_hop) if orders.waypoints else acting)
        if self.opening is not None:
            made = [OpeningController(self.opening[:, agent], then) for agent, then in enumerate(made)]
        return made


def plan_team(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
    search_seconds: float = DEFAULT_SEARCH_SECONDS,
) -> TeamPlan:
    """The best team plan found for one episode (arguments as :func:`~sb3_pm.planning.planner.plan_patrol`).

    The groups are searched twice, each search with a quarter of ``search_seconds``: pricing each
    group by the cheaper of its rules, and by the ``stalest`` rule alone (the planned convention's
    search, which lands in other local optima); the lower prediction is refined, with the first
    on a tie. The joint refinement gets the rest of the time."""
    if search_seconds <= 0:
        raise InputError(f"search_seconds must be positive, got {search_seconds}")
    starts = np.asarray(starts, dtype=np.int64)
    initial = uncertainty_at_reset(graph, initial_uncertainty)
    deadline = time.monotonic() + search_seconds
    groups_plan = plan_both_ways(graph, starts, max_cycles, u_max, initial, search_seconds / 4)
    distances = graph.hop_distances.astype(np.int64).tolist()
    next_hop = graph.next_hop.astype(np.int64).tolist()
    schedules: dict[tuple[int, int], PairSchedule] = {}
    orders: list[AgentOrders] = []
    for start, group, rule in zip(starts.tolist(), groups_plan.groups, groups_plan.rules):
        orders.append(AgentOrders(group, rule))
        if len(group) != 2 or distances[group[0]][group[1]] > MAX_PATH_HOPS:
            continue
        schedule = PairSchedule(
            graph.hop_distances, graph.next_hop, group[0], group[1], max_cycles, u_max, True
        )
        exact, entry = schedule.entry(start, int(initial[group[0]]), int(initial[group[1]]))
        greedy = solo_cost(
            start, group, [int(initial[t]) for t in group], max_cycles, u_max, distances, next_hop
        )
        if exact < greedy:
            schedules[group] = schedule
            orders[-1] = AgentOrders(group, exact_pair=True, entry_node=entry)
    plan = TeamPlan(orders, groups_plan.dropped, 0.0, groups_plan, schedules)

    def price(candidate: list[AgentOrders]) -> float:
        trial = TeamPlan(candidate, plan.dropped, 0.0, groups_plan, schedules)
        return simulate(
            trial.controllers(distances, next_hop), starts, graph.target_indices, initial, max_cycles, u_max
        )

    best = price(orders)
    targets = [int(t) for t in graph.target_indices]
    for agent, start in enumerate(starts.tolist()):
        group = orders[agent].group
        if not group:
            continue
        # the walk to the group: to its nearest member (the rule's and the schedule's first goal)
        first = (
            orders[agent].entry_node
            if orders[agent].exact_pair
            else min(group, key=lambda t: (distances[start][t], t))
        )
        for via in targets:
            if via in group or time.monotonic() > deadline:
                continue
            if distances[start][via] + distances[via][first] > distances[start][first] + WAYPOINT_SLACK:
                continue
            candidate = list(orders)
            candidate[agent] = replace(orders[agent], waypoints=(via,))
            cost = price(candidate)
            if cost < best - 1e-9:
                best, orders = cost, candidate
    plan.orders, plan.simulated = orders, best
    return plan
