"""GAT attention over a batch of sparse graphs as compressed sparse row (CSR) products.

The sparse kernel of :class:`~sb3_pm.policies.layers.GraphAttention` used to be PyG's message
passing: it gathers every edge's source features into an ``(E, heads, C)`` tensor, scales it and
scatters it back, and its backward pass does the same again. On the published 200-node graph a
minibatch of 250 maps holds about 450,000 edges, so each layer moved hundreds of megabytes, and
the update phase was memory-bound. Here the weighted sum over neighbours is one sparse-dense
product per head (``torch.sparse`` CSR times dense), and its backward pass is the transposed
product for the features and a sampled dense-dense product (``torch.sparse.sampled_addmm``) for
the attention weights, so no per-edge feature tensor is ever built. Only per-edge *scalars*
(scores, probabilities) go through ordinary autograd.

It computes :class:`torch_geometric.nn.GATConv`'s function (self loops added, heads averaged by the
caller) on its parameters; only float rounding differs. It is opt-in (``gat_sparse_kernel: csr``):
the default, PyG's message passing, reproduces earlier runs bit for bit, and a different rounding
trains a different team from the same seed.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import torch as th
from torch import nn
from torch_geometric.utils import softmax as segment_softmax

SPARSE_KERNELS = ("csr", "pyg")


@dataclass(frozen=True)
class CSRGraph:
    """A batch of ``B`` graphs on ``N`` nodes as one block-diagonal ``(B*N, B*N)`` CSR pattern,
    self loops included, with its transpose.

    Row ``b*N + i`` (a target) holds the columns ``b*N + j`` (its sources) with
    ``adjacency[b, i, j] != 0`` or ``i == j``, in increasing order. ``perm`` lists the edges in the
    transposed pattern's order, so that ``values[perm]`` are the transpose's values.
    """

    size: int  #: B * N
    crow: th.Tensor  #: (size + 1,) long, row pointers
    col: th.Tensor  #: (E,) long, source of each edge
    row: th.Tensor  #: (E,) long, target of each edge
    t_crow: th.Tensor  #: (size + 1,) long, row pointers of the transpose
    t_col: th.Tensor  #: (E,) long, columns of the transpose (the targets, in transposed order)
    perm: th.Tensor  #: (E,) long, edge index of each transposed entry

    def matrix(self, values: th.Tensor) -> th.Tensor:
        """The sparse ``(size, size)`` matrix with ``values`` ``(E,)`` on the pattern."""
        return _csr_tensor(self.crow, self.col, values, self.size)

    def transposed(self, values: th.Tensor) -> th.Tensor:
        """The transpose of :meth:`matrix`, as CSR."""
        return _csr_tensor(self.t_crow, self.t_col, values[self.perm], self.size)


def _csr_tensor(crow: th.Tensor, col: th.Tensor, values: th.Tensor, size: int) -> th.Tensor:
    """A square CSR tensor. The indices are built by :func:`csr_graph` from sorted edges, so the
    invariants hold and are not checked (a pass per call); torch's notice that CSR support is in
    beta is silenced here, where the kernel's tests cover what it relies on."""
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message="Sparse CSR tensor support is in beta", category=UserWarning
        )
        return th.sparse_csr_tensor(crow, col, values, (size, size), check_invariants=False)


def csr_graph(adjacency: th.Tensor, distinct: tuple[th.Tensor, th.Tensor] | None = None) -> CSRGraph:
    """The CSR pattern of a batch of adjacencies, self loops added.

    :param distinct: the batch's distinct adjacencies and each map's index among them
        (:func:`~sb3_pm.policies.attention.unique_graphs`), if the caller has them: the edges are
        then found once per distinct graph and copied to its maps, instead of searched in all of
        ``(B, N, N)``.

    Shapes:
        - adjacency: ``(B, N, N)``, ``adjacency[b, i, j] != 0`` meaning "``i`` attends to ``j``"
        - distinct: ``(U, N, N)`` and ``(B,)`` long
    """
    batch, n, _ = adjacency.shape
    device = adjacency.device
    eye = th.eye(n, dtype=th.bool, device=device)
    size = batch * n
    if distinct is None:
        graphs, index = adjacency, th.arange(batch, device=device)
    else:
        graphs, index = distinct
    # Edges of each distinct graph, sorted by (graph, i, j), and their transposed order, sorted by
    # (graph, j, i): a sort over the distinct graphs' edges only, not over the whole batch's.
    g, gi, gj = ((graphs != 0) | eye).nonzero(as_tuple=True)
    per_graph = th.bincount(g, minlength=graphs.shape[0])
    starts = per_graph.cumsum(0) - per_graph
    local_perm = th.argsort((g * n + gj) * n + gi) - starts[g]  # within its graph's edges
    # Copy each map's graph: map b's edges, in its graph's order, follow map b-1's.
    per_map = per_graph[index]  # (B,) edges of each map
    map_start = per_map.cumsum(0) - per_map
    b = th.repeat_interleave(th.arange(batch, device=device), per_map)
    within = th.arange(len(b), device=device) - map_start[b]
    source = starts[index][b] + within  # each edge's entry among the distinct graphs' edges
    row, col = b * n + gi[source], b * n + gj[source]
    crow = th.zeros(size + 1, dtype=th.long, device=device)
    crow[1:] = th.bincount(row, minlength=size).cumsum(0)
    perm = map_start[b] + local_perm[source]  # blocks stay in map order in the transpose too
    t_crow = th.zeros_like(crow)
    t_crow[1:] = th.bincount(col, minlength=size).cumsum(0)
    return CSRGraph(size, crow, col, row, t_crow, row[perm], perm)


class _CSRAggregate(th.autograd.Function):
    """``out = A(values) @ features`` for one head, with a backward pass that builds no per-edge
    feature tensor: ``d features = A^T @ d out`` and ``d values_e = d out[row_e] . features[col_e]``
    (sampled at the pattern by ``torch.sparse.sampled_addmm``)."""

    @staticmethod
    def forward(ctx: Any, values: th.Tensor, features: th.Tensor, graph: CSRGraph) -> th.Tensor:  # type: ignore[override]
        ctx.graph = graph
        ctx.save_for_backward(values, features)
        return graph.matrix(values) @ features

    @staticmethod
    def backward(ctx: Any, grad_out: th.Tensor) -> tuple[th.Tensor | None, th.Tensor | None, None]:  # type: ignore[override]
        values, features = ctx.saved_tensors
        graph: CSRGraph = ctx.graph
        grad_out = grad_out.contiguous()
        grad_values = grad_features = None
        if ctx.needs_input_grad[0]:
            # Only the pattern is sampled (beta=0 still lets NaN values through, so zeros are given).
            pattern = graph.matrix(th.zeros_like(values))
            sampled = th.sparse.sampled_addmm(pattern, grad_out, features.t(), beta=0.0)
            grad_values = sampled.values()
        if ctx.needs_input_grad[1]:
            grad_features = graph.transposed(values) @ grad_out
        return grad_values, grad_features, None


def csr_gat_attention(
    h: th.Tensor,
    a_src: th.Tensor,
    a_dst: th.Tensor,
    graph: CSRGraph,
    negative_slope: float,
    dropout: float = 0.0,
    training: bool = False,
) -> th.Tensor:
    """GAT attention ``out_i = sum_j softmax_j(LeakyReLU(a_dst_i + a_src_j)) h_j`` over the pattern.

    Shapes:
        - h: ``(B*N, heads, C)``; a_src, a_dst: ``(B*N, heads)``
        - output: ``(B*N, heads, C)``
    """
    scores = nn.functional.leaky_relu(a_src[graph.col] + a_dst[graph.row], negative_slope)  # (E, heads)
    alpha = segment_softmax(scores, graph.row, ptr=graph.crow, num_nodes=graph.size)
    alpha = nn.functional.dropout(alpha, p=dropout, training=training)
    heads = [
        _CSRAggregate.apply(alpha[:, k].contiguous(), h[:, k].contiguous(), graph) for k in range(h.shape[1])
    ]
    return th.stack(heads, dim=1)
