"""Closed tours through a set of nodes on hop distances (the ``tour_patrol`` baseline's, the planner's).

A nearest-neighbour tour from the first node, improved by 2-opt until no reversal shortens it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["approximate_tour"]


def approximate_tour(nodes: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """A closed tour through ``nodes``: nearest neighbour, then 2-opt to a local optimum.

    :param nodes: ``(T,)`` node indices to visit.
    :param distances: ``(N, N)`` hop distances.
    :return: ``(T,)`` the nodes in tour order, starting with ``nodes[0]``.
    """
    nodes = np.asarray(nodes, dtype=np.int64)
    t = len(nodes)
    if t <= 3:
        return nodes.copy()
    d = distances[np.ix_(nodes, nodes)].astype(np.int64)
    order = [0]
    unvisited = np.ones(t, dtype=bool)
    unvisited[0] = False
    for _ in range(t - 1):
        row = np.where(unvisited, d[order[-1]], np.iinfo(np.int64).max)
        nxt = int(row.argmin())  # ties: lowest index
        order.append(nxt)
        unvisited[nxt] = False
    tour = np.array(order)
    improved = True
    while improved:
        improved = False
        for i in range(t - 1):
            # Gain of reversing tour[i+1..j] for every j at once: replace edges (a,b),(c,e) by (a,c),(b,e).
            a, b = tour[i], tour[i + 1]
            js = np.arange(i + 2, t if i > 0 else t - 1)
            if len(js) == 0:
                continue
            c, e = tour[js], tour[(js + 1) % t]
            gain = d[a, b] + d[c, e] - d[a, c] - d[b, e]
            best = int(gain.argmax())
            if gain[best] > 0:
                j = int(js[best])
                tour[i + 1 : j + 1] = tour[i + 1 : j + 1][::-1].copy()
                improved = True
    return nodes[tour]
