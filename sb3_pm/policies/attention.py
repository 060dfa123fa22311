"""Attention kernels of the graph layers, and the choice between them.

Every attention layer of :mod:`sb3_pm.policies.layers` computes one function with one set of
parameters, by one of two kernels:

* **sparse**: PyG's message passing over an edge list (:func:`batched_edge_index`), which costs
  time per edge;
* **dense**: batched matrices ``(B, heads, N, N)`` with the adjacency as an additive mask
  (:func:`attention_bias`), which costs time per node pair.

:func:`use_dense` picks one per batch (``backend="auto"``) from the batch's size and density. A
discovered adjacency starts very sparse and fills in as the agent explores, so the choice is made
per batch rather than once. Both kernels compute the same function, so the choice changes results
only by float rounding.

The dense kernel computes what depends only on the adjacency (the mask, the positional encoding)
once per *distinct* adjacency of the batch (:func:`unique_graphs`): an agent's known map changes
only when it discovers an edge, so a rollout holds few distinct adjacencies.

Why a custom kernel: on large graphs a minibatch's attention tensors ``(B, heads, N, N)`` run to
hundreds of megabytes, and autograd stores several of them and passes over each a dozen times.
:class:`_ChunkedAttention` (used through :func:`chunked_attention`) instead walks the batch in
cache-sized chunks, stores only its small inputs and recomputes each chunk's probabilities in the
backward pass, as flash attention does on GPUs. Its backward pass calls two private ATen
functions (``torch._softmax_backward_data``, ``aten.leaky_relu_backward``), the exact derivatives
autograd itself would use. ``custom_kernel=False`` computes the same values and gradients with
ordinary differentiable torch operations, for a torch release without those functions or to check
the kernel.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch as th
from torch import nn

BACKENDS = ("auto", "dense", "sparse")
#: Below this adjacency density (self loops excluded) ``backend="auto"`` runs the sparse kernel.
SPARSE_DENSITY = 0.05
#: Graphs with at most this many nodes always run the dense kernel under ``backend="auto"``: for
#: them the sparse kernel's indexing overhead dominates whatever the density (research/LOG.md §3i).
DENSE_MAX_SMALL = 64
#: Batches of at most ``UNIQUE_MIN_BATCH`` maps on graphs up to this size always run the dense kernel.
DENSE_MAX_SMALL_BATCH = 256
#: Batches up to this size skip the distinct-adjacency search (a rollout step holds n_envs maps).
UNIQUE_MIN_BATCH = 8
#: Target size, in floats, of one chunk of attention scores ``(chunk, heads, N, N)``: about 0.5 MB,
#: so a chunk's scores, probabilities and gradients stay in a core's L2 cache.
CHUNK_FLOATS = 131_072
#: The chunked kernel runs when one map's scores ``heads * N * N`` reach this size (about 128 nodes
#: at 4 heads), whatever the batch; below it, see :data:`FUSED_MIN_BATCH_SCORES`.
FUSED_MIN_SCORES = 65_536
#: ... or, on the CPU, when the whole batch's scores ``B * heads * N * N`` reach this size (16 MB of
#: floats, past the caches): a PPO minibatch of 250 maps on 130 nodes or more at one head. Well
#: below it plain autograd over the whole batch is faster, and between 1M and 4M scores which wins
#: depends on the shape (the timings per shape: research/LOG.md §3i, "The chunked kernel for large
#: minibatches"). On the CPU both paths give the same bits
#: (tests/test_attention_kernels.py trains a team both ways), so the choice changes only the speed.
#: The rule is for CPUs: on a GPU a chunked batch is hundreds of small kernel launches, and neither
#: its speed nor its bits were measured there, so GPU batches keep the per-map rule.
FUSED_MIN_BATCH_SCORES = 4_194_304


def use_chunked(batch: int, heads: int, n: int, on_cpu: bool = True) -> bool:
    """Whether a dense batch of ``batch`` maps, ``heads`` heads and ``n`` nodes runs the chunked
    kernel (:func:`chunked_attention` with ``custom_kernel``) rather than plain autograd; the
    batch's size counts only ``on_cpu``."""
    scores = heads * n * n
    return scores >= FUSED_MIN_SCORES or (on_cpu and batch * scores >= FUSED_MIN_BATCH_SCORES)


def dense_by_counts(backend: str, batch: int, n: int, count_known: Callable[[], float]) -> bool:
    """Whether to run the dense kernel for ``batch`` maps of ``n`` nodes whose known directed edges
    number ``count_known()`` in all (called only when the density decides)."""
    if backend != "auto":
        return backend == "dense"
    if n <= DENSE_MAX_SMALL:
        return True
    if batch <= UNIQUE_MIN_BATCH and n <= DENSE_MAX_SMALL_BATCH:
        # A rollout step (n_envs maps): the dense kernel's few large ops beat the sparse kernel's
        # indexing at any density (measured, 50 nodes at 1% density: 1.3 vs 1.75 ms per step).
        return True
    return count_known() / max(1, batch * n * (n - 1)) >= SPARSE_DENSITY


def use_dense(adjacency: th.Tensor, backend: str) -> bool:
    """Whether to run the dense kernel for this batch of ``(B, N, N)`` adjacencies."""
    # count_nonzero, not sum: a minibatch's adjacency is int8, and its sum widens it to int64 first
    # (a copy of the whole batch). The two agree on 0/1 entries, all the environment emits.
    return dense_by_counts(
        backend, adjacency.shape[0], adjacency.shape[-1], lambda: float(th.count_nonzero(adjacency))
    )


def _graph_keys(flat: th.Tensor) -> th.Tensor:
    """One float64 key per flattened adjacency ``(B, N * N) -> (B,)``: two fixed pseudo-random
    integer weightings of its entries, ``k0 * 2**24 + k1``.

    The weights are small enough that, for 0/1 entries, every partial sum of either weighting is an
    integer below 2**24, so both are exact in float32 whatever order the product sums in, and their
    combination is exact in float64: equal graphs always get equal keys (a float weighting rounds
    differently in different rows of the batch). Distinct graphs share a key only by chance, which
    every caller rules out with an exact comparison. One key per graph keeps the search a 1-D
    ``unique`` (over rows, ``unique`` compares element by element). The weights come from a
    generator of their own, so computing keys draws nothing from torch's global random state.
    """
    size = flat.shape[-1]
    weights = _KEY_WEIGHTS.get((size, flat.device))
    if weights is None:
        generator = th.Generator().manual_seed(size)
        high = max(2, (2**24 - 1) // max(size, 1))  # size * (high - 1) < 2**24
        weights = th.randint(1, high, (size, 2), generator=generator).float().to(flat.device)
        _KEY_WEIGHTS[(size, flat.device)] = weights
    keys = th.matmul(flat if flat.dtype == th.float32 else flat.float(), weights).double()  # (B, 2)
    return keys[:, 0] * 2.0**24 + keys[:, 1]


_KEY_WEIGHTS: dict[tuple[int, th.device], th.Tensor] = {}


def unique_graphs(adjacency: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The distinct adjacencies of a batch and, per map, the index of its adjacency among them.

    Small batches (a rollout step) are returned as they are.

    Shapes:
        - adjacency: ``(B, N, N)``
        - output: ``(U, N, N)`` distinct adjacencies (``U <= B``), ``(B,)`` long index into them
    """
    batch = adjacency.shape[0]
    if batch <= UNIQUE_MIN_BATCH:
        return adjacency, th.arange(batch, device=adjacency.device)
    flat = adjacency.reshape(batch, -1)
    if bool((flat == flat[:1]).all()):
        # One map for the whole batch (a known topology, or a map that stopped growing): a byte
        # comparison instead of the keys' float conversion and product (a tenth of a 200-node train()).
        return adjacency[:1], th.zeros(batch, dtype=th.long, device=adjacency.device)
    arange = th.arange(batch, device=adjacency.device)
    # A cheap key first (a weighted sum, not the edge count: two maps of a rollout often know as
    # many edges but different ones); one exact comparison confirms that equal keys mean equal graphs.
    keys, inverse = th.unique(_graph_keys(flat), return_inverse=True)
    first = th.full((len(keys),), batch, dtype=th.long, device=adjacency.device)
    first.scatter_reduce_(0, inverse, arange, reduce="amin")
    if not bool((flat == flat[first[inverse]]).all()):  # two distinct graphs share a key
        _, inverse = th.unique(flat, dim=0, return_inverse=True)
        first = th.full((int(inverse.max()) + 1,), batch, dtype=th.long, device=adjacency.device)
        first.scatter_reduce_(0, inverse, arange, reduce="amin")
    # Put the distinct graphs in the order earlier releases used (by edge count, or in
    # lexicographic order where two share a count): the batched products that follow round
    # differently when their rows move, and this order keeps trained parameters bit for bit.
    distinct = flat[first]
    counts = distinct.sum(-1)
    if len(th.unique(counts)) == len(counts):
        order = th.argsort(counts)
    else:
        order = th.argsort(th.unique(distinct, dim=0, return_inverse=True)[1])
    rank = th.empty_like(order)
    rank[order] = th.arange(len(order), device=order.device)
    return adjacency[first[order]], rank[inverse]


def attention_bias(adjacency: th.Tensor) -> th.Tensor:
    """Additive attention mask for the dense kernel: 0 on edges and self loops, ``-inf`` elsewhere.

    Shapes:
        - adjacency: ``(B, N, N)``
        - output: ``(B, 1, N, N)``
    """
    n = adjacency.shape[-1]
    eye = th.eye(n, dtype=th.bool, device=adjacency.device)
    allowed = (adjacency != 0) | eye
    zero = th.zeros((), dtype=th.float32, device=adjacency.device)
    return th.where(allowed, zero, float("-inf")).unsqueeze(1)


def batched_edge_index(adjacency: th.Tensor) -> th.Tensor:
    """Edges of a batch of graphs as one disjoint union, PyG's ``(2, E)`` ``[source, target]`` format.

    ``adjacency[b, i, j] != 0`` is read as "``i`` attends to ``j``" (the dense layers' convention),
    i.e. a message from source ``b*N + j`` to target ``b*N + i``.

    Shapes:
        - adjacency: ``(B, N, N)``
        - output: ``(2, E)`` long
    """
    b, i, j = adjacency.nonzero(as_tuple=True)
    n = adjacency.shape[-1]
    return th.stack((b * n + j, b * n + i))


def maps_bias(bias: th.Tensor, index: th.Tensor) -> th.Tensor:
    """Each map's additive mask, ``bias[index]``, or ``bias`` itself when the batch has one adjacency.

    With one distinct adjacency (every map of a known topology) the mask broadcasts over the maps
    instead of being gathered into a ``(B, 1, N, N)`` copy: each score then gets the same addend,
    so the sums are the same bit for bit, without writing and reading that copy (a tenth of a
    200-node ``train()``).

    Shapes:
        - bias: ``(U, 1, N, N)``; index: ``(B,)`` long
        - output: ``(B, 1, N, N)``, or ``(1, 1, N, N)`` when ``U == 1``
    """
    return bias if bias.shape[0] == 1 else bias[index]


def attention_probabilities(a_dst: th.Tensor, a_src: th.Tensor, bias: th.Tensor, slope: float) -> th.Tensor:
    """GAT attention probabilities ``softmax_j(LeakyReLU(a_dst_i + a_src_j) + bias_ij)``, plain autograd.

    Shapes:
        - a_dst, a_src: ``(B, H, N)``; bias: ``(B, 1, N, N)``, or ``(1, 1, N, N)`` for every map
        - output: ``(B, H, N_target, N_source)``
    """
    scores = a_dst.unsqueeze(-1) + a_src.unsqueeze(-2)  # (B, H, N_target, N_source)
    scores = nn.functional.leaky_relu(scores, slope) + bias
    return th.softmax(scores, dim=-1)


def chunked_attention(
    a_dst: th.Tensor,
    a_src: th.Tensor,
    h: th.Tensor,
    bias: th.Tensor,
    index: th.Tensor,
    slope: float,
    chunk: int | None = None,
    custom_kernel: bool = True,
) -> th.Tensor:
    """``softmax_j(LeakyReLU(a_dst_i + a_src_j) + bias[index]_ij) @ h``, the dense kernel's attention.

    :param bias: the additive masks of the batch's distinct adjacencies (:func:`attention_bias`).
    :param index: per map, the index of its adjacency in ``bias``.
    :param slope: the LeakyReLU's negative slope.
    :param chunk: maps per chunk of the custom kernel; by default as many as fit
        :data:`CHUNK_FLOATS`.
    :param custom_kernel: ``True``: :class:`_ChunkedAttention` (chunked, recomputes in the backward
        pass); ``False``: ordinary autograd over the whole batch. Both give the same values and
        gradients up to float rounding.

    Shapes:
        - a_dst, a_src: ``(B, H, N)``; h: ``(B, H, N, C)``
        - bias: ``(U, 1, N, N)``; index: ``(B,)`` long
        - output: ``(B, H, N, C)``
    """
    if not custom_kernel:
        return th.matmul(attention_probabilities(a_dst, a_src, maps_bias(bias, index), slope), h)
    if chunk is None:
        heads, n = h.shape[1], h.shape[2]
        chunk = max(1, CHUNK_FLOATS // (heads * n * n))
    return _ChunkedAttention.apply(a_dst, a_src, h, bias, index, slope, chunk)


def _attention_chunk(
    a_dst: th.Tensor, a_src: th.Tensor, bias: th.Tensor, slope: float
) -> tuple[th.Tensor, th.Tensor]:
    """Scores before the LeakyReLU and attention probabilities of one chunk.

    Shapes:
        - a_dst, a_src: ``(b, H, N)``; bias: ``(b, 1, N, N)``, or ``(1, 1, N, N)`` for every map
        - output: both ``(b, H, N_target, N_source)``
    """
    pre = a_dst.unsqueeze(-1) + a_src.unsqueeze(-2)
    scores = nn.functional.leaky_relu(pre, slope).add_(bias)
    return pre, th.softmax(scores, dim=-1)


class _ChunkedAttention(th.autograd.Function):
    """``softmax_j(LeakyReLU(a_dst_i + a_src_j) + bias_ij) @ h``, in cache-sized chunks of the batch.

    Stores only its (small) inputs; the backward pass recomputes each chunk's probabilities, so no
    ``(B, H, N, N)`` tensor ever exists. Gradients are the exact derivatives of the unchunked
    computation (softmax and LeakyReLU backward are ATen's own kernels).

    Shapes:
        - a_dst, a_src: ``(B, H, N)``; h: ``(B, H, N, C)``
        - bias: ``(U, 1, N, N)`` additive masks of the distinct adjacencies; index: ``(B,)`` long
        - output: ``(B, H, N, C)``
    """

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        a_dst: th.Tensor,
        a_src: th.Tensor,
        h: th.Tensor,
        bias: th.Tensor,
        index: th.Tensor,
        slope: float,
        chunk: int,
    ) -> th.Tensor:
        out = h.new_empty(h.shape)
        for start in range(0, h.shape[0], chunk):
            part = slice(start, start + chunk)
            _, alpha = _attention_chunk(a_dst[part], a_src[part], maps_bias(bias, index[part]), slope)
            th.matmul(alpha, h[part], out=out[part])
        ctx.save_for_backward(a_dst, a_src, h, bias, index)
        ctx.slope, ctx.chunk = slope, chunk
        return out

    @staticmethod
    def backward(ctx: Any, grad_out: th.Tensor) -> tuple[th.Tensor | None, ...]:  # type: ignore[override]
        a_dst, a_src, h, bias, index = ctx.saved_tensors
        slope, chunk = ctx.slope, ctx.chunk
        grad_out = grad_out.contiguous()
        grad_dst, grad_src, grad_h = th.empty_like(a_dst), th.empty_like(a_src), th.empty_like(h)
        for start in range(0, h.shape[0], chunk):
            part = slice(start, start + chunk)
            pre, alpha = _attention_chunk(a_dst[part], a_src[part], maps_bias(bias, index[part]), slope)
            grad_alpha = th.matmul(grad_out[part], h[part].transpose(-1, -2))
            th.matmul(alpha.transpose(-1, -2), grad_out[part], out=grad_h[part])
            grad_scores = th._softmax_backward_data(grad_alpha, alpha, -1, alpha.dtype)
            grad_pre = th.ops.aten.leaky_relu_backward(grad_scores, pre, slope, False)
            th.sum(grad_pre, dim=-1, out=grad_dst[part])
            th.sum(grad_pre, dim=-2, out=grad_src[part])
        return grad_dst, grad_src, grad_h, None, None, None, None
