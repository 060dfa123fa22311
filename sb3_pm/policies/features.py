"""Breadth-first hop distances over a known adjacency, batched in torch (used by the DCBF's neglect
bound, :mod:`sb3_pm.policies.neglect_bound`)."""

from __future__ import annotations

import torch as th


def hop_distances(adjacency: th.Tensor, start: th.Tensor) -> th.Tensor:
    """Breadth-first hop distances from one start node per map.

    One frontier-times-adjacency product per hop, so the cost is ``O(B N^2)`` per hop and the
    number of hops is the eccentricity of the start node (2-4 on the paper's graphs).

    :param adjacency: known adjacency (nonzero = edge), any dtype.
    :param start: one-hot start node (nonzero = start).
    :return: hops from the start node, ``-1`` where unreachable.

    Shapes:
        - adjacency: ``(B, N, N)``; start: ``(B, N)``
        - output: ``(B, N)`` long
    """
    edges = (adjacency != 0).float()
    reached = start != 0
    distance = th.where(reached, 0, -1).long()
    frontier = reached.float().unsqueeze(1)  # (B, 1, N)
    for hop in range(1, adjacency.shape[-1]):
        step = (th.bmm(frontier, edges).squeeze(1) > 0) & ~reached
        if not bool(step.any()):
            break
        distance = th.where(step, hop, distance)
        reached = reached | step
        frontier = step.float().unsqueeze(1)
    return distance
