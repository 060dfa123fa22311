"""Graph generators: seeded Erdős–Rényi draws and the paper's Algorithm 1 partition."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from sb3_pm.graphs.spec import GraphError, GraphSpec


def erdos_renyi(
    n_nodes: int,
    edge_prob: float = 0.2,
    target_prob: float | None = 0.16,
    n_targets: int | None = None,
    seed: int = 0,
    name: str | None = None,
    max_tries: int = 1000,
) -> GraphSpec:
    """Draw a connected G(N, p) graph with targets, redrawing until it is connected.

    Give either ``n_targets`` (an exact count, chosen uniformly) or ``target_prob`` (each node a
    target independently); ``n_targets`` wins when both are set. A draw with no target is redrawn
    like a disconnected one.

    :param n_nodes: number of nodes N (at least 2).
    :param edge_prob: probability of each undirected edge.
    :param target_prob: per-node target probability, used when ``n_targets`` is None.
    :param n_targets: exact number of targets.
    :param seed: seed of the only random generator used.
    :param max_tries: give up (``GraphError``) after this many disconnected draws.
    """
    if n_nodes < 2:
        raise GraphError(f"erdos_renyi needs at least 2 nodes, got {n_nodes}")
    if not 0.0 < edge_prob <= 1.0:
        raise GraphError(f"edge_prob must be in (0, 1], got {edge_prob}")
    if n_targets is not None and not 1 <= n_targets <= n_nodes:
        raise GraphError(f"n_targets must be in [1, {n_nodes}], got {n_targets}")
    if n_targets is None and (target_prob is None or not 0.0 < target_prob <= 1.0):
        raise GraphError(f"target_prob must be in (0, 1] when n_targets is not given, got {target_prob}")
    rng = np.random.default_rng(seed)
    upper = np.triu_indices(n_nodes, k=1)
    for _ in range(max_tries):
        adjacency = np.zeros((n_nodes, n_nodes), dtype=bool)
        adjacency[upper] = rng.random(len(upper[0])) < edge_prob
        adjacency |= adjacency.T
        if n_targets is not None:
            targets = np.zeros(n_nodes, dtype=bool)
            targets[rng.choice(n_nodes, size=n_targets, replace=False)] = True
        else:
            assert target_prob is not None  # checked above
            targets = rng.random(n_nodes) < target_prob
        n_components, _ = connected_components(csr_matrix(adjacency), directed=False)
        if n_components == 1 and targets.any():
            label = name or f"er-{n_nodes}-p{edge_prob:g}-s{seed}"
            return GraphSpec(adjacency=adjacency, targets=targets, name=label)
    raise GraphError(
        f"no connected G({n_nodes}, {edge_prob}) graph with a target in {max_tries} draws; raise edge_prob"
    )


def _cell_counts(lengths: Sequence[float], chunk_sizes: Sequence[float]) -> tuple[int, ...]:
    if len(lengths) == 0:
        raise GraphError("hyperrectangle needs at least one dimension")
    if len(lengths) != len(chunk_sizes):
        raise GraphError(f"{len(lengths)} lengths but {len(chunk_sizes)} chunk sizes")
    counts = []
    for axis, (length, chunk) in enumerate(zip(lengths, chunk_sizes)):
        if length <= 0 or chunk <= 0:
            raise GraphError(f"axis {axis}: length and chunk size must be positive, got {length} and {chunk}")
        ratio = length / chunk
        if not math.isclose(ratio, round(ratio), rel_tol=0, abs_tol=1e-9):
            raise GraphError(f"axis {axis}: chunk size {chunk} does not divide length {length}")
        counts.append(int(round(ratio)))
    return tuple(counts)


def hyperrectangle(
    lengths: Sequence[float],
    chunk_sizes: Sequence[float],
    targets: Sequence[int | Sequence[int]] | None = None,
    n_targets: int | None = None,
    seed: int = 0,
    name: str | None = None,
) -> GraphSpec:
    """The paper's Algorithm 1: cut an n-D box into equal cells and join touching cells.

    Axis ``k`` of length ``d_k`` is cut into ``d_k / m_k`` chunks; cells are numbered in C order
    (last axis fastest). Two cells are adjacent when their index offsets lie in ``{-1, 0, 1}^n``
    minus the zero offset (faces, edges and corners touch), so there are
    ``(prod(3 c_k - 2) - prod(c_k)) / 2`` edges for ``c_k`` cells per axis.

    Exactly one of ``targets`` (cell indices, flat ints or n-tuples) and ``n_targets`` (drawn
    uniformly with ``seed``) chooses the target cells.

    :raises GraphError: if a chunk size does not divide its length, or no target is chosen.
    """
    counts = _cell_counts(lengths, chunk_sizes)
    n_cells = math.prod(counts)
    cells = np.array(list(itertools.product(*(range(c) for c in counts))), dtype=np.int64)  # (N, n) C order
    # Chebyshev distance 1 between cell indices == the offset set {-1,0,1}^n \ {0}.
    chebyshev = np.abs(cells[:, None, :] - cells[None, :, :]).max(axis=-1)
    adjacency = chebyshev == 1
    flags = np.zeros(n_cells, dtype=bool)
    if (targets is None) == (n_targets is None):
        raise GraphError("hyperrectangle needs exactly one of targets or n_targets")
    if targets is not None:
        for cell in targets:
            index = (
                int(np.ravel_multi_index(tuple(cell), counts)) if isinstance(cell, Sequence) else int(cell)
            )
            if not 0 <= index < n_cells:
                raise GraphError(f"target cell {cell} is outside the {counts} grid")
            flags[index] = True
    else:
        assert n_targets is not None
        if not 1 <= n_targets <= n_cells:
            raise GraphError(f"n_targets must be in [1, {n_cells}], got {n_targets}")
        flags[np.random.default_rng(seed).choice(n_cells, size=n_targets, replace=False)] = True
    # Cell centres give a drawing for 1-D and 2-D boxes (higher axes are projected away).
    centres = (cells + 0.5) * np.asarray(chunk_sizes, dtype=float)
    positions = np.zeros((n_cells, 2))
    positions[:, : min(2, len(counts))] = centres[:, :2]
    label = name or "box-" + "x".join(str(c) for c in counts)
    if n_cells == 1:
        raise GraphError("the partition has a single cell; agents would have nowhere to move")
    return GraphSpec(adjacency=adjacency, targets=flags, name=label, positions=positions)
