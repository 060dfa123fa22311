"""The graph layer of the extractor: a GAT layer.

The layer owns the parameters of a PyTorch Geometric :class:`~torch_geometric.nn.GATConv`, which is
also its sparse kernel, and computes the same function on those parameters as batched dense matrices
when :func:`~sb3_pm.policies.attention.use_dense` says the batch is better served that way
(:mod:`sb3_pm.policies.attention`). Because the parameters are PyG's, the layer's ``state_dict``
does not depend on the kernel that runs.

It takes a batch of maps, node features ``(B, N, F)`` and adjacencies ``(B, N, N)``.
"""

from __future__ import annotations

import torch as th
from torch import nn
from torch_geometric.nn import GATConv

from sb3_pm.errors import InputError
from sb3_pm.policies import neighbour_sum
from sb3_pm.policies.attention import (
    BACKENDS,
    attention_bias,
    attention_probabilities,
    batched_edge_index,
    chunked_attention,
    maps_bias,
    unique_graphs,
    use_chunked,
    use_dense,
)


class GraphAttention(nn.Module):
    """A GAT layer with one parameter set and two kernels (dense / sparse), chosen per call.

    The parameters are those of a :class:`torch_geometric.nn.GATConv`, which is the sparse kernel;
    the dense kernel computes the same function (:class:`torch_geometric.nn.DenseGATConv`'s maths)
    on those parameters in a faster memory layout. Self loops are added by both kernels.

    :param in_channels: input features per node.
    :param out_channels: output features per node (heads are averaged).
    :param heads: attention heads.
    :param backend: ``"auto"``, ``"dense"`` or ``"sparse"``.
    :param custom_kernel: on large graphs, run the dense kernel's attention through the chunked
        custom autograd function (``True``) or through plain autograd (``False``); see
        :func:`~sb3_pm.policies.attention.chunked_attention`. Results are the same either way.

    Shapes:
        - x: ``(B, N, in_channels)``; adjacency: ``(B, N, N)`` (0/1, no self loops needed)
        - output: ``(B, N, out_channels)``
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        heads: int = 1,
        backend: str = "auto",
        custom_kernel: bool = True,
    ) -> None:
        super().__init__()
        if backend not in BACKENDS:
            raise InputError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.in_channels, self.out_channels, self.heads, self.backend = (
            in_channels,
            out_channels,
            heads,
            backend,
        )
        self.custom_kernel = bool(custom_kernel)
        self.conv = GATConv(in_channels, out_channels, heads=heads, concat=False, add_self_loops=True)

    def reset_parameters(self) -> None:
        self.conv.reset_parameters()

    def forward(
        self,
        x: th.Tensor,
        adjacency: th.Tensor | None,
        dense: bool | None = None,
        bias: th.Tensor | tuple[th.Tensor, th.Tensor] | None = None,
        encoding: tuple[th.Tensor, th.Tensor] | None = None,
        edge_index: th.Tensor | None = None,
        target_sorted: neighbour_sum.TargetSortedEdges | None = None,
    ) -> th.Tensor:
        """Attend over ``adjacency`` (plus self loops).

        :param bias: dense kernel: a precomputed
            :func:`~sb3_pm.policies.attention.attention_bias` ``(B, 1, N, N)``, or the biases
            of the batch's distinct adjacencies with each map's index, ``((U, 1, N, N), (B,))``.
        :param encoding: extra input columns given per distinct adjacency, ``((U, N, E), (B,))``:
            the layer's input is then ``[x, encoding[0][encoding[1]]]`` (``in_channels = F + E``),
            and its linear map of the encoding is computed once per distinct adjacency.
        :param edge_index: sparse kernel: the batch's edges ``(2, E)`` long as
            :func:`~sb3_pm.policies.attention.batched_edge_index` gives them (``adjacency`` may
            then be ``None``: maps in the env's edges layout, :mod:`sb3_pm.policies.edges`).
        :param target_sorted: sparse kernel: the same edges with self loops, sorted by target, to
            sum over neighbours by sparse products (:mod:`sb3_pm.policies.neighbour_sum`; the same
            function, rounded otherwise) instead of PyG's gather and scatter.
        """
        if dense is None:
            # an edge list is the sparse kernel's input; an adjacency decides by its density
            sparse_input = edge_index is not None or adjacency is None
            dense = False if sparse_input else use_dense(adjacency, self.backend)  # type: ignore[arg-type]
        if adjacency is None and (edge_index is None if not dense else bias is None):
            raise InputError("GraphAttention needs an adjacency, or an edge_index for the sparse kernel")
        if dense:
            if bias is None:
                assert adjacency is not None
                graphs, index = unique_graphs(adjacency)
                bias = (attention_bias(graphs), index)
            elif isinstance(bias, th.Tensor):
                bias = (bias, th.arange(bias.shape[0], device=bias.device))
            return self._dense(x, *bias, encoding=encoding)
        if encoding is not None:
            x = th.cat((x, encoding[0][encoding[1]]), dim=-1)
        batch, n, _ = x.shape
        if edge_index is None:
            assert adjacency is not None
            edge_index = batched_edge_index(adjacency)
        if target_sorted is not None and neighbour_sum.applies_to(self.conv, self.training):
            out = neighbour_sum.gat_by_products(self.conv, x.reshape(batch * n, -1), target_sorted)
        else:
            out = self.conv(x.reshape(batch * n, -1), edge_index)
        return out.view(batch, n, -1)

    def _project(self, x: th.Tensor, encoding: tuple[th.Tensor, th.Tensor] | None) -> th.Tensor:
        """The layer's linear map ``W [x, encoding]``, ``(B, N, heads * C)``."""
        if encoding is None:
            return self.conv.lin(x)
        weight = self.conv.lin.weight  # (heads * C, F + E); GATConv's lin has no bias
        features = x.shape[-1]
        per_graph = th.matmul(encoding[0], weight[:, features:].t())  # (U, N, heads * C), once per graph
        return nn.functional.linear(x, weight[:, :features]) + per_graph[encoding[1]]

    def _dense(
        self,
        x: th.Tensor,
        bias: th.Tensor,
        index: th.Tensor,
        encoding: tuple[th.Tensor, th.Tensor] | None = None,
    ) -> th.Tensor:
        """GAT attention as batched matrices, laid out ``(B, heads, target, source)``.

        The maths of :class:`~torch_geometric.nn.DenseGATConv`, with the softmax over the last,
        contiguous axis and the adjacency mask added as a precomputed bias (one per distinct
        adjacency, ``bias[index]`` per map, or broadcast when the batch has one adjacency:
        :func:`~sb3_pm.policies.attention.maps_bias`); DenseGATConv's own ``(B, N, N, heads)`` layout spends
        most of its time in ``masked_fill``/``softmax`` over a strided axis.
        """
        conv = self.conv
        batch, n, _ = x.shape
        heads, channels = self.heads, self.out_channels
        h = self._project(x, encoding).view(batch, n, heads, channels).transpose(1, 2).contiguous()
        alpha_src = (h * conv.att_src.view(1, heads, 1, channels)).sum(-1)  # (B, H, N)
        alpha_dst = (h * conv.att_dst.view(1, heads, 1, channels)).sum(-1)
        chunked = use_chunked(batch, heads, n, on_cpu=h.device.type == "cpu")
        if (self.training and conv.dropout > 0) or not chunked:
            # Whole batch at once: attention dropout needs the probabilities, and on small batches
            # recomputing the scores in the backward pass costs more than the memory traffic it saves.
            alpha = attention_probabilities(alpha_dst, alpha_src, maps_bias(bias, index), conv.negative_slope)
            alpha = nn.functional.dropout(alpha, p=conv.dropout, training=self.training)
            out = th.matmul(alpha, h)
        else:
            out = chunked_attention(
                alpha_dst, alpha_src, h, bias, index, conv.negative_slope, custom_kernel=self.custom_kernel
            )
        out = out.mean(1)  # heads averaged (concat=False)
        return out + conv.bias if conv.bias is not None else out

    def __repr__(self) -> str:
        name = type(self).__name__
        kernel = "" if self.custom_kernel else ", custom_kernel=False"
        return (
            f"{name}({self.in_channels}, {self.out_channels}, heads={self.heads}, "
            f"backend={self.backend!r}{kernel})"
        )
