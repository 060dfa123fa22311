"""Shortest routes to the targets, without the all-pairs tables on large sites.

The territory rule (:mod:`sb3_pm.envs.territory_rule`) and the territory split
(:mod:`sb3_pm.graphs.territories`) only ever ask for distances *to a target* and for the first hop
of a shortest path *towards a target*. :class:`GraphSpec`'s all-pairs ``hop_distances`` and
``next_hop`` answer that with two ``(N, N)`` tables (at 5,000 nodes 100 MB + 200 MB, and an
``O(N^2)`` Python loop to build ``next_hop``); :class:`TargetRoutes` answers it from one
breadth-first search per target, ``(T, N)`` int32 (``T`` targets), and finds a next hop on demand
from the node's sorted neighbour list.

Both give the same answers, bit for bit: distances are exact hop counts, and the next hop is the
*smallest-index* neighbour one hop closer, as ``GraphSpec.next_hop`` picks it
(``tests/test_large_deploy.py``). :func:`site_routes` takes the all-pairs tables up to
:data:`DENSE_ROUTES_MAX` nodes (every published graph), where they are cheap and already used by
other parts, and the per-target searches above it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path

if TYPE_CHECKING:
    from sb3_pm.graphs.spec import GraphSpec

#: Largest site whose routes come from the all-pairs tables. Measured on ``city_streets`` (one
#: thread, a machine busy with other work): building the all-pairs tables took 0.04 s at 500 nodes,
#: 0.14 s at 1,000 and 0.68 s at 2,000, the per-target searches 0.003 s, 0.013 s and 0.05 s; a
#: next hop costs 0.4 us from the table and 4 us from a neighbour list, distances 2 us and 5 us.
#: Over a 500-step episode with one agent per 80 nodes the two break even near 500 nodes.
DENSE_ROUTES_MAX = 500


class Routes(Protocol):
    """Distances to targets and next hops towards them (what the territory rule reads)."""

    def distances(self, node: int, goals: np.ndarray) -> np.ndarray:
        """``(len(goals),)`` hop distances from ``node`` to each of ``goals`` (targets)."""

    def next_hop(self, node: int, goal: int) -> int:
        """The first node after ``node`` on a shortest path to target ``goal`` (``node`` itself
        when ``node == goal``; the smallest-index neighbour among equally short options)."""

    def between_targets(self) -> np.ndarray:
        """``(T, T)`` hop distances between the targets, in ``target_indices`` order."""

    def to_targets(self, nodes: np.ndarray) -> np.ndarray:
        """``(len(nodes), T)`` hop distances from each of ``nodes`` to each target."""

    def next_hops_to_targets(self) -> np.ndarray:
        """``(N, T)`` int64: :meth:`next_hop` from every node towards every target, as one table."""


class DenseRoutes:
    """:class:`Routes` read from the all-pairs tables.

    :param hop_distances: ``(N, N)`` hop distances; ``next_hop``: ``(N, N)`` first hops;
        ``target_indices``: ``(T,)`` the target nodes.
    """

    def __init__(self, hop_distances: np.ndarray, next_hop: np.ndarray, target_indices: np.ndarray) -> None:
        self.hop_distances, self._next_hop = hop_distances, next_hop
        self.target_indices = np.asarray(target_indices, dtype=np.int64)

    def distances(self, node: int, goals: np.ndarray) -> np.ndarray:
        return self.hop_distances[node, goals]  # type: ignore[no-any-return]

    def next_hop(self, node: int, goal: int) -> int:
        return int(self._next_hop[node, goal])

    def between_targets(self) -> np.ndarray:
        return self.hop_distances[np.ix_(self.target_indices, self.target_indices)]  # type: ignore[no-any-return]

    def to_targets(self, nodes: np.ndarray) -> np.ndarray:
        return self.hop_distances[np.ix_(np.asarray(nodes, dtype=np.int64), self.target_indices)]  # type: ignore[no-any-return]

    def next_hops_to_targets(self) -> np.ndarray:
        return self._next_hop[:, self.target_indices].astype(np.int64)  # type: ignore[no-any-return]


class TargetRoutes:
    """:class:`Routes` from one breadth-first search per target: ``(T, N)`` int32 in memory.

    :param graph: the site.
    """

    def __init__(self, graph: GraphSpec) -> None:
        targets = np.asarray(graph.target_indices, dtype=np.int64)
        self.target_indices = targets
        adjacency = graph.sparse_adjacency
        # CSR rows list each node's neighbours in increasing order: the first one found closer is
        # the smallest-index one, as GraphSpec.next_hop picks it.
        self._indptr, self._indices = adjacency.indptr, adjacency.indices
        hops = shortest_path(adjacency, directed=False, unweighted=True, indices=targets)  # (T, N) float
        #: ``(T, N)`` int32: ``from_target[k, v]`` is the hop distance between target ``k`` and ``v``.
        self.from_target = hops.astype(np.int32)
        #: ``(N,)`` int64: the row of ``from_target`` of each target node (-1 elsewhere).
        self.row = np.full(graph.n_nodes, -1, dtype=np.int64)
        self.row[targets] = np.arange(targets.size)

    def distances(self, node: int, goals: np.ndarray) -> np.ndarray:
        rows = self.row[np.asarray(goals, dtype=np.int64)]
        if (rows < 0).any():
            raise ValueError("TargetRoutes answers distances to targets only")
        return self.from_target[rows, node]  # the graph is undirected: d(t, v) = d(v, t)

    def next_hop(self, node: int, goal: int) -> int:
        if node == goal:
            return int(node)
        row = int(self.row[goal])
        if row < 0:
            raise ValueError(f"TargetRoutes routes towards targets only; node {goal} is not one")
        to_goal = self.from_target[row]
        neighbours = self._indices[self._indptr[node] : self._indptr[node + 1]]
        closer = neighbours[to_goal[neighbours] == to_goal[node] - 1]
        return int(closer[0])  # a connected graph always has one

    def between_targets(self) -> np.ndarray:
        return self.from_target[:, self.target_indices]  # type: ignore[no-any-return]

    def to_targets(self, nodes: np.ndarray) -> np.ndarray:
        return self.from_target[:, np.asarray(nodes, dtype=np.int64)].T  # type: ignore[no-any-return]

    def next_hops_to_targets(self) -> np.ndarray:
        # next_hop() for every node at once, one pass over the CSR edge list per target: the first
        # closer neighbour in a sorted row is the smallest-index one
        n_nodes = self.row.size
        source = np.repeat(np.arange(n_nodes), np.diff(self._indptr))
        neighbour = self._indices.astype(np.int64)
        result = np.empty((n_nodes, self.target_indices.size), dtype=np.int64)
        for column, target in enumerate(self.target_indices.tolist()):
            hops = self.from_target[column]
            closer = np.flatnonzero(hops[neighbour] == hops[source] - 1)
            nodes, first = np.unique(source[closer], return_index=True)
            result[nodes, column] = neighbour[closer[first]]
            result[target, column] = target
        return result


def site_routes(graph: GraphSpec) -> Routes:
    """The routes of ``graph``: all-pairs up to :data:`DENSE_ROUTES_MAX` nodes, per target above
    (the same answers either way; module docstring). Cached on the graph (``graph.routes``)."""
    if graph.n_nodes <= DENSE_ROUTES_MAX:
        return DenseRoutes(graph.hop_distances, graph.next_hop, graph.target_indices)
    return TargetRoutes(graph)


def sparse_adjacency(adjacency: np.ndarray) -> csr_matrix:
    """``(N, N)`` CSR of a bool adjacency, int8 entries, indices sorted within each row."""
    matrix = csr_matrix(adjacency, dtype=np.int8)
    matrix.sort_indices()
    return matrix


__all__ = ["DENSE_ROUTES_MAX", "DenseRoutes", "Routes", "TargetRoutes", "site_routes", "sparse_adjacency"]
