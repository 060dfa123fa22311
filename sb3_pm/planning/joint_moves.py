"""Every joint move of a team, vectorized: the exact first steps of the components bound and of
the planner's openings (docs/PLANNING.md)."""

from __future__ import annotations

import numpy as np

__all__ = ["after_step", "distinct_cheapest", "joint_choices"]


def joint_choices(choices: list[np.ndarray], at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every joint choice of the agents: ``choices[node]`` are one agent's options from ``node``.

    :param at: ``(M, n)`` each row's agents' nodes.
    :return: ``(M', n)`` the chosen options and ``(M',)`` each new row's parent row.
    """
    parent = np.arange(at.shape[0])
    chosen = np.zeros((at.shape[0], 0), dtype=np.int64)
    sizes = np.array([c.size for c in choices], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    flat = np.concatenate(choices)
    for agent in range(at.shape[1]):
        count = sizes[at[parent, agent]]
        rows = np.repeat(np.arange(parent.size), count)
        within = np.arange(rows.size) - np.repeat(np.cumsum(count) - count, count)
        option = flat[offsets[at[parent[rows], agent]] + within]
        chosen = np.concatenate([chosen[rows], option[:, None]], axis=1)
        parent = parent[rows]
    return chosen, parent


def after_step(on: np.ndarray, before: np.ndarray, u_max: int) -> np.ndarray:
    """Eq. (1) on the targets: ``on`` ``(M, n)`` the target each agent stands on (-1: none),
    ``before`` ``(M, T)`` the targets' ``u``; returns ``(M, T)`` after the step."""
    occupied = np.zeros(before.shape, dtype=bool)
    for agent in range(on.shape[1]):
        rows = np.flatnonzero(on[:, agent] >= 0)
        occupied[rows, on[rows, agent]] = True
    return np.where(occupied, np.maximum(before - 1, 0), np.minimum(before + 1, u_max))


def distinct_cheapest(keys: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Row indices of ``keys`` ``(M, k)``, each distinct row once at its least ``cost`` ``(M,)``,
    ordered by cost, then by the row (so the order does not depend on how the rows were made)."""
    order = np.lexsort((*keys.T[::-1], cost))
    _, first = np.unique(keys[order], axis=0, return_index=True)
    return order[np.sort(first)]
