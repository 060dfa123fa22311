"""The one description of a monitoring graph that every other module reads.

A :class:`GraphSpec` is immutable: its arrays are private read-only copies, so an
environment, a policy and a baseline can share one spec without defensive copies.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, shortest_path

from sb3_pm.errors import InputError

if TYPE_CHECKING:
    import networkx as nx

    from sb3_pm.graphs.routes import Routes


class GraphError(InputError):
    """A graph that cannot be used for persistent monitoring (the message names why)."""


def _read_only(array: np.ndarray) -> np.ndarray:
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class GraphSpec:
    """An undirected, connected graph with target nodes.

    :param adjacency: ``(N, N)`` boolean, symmetric, zero diagonal.
    :param targets: ``(N,)`` boolean target flags; at least one must be set.
    :param name: a short label used in reports and run folders.
    :param positions: optional ``(N, 2)`` float drawing coordinates.
    :param node_ids: optional original node ids (e.g. from GraphML), kept for round-trips.
    :raises GraphError: if the adjacency is not square, not symmetric, has self-loops,
        is disconnected, or there are no targets.
    """

    adjacency: np.ndarray
    targets: np.ndarray
    name: str = "graph"
    positions: np.ndarray | None = None
    node_ids: tuple[str, ...] | None = field(default=None)

    def __post_init__(self) -> None:
        adjacency = np.asarray(self.adjacency)
        if adjacency.ndim != 2 or adjacency.shape[0] != adjacency.shape[1]:
            raise GraphError(f"graph {self.name!r}: adjacency must be square, got shape {adjacency.shape}")
        # bool needs no look; np.isin on an (N, N) array took 19 s at 20,000 nodes, two compares 1 s
        if adjacency.dtype != bool and not ((adjacency == 0) | (adjacency == 1)).all():
            raise GraphError(f"graph {self.name!r}: adjacency entries must be 0/1")
        adjacency = adjacency.astype(bool)
        n_nodes = adjacency.shape[0]
        if n_nodes == 0:
            raise GraphError(f"graph {self.name!r} has no nodes")
        if not (adjacency == adjacency.T).all():
            raise GraphError(
                f"graph {self.name!r}: adjacency is not symmetric (the graph must be undirected)"
            )
        if adjacency.diagonal().any():
            loops = np.flatnonzero(adjacency.diagonal()).tolist()
            raise GraphError(f"graph {self.name!r} has self-loops at nodes {loops[:10]}")
        targets = np.asarray(self.targets)
        if targets.shape != (n_nodes,):
            raise GraphError(
                f"graph {self.name!r}: targets must have shape ({n_nodes},), got {targets.shape}"
            )
        if not np.isin(targets, (0, 1)).all():
            raise GraphError(f"graph {self.name!r}: target flags must be 0/1")
        targets = targets.astype(bool)
        if not targets.any():
            raise GraphError(f"graph {self.name!r} has no targets: at least one node must be a target")
        n_components, _ = connected_components(csr_matrix(adjacency), directed=False)
        if n_components != 1:
            raise GraphError(f"graph {self.name!r} is not connected ({n_components} components)")
        object.__setattr__(self, "adjacency", _read_only(adjacency))
        object.__setattr__(self, "targets", _read_only(targets))
        if self.positions is not None:
            positions = np.asarray(self.positions, dtype=float)
            if positions.shape != (n_nodes, 2):
                raise GraphError(f"graph {self.name!r}: positions must have shape ({n_nodes}, 2)")
            object.__setattr__(self, "positions", _read_only(positions))
        if self.node_ids is not None:
            node_ids = tuple(str(node) for node in self.node_ids)
            if len(node_ids) != n_nodes or len(set(node_ids)) != n_nodes:
                raise GraphError(f"graph {self.name!r}: node_ids must be {n_nodes} distinct ids")
            object.__setattr__(self, "node_ids", node_ids)

    # ------------------------------------------------------------------ sizes
    @property
    def n_nodes(self) -> int:
        return int(self.adjacency.shape[0])

    @property
    def n_targets(self) -> int:
        return int(self.targets.sum())

    @property
    def n_edges(self) -> int:
        return int(self.adjacency.sum()) // 2

    @property
    def density(self) -> float:
        """Fraction of possible undirected edges present."""
        n = self.n_nodes
        return 0.0 if n < 2 else self.n_edges / (n * (n - 1) / 2)

    # ------------------------------------------------------- derived (cached)
    @cached_property
    def target_indices(self) -> np.ndarray:
        """``(T,)`` int64 indices of the target nodes, ascending."""
        return _read_only(np.flatnonzero(self.targets))

    @cached_property
    def reachable(self) -> np.ndarray:
        """``(N, N)`` bool: ``reachable[i, j]`` iff an agent on ``i`` may move to ``j``."""
        return _read_only(self.adjacency | np.eye(self.n_nodes, dtype=bool))

    @cached_property
    def hop_distances(self) -> np.ndarray:
        """``(N, N)`` int32 shortest-path lengths in hops (the graph is connected, so all finite)."""
        dist = shortest_path(csr_matrix(self.adjacency), directed=False, unweighted=True)
        return _read_only(dist.astype(np.int32))

    @cached_property
    def next_hop(self) -> np.ndarray:
        """``(N, N)`` int: ``next_hop[i, j]`` is the first node after ``i`` on a shortest path to ``j``.

        The smallest-index neighbour is chosen among equally short options, so paths are
        deterministic. ``next_hop[i, i] == i``.
        """
        dist = self.hop_distances
        n = self.n_nodes
        result = np.empty((n, n), dtype=np.int64)
        for i in range(n):
            neighbours = np.flatnonzero(self.adjacency[i])
            # For each destination j pick the first neighbour one hop closer to j.
            closer = dist[neighbours] == (dist[i] - 1)[None, :]
            result[i] = neighbours[np.argmax(closer, axis=0)]
            result[i, i] = i
        return _read_only(result)

    @cached_property
    def sparse_adjacency(self) -> csr_matrix:
        """``(N, N)`` CSR adjacency (int8, each row's neighbours in increasing order)."""
        from sb3_pm.graphs.routes import sparse_adjacency

        return sparse_adjacency(self.adjacency)

    @cached_property
    def routes(self) -> Routes:
        """Distances to the targets and next hops towards them (:mod:`sb3_pm.graphs.routes`):
        from the all-pairs tables on small graphs, from one search per target on large ones."""
        from sb3_pm.graphs.routes import site_routes

        return site_routes(self)

    @cached_property
    def fingerprint(self) -> str:
        """A short hash of adjacency and targets: two specs with equal fingerprints are the same problem."""
        digest = hashlib.sha1()
        digest.update(np.packbits(self.adjacency).tobytes())
        digest.update(np.packbits(self.targets).tobytes())
        digest.update(str(self.n_nodes).encode())
        return digest.hexdigest()[:16]

    def neighbours(self, node: int) -> np.ndarray:
        """Indices of the nodes adjacent to ``node``."""
        return np.flatnonzero(self.adjacency[node])

    # ------------------------------------------------------------- interop
    def same_problem(self, other: GraphSpec) -> bool:
        """True when both specs have identical adjacency and targets (names and drawings may differ)."""
        return self.fingerprint == other.fingerprint

    def to_networkx(self) -> nx.Graph:
        """An ``nx.Graph`` with integer nodes ``0..N-1`` and a 0/1 ``target`` node attribute."""
        import networkx as nx

        graph = nx.Graph(name=self.name)
        for node in range(self.n_nodes):
            attributes: dict[str, object] = {"target": int(self.targets[node])}
            if self.positions is not None:
                attributes["x"], attributes["y"] = (float(v) for v in self.positions[node])
            graph.add_node(node, **attributes)
        rows, cols = np.nonzero(np.triu(self.adjacency))
        graph.add_edges_from(zip(rows.tolist(), cols.tolist()))
        return graph

    def layout(self, seed: int = 0) -> np.ndarray:
        """``(N, 2)`` drawing coordinates: the stored positions, else a seeded spring layout."""
        if self.positions is not None:
            return self.positions
        import networkx as nx

        pos = nx.spring_layout(self.to_networkx(), seed=seed)
        return np.array([pos[node] for node in range(self.n_nodes)])

    def __repr__(self) -> str:
        return (
            f"GraphSpec(name={self.name!r}, n_nodes={self.n_nodes}, n_edges={self.n_edges}, "
            f"n_targets={self.n_targets})"
        )
