"""Many solo walks priced at once (docs/PLANNING.md "Plans").

:func:`~sb3_pm.planning.group_patrol.solo_cost` walks one agent alone on its group, step by step in
plain Python. A plan search prices thousands of (start, group) pairs per round of its local search,
so :func:`solo_costs` walks all of them together as NumPy arrays, one row per walk, with the same
rules and tie-breaks, and returns the same sums.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["solo_costs"]


def _padded(groups: Sequence[Sequence[int]], fill: int) -> tuple[np.ndarray, np.ndarray]:
    """``(B, K)`` groups padded with ``fill``, and the ``(B, K)`` mask of real entries."""
    width = max(1, max((len(group) for group in groups), default=1))
    padded = np.full((len(groups), width), fill, dtype=np.int64)
    for row, group in enumerate(groups):
        padded[row, : len(group)] = group
    mask = np.arange(width)[None, :] < np.array([len(g) for g in groups], dtype=np.int64)[:, None]
    return padded, mask


def solo_costs(
    starts: Sequence[int],
    groups: Sequence[Sequence[int]],
    rules: Sequence[str],
    initials: Sequence[Sequence[int]],
    max_cycles: int,
    u_max: int,
    distances: np.ndarray,
    next_hop: np.ndarray,
) -> np.ndarray:
    """Each walk's ``solo_cost``: one agent alone on its group, every walk at once.

    :param starts: ``B`` start nodes.
    :param groups: ``B`` groups of target nodes (for the ``tour`` rule, in tour order).
    :param rules: ``B`` rule names, ``stalest`` or ``tour``.
    :param initials: ``B`` lists of the group targets' ``u`` at reset, in group order.
    :param max_cycles: ``K``, the episode's length.
    :param u_max: the uncertainty cap.
    :param distances: ``(N, N)`` hop distances.
    :param next_hop: ``(N, N)`` the first node of a shortest path.
    :return: ``(B,)`` int64, ``Σ_k Σ_group u`` over steps ``1 .. K`` of each walk.
    """
    count = len(starts)
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    distances = np.asarray(distances, dtype=np.int64)
    next_hop = np.asarray(next_hop, dtype=np.int64)
    members, real = _padded(groups, 0)
    values, _ = _padded(initials, 0)
    lengths = real.sum(axis=1)
    tour = np.array([rule == "tour" for rule in rules], dtype=bool)
    position = np.asarray(starts, dtype=np.int64).copy()
    goal = np.full(count, -1, dtype=np.int64)  # -1: no goal kept
    # One integer orders (-u, distance, node) lexicographically: the stalest rule's key.
    scale = int(distances.shape[0]) + int(distances.max()) + 1
    total = np.zeros(count, dtype=np.int64)
    here = real & (members == position[:, None])
    for _ in range(max_cycles):
        on_group = here.any(axis=1)
        dwell = (lengths == 0) | (on_group & ((values * here).sum(axis=1) > 0))
        keep = ~dwell & (goal >= 0) & (goal != position)
        choose = ~dwell & ~keep
        new_position, new_goal = position.copy(), goal.copy()
        new_goal[dwell] = -1
        new_position[keep] = next_hop[position[keep], goal[keep]]
        if choose.any():
            chosen_rows = np.flatnonzero(choose)
            chosen_goals = _choose_goals(
                chosen_rows, position, members, real, values, here, on_group, lengths, tour, distances, scale
            )
            new_goal[chosen_rows] = chosen_goals
            moving = chosen_goals >= 0
            new_position[chosen_rows[moving]] = next_hop[position[chosen_rows[moving]], chosen_goals[moving]]
        position, goal = new_position, new_goal
        here = real & (members == position[:, None])
        # padded entries stay 0: real is 0 there
        values = np.where(here, np.maximum(values - 1, 0), np.minimum(values + real, u_max))
        total += values.sum(axis=1)
    return total


def _choose_goals(
    idx: np.ndarray,
    position: np.ndarray,
    members: np.ndarray,
    real: np.ndarray,
    values: np.ndarray,
    here: np.ndarray,
    on_group: np.ndarray,
    lengths: np.ndarray,
    tour: np.ndarray,
    distances: np.ndarray,
    scale: int,
) -> np.ndarray:
    """The next goal of each walk in ``idx`` that must choose one (``-1``: stay without a goal)."""
    group, mask, at = members[idx], real[idx], position[idx]
    hops = distances[at[:, None], group]
    never = np.iinfo(np.int64).max
    # stalest: the other target with the highest u, then the nearest, then the lowest node
    key = -values[idx] * scale * scale + hops * scale + group
    stalest_key = np.where(mask & (group != at[:, None]), key, never)
    stalest_slot = stalest_key.argmin(axis=1)
    stalest = np.where(stalest_key.min(axis=1) == never, -1, group[np.arange(idx.size), stalest_slot])
    # tour: the target after this one in tour order; from off the group, the nearest
    nearest_key = np.where(mask, hops * scale + group, never)
    nearest = group[np.arange(idx.size), nearest_key.argmin(axis=1)]
    slot = here[idx].argmax(axis=1)
    following = group[np.arange(idx.size), (slot + 1) % np.maximum(lengths[idx], 1)]
    on = on_group[idx]
    tour_goal = np.where(on, np.where(lengths[idx] == 1, -1, following), nearest)
    return np.where(tour[idx], tour_goal, stalest)
