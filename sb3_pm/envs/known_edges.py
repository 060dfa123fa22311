"""The ``layout="edges"`` pieces of the env: a graph's edge list, the mental maps' known edges over
it, and the sensing tables as sparse rows.

With ``layout="dense"`` a map observation carries the agent's known adjacency as an ``(N, N)`` int8
matrix, and the env precomputes ``(N, N)`` sensing tables from the all-pairs hop distances. With
``layout="edges"`` everything here grows with the edges instead:

* :func:`edge_list`: the graph's directed edge list ``(2, E)`` (both directions of each undirected
  edge, no self loops), in the row-major order of the adjacency's nonzeros, so that an edge mask over
  it lists an agent's known edges in the order ``np.nonzero`` lists the dense map's;
* :class:`KnownEdges`: each agent's known edges as an ``(n_agents, E)`` bool array over that list;
* :class:`SparseRows` and :func:`sensing_tables`: the balls of radius ``r`` around every node as a
  CSR matrix from a breadth-first search of ``r`` hops (sparse matrix products), of which only the
  agents' current rows are made dense each step (``n_agents x N``).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec

LAYOUTS = ("dense", "edges")


def check_layout(layout: object, observation: str, family: bool) -> str:
    """The validated ``layout`` env argument (one-line errors naming what is wrong)."""
    if not isinstance(layout, str) or layout not in LAYOUTS:
        raise InputError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if layout == "edges" and observation != "map":
        raise InputError(f"layout='edges' needs observation='map' (a map layout), not {observation!r}")
    if layout == "edges" and family:
        raise InputError("layout='edges' needs one graph, not a graph family (its edge count varies)")
    return layout


def edge_list(adjacency: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The directed edges of ``adjacency``, with each row's slice and each edge's reverse.

    Shapes:
        - adjacency: ``(N, N)`` bool, symmetric, zero diagonal
        - output: ``edge_index`` ``(2, E)`` int64 (``[i, j]`` per edge, sorted by ``i`` then ``j``,
          E = twice the undirected edges), ``indptr`` ``(N + 1,)`` int64 (the edges of row ``i``
          are ``indptr[i]:indptr[i + 1]``) and ``reverse`` ``(E,)`` int64 (the index of ``[j, i]``)
    """
    matrix = sparse.csr_matrix(np.asarray(adjacency, dtype=bool))
    matrix.sort_indices()
    n = matrix.shape[0]
    indptr = matrix.indptr.astype(np.int64)
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    cols = matrix.indices.astype(np.int64)
    # The reverse edge [j, i] sits where the pair sorted by (j, i) falls in row-major order.
    order = np.lexsort((rows, cols))  # edges sorted by (col, row) = their reverses' positions
    reverse = np.empty_like(order)
    reverse[order] = np.arange(len(order))
    return np.stack((rows, cols)), indptr, reverse


def _row_edges(indptr: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``(k,)`` int64 indices of every edge leaving ``rows``: concatenated ``indptr`` slices."""
    starts, counts = indptr[rows], indptr[rows + 1] - indptr[rows]
    total = int(counts.sum())
    offsets = np.repeat(starts - np.cumsum(counts) + counts, counts)
    return offsets + np.arange(total, dtype=np.int64)


class KnownEdges:
    """Each agent's known edges over the graph's :func:`edge_list` (``layout="edges"``).

    An agent knows an edge once it has explored either end (the dense maps' rule: exploring row ``r``
    sets row and column ``r`` of the known adjacency), so the mask is always symmetric.

    :param n_agents: number of maps.
    :param adjacency: ``(N, N)`` bool true adjacency.
    :param known: every edge known from the start (``graph_knowledge="known"``).
    """

    def __init__(self, n_agents: int, adjacency: np.ndarray, known: bool) -> None:
        edge_index, self._indptr, self._reverse = edge_list(adjacency)
        edge_index.setflags(write=False)
        #: ``(2, E)`` int64 read-only edge list (both directions, no self loops).
        self.edge_index = edge_index
        self.n_edges = edge_index.shape[1]
        #: ``(n_agents, E)`` bool known edges.
        self.known = np.full((n_agents, self.n_edges), known, dtype=bool)
        self._mask_int8: list[np.ndarray | None] = [None] * n_agents

    def __setstate__(self, state: dict) -> None:
        """Unpickle: the cached int8 masks are read-only again (NumPy unpickles them writeable)."""
        self.__dict__.update(state)
        for array in [self.edge_index, *(m for m in self._mask_int8 if m is not None)]:
            array.setflags(write=False)

    def discover(self, agent: int, rows: np.ndarray) -> None:
        """Mark every edge at the nodes ``rows`` ``(k,)`` int as known to ``agent``."""
        edges = _row_edges(self._indptr, np.asarray(rows, dtype=np.int64))
        self.known[agent, edges] = True
        self.known[agent, self._reverse[edges]] = True
        self._mask_int8[agent] = None

    def forget(self) -> None:
        """No edge known to any agent (a new lifetime)."""
        self.known[:] = False
        self._mask_int8 = [None] * len(self._mask_int8)

    def load(self, known: np.ndarray) -> None:
        """Put back a saved ``known`` ``(n_agents, E)`` bool array."""
        self.known = np.array(known, dtype=bool, copy=True)
        self._mask_int8 = [None] * len(self._mask_int8)

    def mask_observations(self) -> list[np.ndarray]:
        """Each agent's ``(E,)`` int8 read-only edge mask, rebuilt only after it gains an edge."""
        masks = self._mask_int8
        for agent, cached in enumerate(masks):
            if cached is None:
                cached = self.known[agent].astype(np.int8)
                cached.setflags(write=False)
                masks[agent] = cached
        return masks  # type: ignore[return-value]

    def dense(self, n_nodes: int) -> np.ndarray:
        """``(n_agents, N, N)`` bool known adjacency (for tests and checks, never per step)."""
        out = np.zeros((self.known.shape[0], n_nodes, n_nodes), dtype=bool)
        agents, edges = np.nonzero(self.known)
        out[agents, self.edge_index[0, edges], self.edge_index[1, edges]] = True
        return out


class SparseRows:
    """A read-only ``(N, N)`` table stored as CSR, indexed by a few rows at a time.

    ``table[rows]`` with ``rows`` ``(k,)`` int gives the fresh dense ``(k, N)`` rows, as a dense
    table's fancy indexing does, so the env's per-step code reads both layouts alike.
    """

    def __init__(self, matrix: sparse.csr_matrix, dtype: type) -> None:
        matrix = sparse.csr_matrix(matrix)
        matrix.sort_indices()
        self.shape = matrix.shape
        self.dtype = np.dtype(dtype)
        self._indptr = matrix.indptr.astype(np.int64)
        self._indices = matrix.indices.astype(np.int64)

    def __getitem__(self, rows: np.ndarray | int) -> np.ndarray:
        one = np.ndim(rows) == 0
        rows = np.atleast_1d(np.asarray(rows, dtype=np.int64))
        out = np.zeros((len(rows), self.shape[1]), dtype=self.dtype)
        entries = _row_edges(self._indptr, rows)
        counts = self._indptr[rows + 1] - self._indptr[rows]
        out[np.repeat(np.arange(len(rows)), counts), self._indices[entries]] = 1
        return out[0] if one else out

    def toarray(self) -> np.ndarray:
        """The whole ``(N, N)`` table (for tests)."""
        return self[np.arange(self.shape[0])]


def balls(adjacency: sparse.csr_matrix, radius: int) -> sparse.csr_matrix:
    """``(N, N)`` CSR 0/1: entry ``(i, j)`` set iff ``j`` is within ``radius`` hops of ``i``
    (empty for a negative radius), by ``radius`` sparse products, one per hop."""
    n = adjacency.shape[0]
    if radius < 0:
        return sparse.csr_matrix((n, n), dtype=np.int8)
    step = (adjacency + sparse.identity(n, dtype=np.int32, format="csr")).astype(np.int32)
    ball = sparse.identity(n, dtype=np.int32, format="csr")
    for _ in range(radius):
        ball = (ball @ step).tocsr()
        ball.data[:] = 1  # 0/1, so the counts of paths never grow
    return ball


def sensing_tables(
    graph: GraphSpec, obs_radius: int, layout: str
) -> tuple[np.ndarray | SparseRows, np.ndarray | SparseRows, np.ndarray | SparseRows]:
    """The env's per-step tables: nodes seen from each node (within ``obs_radius`` hops), nodes whose
    incident edges are seen (within ``obs_radius - 1``), and the moves from each node as int8.

    ``"dense"``: ``(N, N)`` arrays from the all-pairs hop distances; ``"edges"``: :class:`SparseRows`
    from a breadth-first search of ``obs_radius`` hops, never an ``(N, N)`` array.
    """
    if layout == "dense":
        hops = graph.hop_distances
        return hops <= obs_radius, hops <= obs_radius - 1, graph.reachable.astype(np.int8)
    adjacency = sparse.csr_matrix(graph.adjacency).astype(np.int32)  # never an (N, N) int32 copy
    return (
        SparseRows(balls(adjacency, obs_radius), bool),
        SparseRows(balls(adjacency, obs_radius - 1), bool),
        SparseRows(balls(adjacency, 1), np.int8),
    )


__all__ = ["LAYOUTS", "check_layout", "KnownEdges", "SparseRows", "balls", "edge_list", "sensing_tables"]
