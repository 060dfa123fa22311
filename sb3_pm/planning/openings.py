"""Openings: the first steps played exactly, then a fresh plan (docs/PLANNING.md "Openings").

A plan sends every agent to its group at once. Where several agents start near the same targets,
the cheapest start can be another: an agent that waits a step on a target already at 0, or that
takes a pair for a while before leaving for a lone target, so that the waste a crowded start
forces comes later, when it costs less (a step's waste counts for every step left). So the
planner also plays every joint move of the first :data:`OPENING_STEPS` steps exactly, keeps the
:data:`OPENING_CANDIDATES` cheapest distinct states (where the agents stand and the targets' ``u``;
only the cheapest first steps are continued), plans afresh from each with
:func:`~sb3_pm.planning.team_plan.plan_team` for the steps left, and keeps an opening where the
whole episode's simulated ``avg_uncertainty`` falls.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sb3_pm.graphs import GraphSpec
from sb3_pm.planning.joint_moves import after_step, distinct_cheapest, joint_choices
from sb3_pm.planning.planner import DEFAULT_SEARCH_SECONDS, uncertainty_at_reset
from sb3_pm.planning.team_plan import TeamPlan, plan_team

__all__ = ["MAX_OPENING_MOVES", "OPENING_CANDIDATES", "OPENING_STEPS", "best_opening", "plan_with_openings"]

#: The steps an opening fixes.
OPENING_STEPS = 2
#: The cheapest openings continued by a fresh plan.
OPENING_CANDIDATES = 8
#: The most joint first moves searched; with more agents or moves, no opening is tried.
MAX_OPENING_MOVES = 200_000


def best_opening(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial: np.ndarray,
    seconds: float,
) -> TeamPlan | None:
    """The best opening found and the plan after it, or ``None`` where none is searched.

    :param starts: ``(n,)`` start nodes; :param initial: ``(N,)`` ``u`` at reset.
    :param seconds: the budget of all the fresh plans together.
    :return: a plan with ``opening`` set, its ``simulated`` the whole episode's.
    """
    if max_cycles <= OPENING_STEPS or graph.n_targets == 0:
        return None
    reach = [np.flatnonzero(row).astype(np.int64) for row in graph.reachable]
    if float(np.prod([float(reach[s].size) for s in starts])) > MAX_OPENING_MOVES:
        return None
    targets = graph.target_indices
    target_of = np.full(graph.n_nodes, -1, dtype=np.int64)
    target_of[targets] = np.arange(targets.size)
    # step 1: every joint move; only the cheapest are continued
    first, _ = joint_choices(reach, np.asarray(starts, dtype=np.int64)[None, :])
    values1 = after_step(
        target_of[first], np.repeat(initial[targets][None, :], first.shape[0], axis=0), u_max
    )
    cost1 = values1.sum(axis=1)
    keep = distinct_cheapest(np.concatenate([np.sort(first, axis=1), values1], axis=1), cost1)
    keep = keep[cost1[keep] == cost1.min()]
    first, values1, cost1 = first[keep], values1[keep], cost1[keep]
    # step 2: every joint move from those
    second, parent = joint_choices(reach, first)
    values2 = after_step(target_of[second], values1[parent], u_max)
    cost2 = cost1[parent] + values2.sum(axis=1)
    # the agents are alike: a state is where they stand, sorted, and the targets' u
    states = np.concatenate([np.sort(second, axis=1), values2], axis=1)
    picked = distinct_cheapest(states, cost2)[:OPENING_CANDIDATES]
    best: TeamPlan | None = None
    each = seconds / max(1, picked.size)
    for row in picked:
        now = np.asarray(initial).copy()
        now[targets] = values2[row]
        rest = plan_team(graph, second[row], max_cycles - OPENING_STEPS, u_max, now, each)
        total = (float(cost2[row]) + rest.simulated * (max_cycles - OPENING_STEPS)) / max_cycles
        if best is None or total < best.simulated - 1e-9:
            opening = np.stack([first[parent[row]], second[row]])  # (2, n)
            best = replace(rest, opening=opening, simulated=total)
    return best


def plan_with_openings(
    graph: GraphSpec,
    starts: np.ndarray,
    max_cycles: int,
    u_max: int,
    initial_uncertainty: np.ndarray | None = None,
    search_seconds: float = DEFAULT_SEARCH_SECONDS,
) -> TeamPlan:
    """:func:`~sb3_pm.planning.team_plan.plan_team`, or the best opening where that scores lower
    (arguments as ``plan_team``; the openings get half as much time again)."""
    plan = plan_team(graph, starts, max_cycles, u_max, initial_uncertainty, search_seconds)
    initial = uncertainty_at_reset(graph, initial_uncertainty).astype(np.int64)
    opened = best_opening(
        graph, np.asarray(starts, dtype=np.int64), max_cycles, u_max, initial, search_seconds / 2
    )
    if opened is not None and opened.simulated < plan.simulated - 1e-9:
        return opened
    return plan
