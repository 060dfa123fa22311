"""The GAT layer's weighted sum over neighbours as sparse matrix products, for large sites.

A GAT layer sums, for every node ``i``, its neighbours' projected features weighted by their
attention: ``out[i] = sum_j alpha_ij h[j]`` over the edges ``j -> i`` and the self loop. PyG's
:class:`~torch_geometric.nn.GATConv` does it edge by edge: it gathers ``h[j]`` into an ``(E, heads,
channels)`` tensor, multiplies it by ``alpha`` and scatters it to the targets, and autograd keeps
the gathered copy for the backward pass. On a minibatch of 250 maps of a 1,000-node site that copy
is about 150 MB per layer and channel block, and the gather and scatter took most of the update.

Here the same sum is a sparse matrix (the attention, in compressed rows by target) times the dense
``h``, per head, and its backward pass is two more sparse products: ``A^T grad`` for ``h`` and the
product ``grad h^T`` sampled at the edges for ``alpha`` (:func:`torch.sparse.sampled_addmm`).
Nothing of size ``(E, channels)`` is kept.

**Same function, other rounding.** The sums run in another order than PyG's, so results agree to
the last bits of float32, not bit for bit (``tests/test_neighbour_sum.py`` compares values and
gradients). To keep every recorded training on the published graphs and families bit for bit,
:class:`~sb3_pm.policies.extractor.GATFeaturesExtractor` takes this path only on large sites in
the env's edges layout (:data:`~sb3_pm.policies.edges.LARGE_SITE_NODES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import torch as th
from torch_geometric.nn import GATConv
from torch_geometric.utils import softmax


@dataclass(frozen=True, eq=False)
class TargetSortedEdges:
    """A batch's edges with one self loop per node, in compressed rows by target and by source.

    :ivar source: ``(E,)`` each edge's source, edges sorted by target then source.
    :ivar target: ``(E,)`` each edge's target, in the same order.
    :ivar target_rows: ``(N + 1,)`` row pointers of the edges by target.
    :ivar n_nodes: ``N``, the nodes of the whole batch.

    The order by source (:attr:`by_source`, :attr:`source_rows`), which only a backward pass reads,
    is sorted on first use: a rollout step without gradients never pays for it.
    """

    source: th.Tensor
    target: th.Tensor
    target_rows: th.Tensor
    n_nodes: int

    @cached_property
    def by_source(self) -> th.Tensor:
        """``(E,)`` the edges' order sorted by source then target."""
        return th.argsort(self.source * self.n_nodes + self.target)

    @cached_property
    def source_rows(self) -> th.Tensor:
        """``(N + 1,)`` row pointers of the edges in :attr:`by_source`'s order."""
        nodes = th.arange(self.n_nodes + 1, device=self.source.device)
        return th.searchsorted(self.source[self.by_source], nodes)

    @cached_property
    def _target_by_source(self) -> th.Tensor:
        """``(E,)`` the targets in :attr:`by_source`'s order: the transposed matrix's columns."""
        return self.target[self.by_source]

    @classmethod
    def of(cls, edge_index: th.Tensor, n_nodes: int) -> TargetSortedEdges:
        """From PyG's ``(2, K)`` ``[source, target]`` edges of ``n_nodes`` nodes (duplicates not
        allowed): self loops are replaced by one per node, as GATConv's ``add_self_loops`` does."""
        source, target = edge_index.long()
        off_diagonal = source != target
        source, target = source[off_diagonal], target[off_diagonal]
        loops = th.arange(n_nodes, device=edge_index.device)
        key, loop_key = target * n_nodes + source, loops * (n_nodes + 1)
        if bool((key[1:] > key[:-1]).all()):
            # already sorted (the env's edge lists are, by map, target, source): merge the loops in
            place = th.empty(key.numel() + n_nodes, dtype=th.long, device=key.device)
            place[th.arange(key.numel(), device=key.device) + th.searchsorted(loop_key, key)] = th.arange(
                key.numel(), device=key.device
            )
            place[loops + th.searchsorted(key, loop_key)] = key.numel() + loops
            order = place
        else:
            order = th.argsort(th.cat((key, loop_key)))
        source, target = th.cat((source, loops))[order], th.cat((target, loops))[order]
        nodes = th.arange(n_nodes + 1, device=edge_index.device)
        return cls(source=source, target=target, target_rows=th.searchsorted(target, nodes), n_nodes=n_nodes)

    def matrix(self, values: th.Tensor, transposed: bool = False) -> th.Tensor:
        """The ``(N, N)`` sparse CSR matrix with ``values`` ``(E,)`` at ``[target, source]``, or at
        ``[source, target]`` when ``transposed``."""
        if transposed:
            rows, columns, values = self.source_rows, self._target_by_source, values[self.by_source]
        else:
            rows, columns = self.target_rows, self.source
        # torch warns once per process that CSR tensors are a beta feature; silencing it here
        # would change the process's warning filters from the learners' threads
        size = (self.n_nodes, self.n_nodes)
        return th.sparse_csr_tensor(rows, columns, values, size=size, check_invariants=False)


class _NeighbourSum(th.autograd.Function):
    """``out[:, k] = A_k h[:, k]`` per head ``k``, ``A_k`` the attention ``alpha[:, k]`` at the edges."""

    @staticmethod
    def forward(ctx, alpha: th.Tensor, h: th.Tensor, edges: TargetSortedEdges) -> th.Tensor:  # type: ignore[override]
        ctx.save_for_backward(alpha, h)
        ctx.edges = edges
        heads = h.shape[1]
        return th.stack([edges.matrix(alpha[:, k]) @ h[:, k] for k in range(heads)], dim=1)

    @staticmethod
    def backward(ctx, grad: th.Tensor) -> tuple[th.Tensor | None, th.Tensor | None, None]:  # type: ignore[override]
        alpha, h = ctx.saved_tensors
        edges: TargetSortedEdges = ctx.edges
        heads = h.shape[1]
        grad = grad.contiguous()
        grad_alpha = grad_h = None
        if ctx.needs_input_grad[1]:
            grad_h = th.stack(
                [edges.matrix(alpha[:, k], transposed=True) @ grad[:, k] for k in range(heads)], dim=1
            )
        if ctx.needs_input_grad[0]:
            # d out[i] / d alpha_ij = h[j]: the gradient is grad[i] . h[j] at each edge (i <- j)
            grad_alpha = th.stack(
                [
                    th.sparse.sampled_addmm(
                        edges.matrix(alpha[:, k]), grad[:, k], h[:, k].t(), beta=0.0
                    ).values()
                    for k in range(heads)
                ],
                dim=1,
            )
        return grad_alpha, grad_h, None


def neighbour_sum(alpha: th.Tensor, h: th.Tensor, edges: TargetSortedEdges) -> th.Tensor:
    """``sum_j alpha_ij h[j]`` for every node ``i``, per head.

    Shapes:
        - alpha: ``(E, heads)`` in ``edges``' order; h: ``(N, heads, channels)``
        - output: ``(N, heads, channels)``
    """
    return _NeighbourSum.apply(alpha, h.contiguous(), edges)  # type: ignore[no-any-return]


def gat_by_products(conv: GATConv, x: th.Tensor, edges: TargetSortedEdges) -> th.Tensor:
    """A :class:`~torch_geometric.nn.GATConv` for which :func:`applies_to` holds, on ``x``, its
    weighted sum by :func:`neighbour_sum`.

    Shapes:
        - x: ``(N, in_channels)``
        - output: ``(N, out_channels)``
    """
    heads, channels = conv.heads, conv.out_channels
    h = conv.lin(x).view(-1, heads, channels)
    # (N, heads) each, by products rather than through an (N, heads, channels) temporary
    score_source = th.einsum("nhc,hc->nh", h, conv.att_src[0])
    score_target = th.einsum("nhc,hc->nh", h, conv.att_dst[0])
    scores = score_source[edges.source] + score_target[edges.target]  # (E, heads)
    scores = th.nn.functional.leaky_relu(scores, conv.negative_slope)
    alpha = softmax(scores, edges.target, num_nodes=edges.n_nodes)  # (E, heads)
    summed = neighbour_sum(alpha, h, edges)
    out = summed[:, 0] if heads == 1 else summed.mean(1)  # one head: its mean is itself, uncopied
    return out + conv.bias if conv.bias is not None else out


def applies_to(conv: GATConv, training: bool) -> bool:
    """Whether :func:`gat_by_products` computes ``conv``'s function: heads averaged, one self loop
    per node added, one projection for sources and targets, no attention dropout while training,
    no residual, no edge features."""
    return (
        not conv.concat
        and bool(conv.add_self_loops)
        and getattr(conv, "lin", None) is not None
        and not (training and conv.dropout > 0)
        and getattr(conv, "res", None) is None
        and getattr(conv, "lin_edge", None) is None
    )


__all__ = ["TargetSortedEdges", "applies_to", "gat_by_products", "neighbour_sum"]
