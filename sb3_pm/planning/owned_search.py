"""The plan search for large teams: nearby changes, priced with each group's own agent (docs/PLANNING.md).

The exhaustive search (:func:`sb3_pm.planning.planner.plan_patrol`) tries every move, drop, return
and swap and re-matches all agents to all groups for each: ``O(T^2)`` candidates a round, each
priced from every start. With 64 agents on 500 targets that is about 160,000 candidates and ten
million walks a round. Above :data:`EXACT_SEARCH_MAX_WALKS` walks a round (:func:`exhaustive`) this
search takes its place, keeping the matching fixed while it descends:

* a target moves to the groups holding one of its :data:`NEAR_TARGETS` nearest targets, or to an
  empty group, swaps with one of those nearest targets held by another group, or is dropped (a
  far group never gains from it on a site where travel is what costs), and a dropped target
  returns only to those groups;
* each changed group is priced with the agent that holds it (by each rule the group is priced
  by), and a candidate's gain is the difference of its groups' solo costs;
* every round applies all improving candidates that touch disjoint groups and targets, best
  first (their gains add up, since each agent is priced alone);
* after each round the agents are matched to the groups again by the Hungarian method, which
  costs no more than keeping each group's agent, so the cost falls every round until no nearby
  change gains.
"""

from __future__ import annotations

import time

import numpy as np

from sb3_pm.planning.pricer import GroupPricer

__all__ = [
    "EXACT_SEARCH_MAX_WALKS",
    "NEAR_TARGETS",
    "descend_owned",
    "exhaustive",
    "nearest_targets",
]

#: The most walks a round of the exhaustive search may price (every candidate from every start)
#: for a plan to take it; larger plans take :func:`descend_owned`. 16 agents on ``paper-200``'s
#: 32 targets are about 16,000; 12 agents on ``city-1k``'s 100 targets about 74,000, where the
#: exhaustive search does not finish within a minute; 64 agents on 500 targets about ten million.
EXACT_SEARCH_MAX_WALKS = 50_000
#: How many nearest targets (by hops) name the groups a target may join.
NEAR_TARGETS = 8

#: One candidate: its gain (negative: cheaper), each changed group as (group index, new group),
#: the targets it moves, and the dropped targets after it.
_Candidate = tuple[int, tuple[tuple[int, tuple[int, ...]], ...], tuple[int, ...], tuple[int, ...]]


def exhaustive(n_agents: int, n_targets: int) -> bool:
    """Whether a plan for ``n_agents`` on ``n_targets`` takes the exhaustive search: whether a round's
    candidates (``n T`` moves and drops, ``T (T - 1) / 2`` swaps at most), each priced from every
    start, are at most :data:`EXACT_SEARCH_MAX_WALKS` walks."""
    candidates = n_agents * n_targets + n_targets * (n_targets - 1) // 2
    return n_agents * candidates <= EXACT_SEARCH_MAX_WALKS


def nearest_targets(between: np.ndarray, count: int = NEAR_TARGETS) -> np.ndarray:
    """``(T, min(count, T - 1))`` each target's nearest other targets by hops (ties: lower label).

    :param between: ``(T, T)`` hop distances between the targets.
    """
    n_targets = between.shape[0]
    order = np.argsort(between, axis=1, kind="stable")
    others = np.array([row[row != t] for t, row in enumerate(order)]).reshape(n_targets, -1)
    return others[:, : min(count, max(n_targets - 1, 0))]


def _changes(
    groups: list[tuple[int, ...]], dropped: tuple[int, ...], near: np.ndarray
) -> list[tuple[tuple[tuple[int, tuple[int, ...]], ...], tuple[int, ...], tuple[int, ...]]]:
    """Every nearby change: (changed groups as (index, new group), targets moved, dropped after)."""
    holder = {target: g for g, group in enumerate(groups) for target in group}
    empty = {g for g, group in enumerate(groups) if not group}  # an idle agent may take any target
    found = []
    for target in range(near.shape[0]):
        g = holder.get(target)
        near_groups = sorted(
            ({holder[other] for other in near[target].tolist() if other in holder} | empty) - {g}
        )
        if g is None:  # dropped: return it to a nearby group
            rest = tuple(t for t in dropped if t != target)
            for h in near_groups:
                found.append((((h, tuple(sorted(groups[h] + (target,)))),), (target,), rest))
            continue
        without = tuple(t for t in groups[g] if t != target)
        found.append((((g, without),), (target,), tuple(sorted(dropped + (target,)))))
        for h in near_groups:
            found.append((((g, without), (h, tuple(sorted(groups[h] + (target,))))), (target,), dropped))
        for other in near[target].tolist():
            h = holder.get(other)
            if h is None or h == g or other < target and target in near[other]:
                continue  # the pair is tried once, from its lower label, where each is near the other
            swapped_g = tuple(sorted(without + (other,)))
            swapped_h = tuple(sorted(tuple(t for t in groups[h] if t != other) + (target,)))
            found.append((((g, swapped_g), (h, swapped_h)), (target, other), dropped))
    return found


def descend_owned(
    pricer: GroupPricer,
    groups: list[tuple[int, ...]],
    dropped: tuple[int, ...],
    deadline: float,
    near: np.ndarray,
) -> tuple[int, list[tuple[int, ...]], tuple[int, ...], list[int], int, bool]:
    """Local search with the matching fixed between re-matchings (module docstring).

    :param near: ``(T, k)`` each target's nearest targets (:func:`nearest_targets`).
    :return: as the exhaustive search: (cost, groups, dropped, order, rounds, complete), where
        ``order[agent]`` is the index of the agent's group.
    """
    groups = list(groups)
    pricer.prefetch(set(groups))
    best, order = pricer.total(groups, dropped)
    rounds = 0
    while True:
        if time.monotonic() > deadline:
            return best, groups, dropped, order, rounds, False
        start_of = {group_index: pricer.starts[agent] for agent, group_index in enumerate(order)}
        changes = _changes(groups, dropped, near)
        pricer.prefetch_pairs((start_of[g], new) for changed, _, _ in changes for g, new in changed)
        if time.monotonic() > deadline:
            return best, groups, dropped, order, rounds, False
        was_dropped = set(dropped)
        candidates: list[_Candidate] = []
        for changed, moved, after in changes:
            gain = sum(
                pricer.solo(start_of[g], new) - pricer.solo(start_of[g], groups[g]) for g, new in changed
            )
            for target in moved:  # a drop adds what the target costs alone, a return takes it off
                gain += pricer.dropped(target) * ((target in after) - (target in was_dropped))
            if gain < 0:
                candidates.append((gain, changed, moved, after))
        if not candidates:
            return best, groups, dropped, order, rounds, True
        groups, dropped = _apply_disjoint(candidates, groups, dropped)
        # matched again: never dearer than keeping each group's agent, whose cost fell by the gains
        pricer.prefetch(set(groups))
        best, order = pricer.total(groups, dropped)
        rounds += 1


def _apply_disjoint(
    candidates: list[_Candidate], groups: list[tuple[int, ...]], dropped: tuple[int, ...]
) -> tuple[list[tuple[int, ...]], tuple[int, ...]]:
    """``groups`` and ``dropped`` after every candidate, best first, that touches no group or target
    an earlier one touched (gains of disjoint changes add up)."""
    groups = list(groups)
    dropped_set = set(dropped)
    touched_groups: set[int] = set()
    touched_targets: set[int] = set()
    for _, changed, moved, after in sorted(candidates, key=lambda item: (item[0], item[1], item[2])):
        indices = {g for g, _ in changed}
        if indices & touched_groups or set(moved) & touched_targets:
            continue
        for g, new in changed:
            groups[g] = new
        # the change's own effect on the dropped targets: those it drops or brings back
        was = set(moved) & dropped_set
        now = set(moved) & set(after)
        dropped_set = (dropped_set - was) | now
        touched_groups |= indices
        touched_targets |= set(moved)
    return groups, tuple(sorted(dropped_set))
