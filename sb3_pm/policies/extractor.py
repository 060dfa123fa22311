"""Graph-attention features extractor over an agent's mental map (docs/METHOD.md "Network of one agent").

The extractor turns one SB3-preprocessed mental-map observation (see
:mod:`sb3_pm.envs.persistent_monitoring`) into per-node embeddings ``H``:

1. node features ``[u, age, target, occupied, self]`` divided by the observation space's highs, so
   every column lies in ``[0, 1]`` whatever ``u_max`` and ``max_cycles`` are;
2. a positional encoding of the *known* adjacency's Laplacian ``L = D - A`` (option ``laplacian``):
   ``"rows"`` (the paper's: node ``m`` gets row ``m`` of ``L``, scaled by the largest degree so its
   entries stay in ``[-1, 1]``), ``"eigen"`` (the ``laplacian_k`` eigenvectors of ``L`` with the
   smallest eigenvalues, sign-fixed) or ``"none"``;
3. with ``derived_features=True``, two derived features per node (projected uncertainty and hop
   closeness, :mod:`sb3_pm.policies.features`);
4. ``gat_layers`` GAT layers over the known adjacency with self loops (ELU between layers, heads
   averaged), then with ``extra_attention=True`` one more single-head GAT layer and one
   graph-transformer layer (the paper's "extra attention" ablation).

Every attention layer keeps one set of parameters and runs either a dense or a sparse kernel,
chosen per call (``backend="auto"``) from the batch's size and density: dense
(:class:`torch_geometric.nn.DenseGATConv` maths) is about 3x faster on 50-200-node graphs at 20%
density on 2 CPU cores, sparse (:class:`torch_geometric.nn.GATConv`) wins below about 5% density.
A discovered adjacency starts very sparse and fills in, so the choice is made per batch rather
than once; both kernels compute the same function (tested), so the choice never changes results
beyond float rounding.

Speed (profiled on 2 CPU cores, ``benchmarks/train_speed.py``): PPO's minibatches hold 250 maps,
and the attention tensors ``(B, heads, N, N)`` are 10 MB on 50 nodes and 160 MB on 200 nodes, so
autograd's dozen elementwise passes over them ran at memory speed. The dense kernel therefore

* computes everything that depends only on the adjacency (the attention mask, the Laplacian and
  its product with the first layer's weights) once per *distinct* adjacency of the batch
  (:func:`unique_graphs`): one agent's known map changes only when it discovers an edge, so a
  rollout holds a few distinct adjacencies, not one per step;
* on large graphs (``heads * N * N >= FUSED_MIN_SCORES``), runs masked softmax attention as one
  autograd function (:class:`_ChunkedAttention`) over chunks of the batch small enough to stay in
  cache, recomputing the scores in the backward pass instead of storing them (as flash attention
  does on GPUs); on small graphs plain autograd is faster.

Sparse maps (a discovered adjacency early in training) on graphs above ``DENSE_MAX_SMALL`` nodes
still run the sparse kernel for PPO's minibatches (200 nodes at 1% density: 256 vs 697 ms per
gradient step), while rollout steps (a few maps) always run dense.
"""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn
from torch_geometric.nn import GATConv, TransformerConv

from sb3_pm.envs.mental_map import U
from sb3_pm.policies.features import DERIVED_FEATURES, derived_node_features

LAPLACIAN_MODES = ("rows", "eigen", "none")
BACKENDS = ("auto", "dense", "sparse")
#: Below this adjacency density (self loops excluded) ``backend="auto"`` runs the sparse kernel.
SPARSE_DENSITY = 0.05
#: Graphs with at most this many nodes always run the dense kernel under ``backend="auto"``: for
#: them the sparse kernel's indexing overhead dominates whatever the density (measured on 2 cores,
#: 50 nodes at 1-6% density, B=250, 1 head: dense 35 ms, sparse 47 ms per PPO gradient step).
DENSE_MAX_SMALL = 64
#: Batches of at most ``UNIQUE_MIN_BATCH`` maps on graphs up to this size always run the dense kernel.
DENSE_MAX_SMALL_BATCH = 256
#: Batches up to this size skip the distinct-adjacency search (a rollout step holds n_envs maps).
UNIQUE_MIN_BATCH = 8


def _use_dense(adjacency: th.Tensor, backend: str) -> bool:
    """Whether to run the dense kernel for this batch of ``(B, N, N)`` adjacencies."""
    if backend != "auto":
        return backend == "dense"
    n = adjacency.shape[-1]
    if n <= DENSE_MAX_SMALL:
        return True
    if adjacency.shape[0] <= UNIQUE_MIN_BATCH and n <= DENSE_MAX_SMALL_BATCH:
        # A rollout step (n_envs maps): the dense kernel's few large ops beat the sparse kernel's
        # indexing at any density (measured, 50 nodes at 1% density: 1.3 vs 1.75 ms per step).
        return True
    density = float(adjacency.sum()) / max(1, adjacency.shape[0] * n * (n - 1))
    return density >= SPARSE_DENSITY


#: Target size, in floats, of one chunk of attention scores ``(chunk, heads, N, N)``: about 0.5 MB,
#: so a chunk's scores, probabilities and gradients stay in a core's L2 cache. Measured on 2 cores:
#: 200 nodes, 4 heads, B=250: chunks of 1-2 maps are 1.65x faster than one pass over the batch.
CHUNK_FLOATS = 131_072
#: The fused kernel runs when one map's scores ``heads * N * N`` reach this size (about 128 nodes at
#: 4 heads): measured 1.65x faster per layer at 200 nodes, 15% slower at 50 nodes.
FUSED_MIN_SCORES = 65_536


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
    # Cheap key first (edge count); one exact comparison confirms that equal keys mean equal graphs.
    counts = flat.sum(-1)
    keys, inverse = th.unique(counts, return_inverse=True)
    first = th.full((len(keys),), batch, dtype=th.long, device=adjacency.device)
    first.scatter_reduce_(0, inverse, th.arange(batch, device=adjacency.device), reduce="amin")
    if bool((flat == flat[first[inverse]]).all()):
        return adjacency[first], inverse
    _, inverse = th.unique(flat, dim=0, return_inverse=True)  # graphs with equal edge counts differ
    first = th.full((int(inverse.max()) + 1,), batch, dtype=th.long, device=adjacency.device)
    first.scatter_reduce_(0, inverse, th.arange(batch, device=adjacency.device), reduce="amin")
    return adjacency[first], inverse


def _attention_chunk(
    a_dst: th.Tensor, a_src: th.Tensor, bias: th.Tensor, slope: float
) -> tuple[th.Tensor, th.Tensor]:
    """Scores before the LeakyReLU and attention probabilities of one chunk.

    Shapes:
        - a_dst, a_src: ``(b, H, N)``; bias: ``(b, 1, N, N)``
        - output: both ``(b, H, N_target, N_source)``
    """
    pre = a_dst.unsqueeze(-1) + a_src.unsqueeze(-2)
    scores = nn.functional.leaky_relu(pre, slope).add_(bias)
    return pre, th.softmax(scores, dim=-1)


class _ChunkedAttention(th.autograd.Function):
    """``softmax_j(LeakyReLU(a_dst_i + a_src_j) + bias_ij) @ h``, in cache-sized chunks of the batch.

    Stores only its (small) inputs; the backward pass recomputes each chunk's probabilities, so no
    ``(B, H, N, N)`` tensor ever exists. Gradients are the exact derivatives of the unfused
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
            _, alpha = _attention_chunk(a_dst[part], a_src[part], bias[index[part]], slope)
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
            pre, alpha = _attention_chunk(a_dst[part], a_src[part], bias[index[part]], slope)
            grad_alpha = th.matmul(grad_out[part], h[part].transpose(-1, -2))
            th.matmul(alpha.transpose(-1, -2), grad_out[part], out=grad_h[part])
            grad_scores = th._softmax_backward_data(grad_alpha, alpha, -1, alpha.dtype)
            grad_pre = th.ops.aten.leaky_relu_backward(grad_scores, pre, slope, False)
            th.sum(grad_pre, dim=-1, out=grad_dst[part])
            th.sum(grad_pre, dim=-2, out=grad_src[part])
        return grad_dst, grad_src, grad_h, None, None, None, None


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


class GraphAttention(nn.Module):
    """A GAT layer with one parameter set and two kernels (dense / sparse), chosen per call.

    The parameters are those of a :class:`torch_geometric.nn.GATConv`, which is the sparse kernel;
    the dense kernel computes the same function (:class:`torch_geometric.nn.DenseGATConv`'s maths)
    on those parameters in a faster memory layout. Self loops are added by both kernels.

    :param in_channels: input features per node.
    :param out_channels: output features per node (heads are averaged).
    :param heads: attention heads.
    :param backend: ``"auto"``, ``"dense"`` or ``"sparse"``.

    Shapes:
        - x: ``(B, N, in_channels)``; adjacency: ``(B, N, N)`` (0/1, no self loops needed)
        - output: ``(B, N, out_channels)``
    """

    def __init__(self, in_channels: int, out_channels: int, heads: int = 1, backend: str = "auto") -> None:
        super().__init__()
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.in_channels, self.out_channels, self.heads, self.backend = (
            in_channels,
            out_channels,
            heads,
            backend,
        )
        self.conv = GATConv(in_channels, out_channels, heads=heads, concat=False, add_self_loops=True)

    def reset_parameters(self) -> None:
        self.conv.reset_parameters()

    def forward(
        self,
        x: th.Tensor,
        adjacency: th.Tensor,
        dense: bool | None = None,
        bias: th.Tensor | tuple[th.Tensor, th.Tensor] | None = None,
        encoding: tuple[th.Tensor, th.Tensor] | None = None,
    ) -> th.Tensor:
        """Attend over ``adjacency`` (plus self loops).

        :param bias: dense kernel: a precomputed :func:`attention_bias` ``(B, 1, N, N)``, or the biases
            of the batch's distinct adjacencies with each map's index, ``((U, 1, N, N), (B,))``.
        :param encoding: extra input columns given per distinct adjacency, ``((U, N, E), (B,))``:
            the layer's input is then ``[x, encoding[0][encoding[1]]]`` (``in_channels = F + E``),
            and its linear map of the encoding is computed once per distinct adjacency.
        """
        if dense is None:
            dense = _use_dense(adjacency, self.backend)
        if dense:
            if bias is None:
                graphs, index = unique_graphs(adjacency)
                bias = (attention_bias(graphs), index)
            elif isinstance(bias, th.Tensor):
                bias = (bias, th.arange(bias.shape[0], device=bias.device))
            return self._dense(x, *bias, encoding=encoding)
        if encoding is not None:
            x = th.cat((x, encoding[0][encoding[1]]), dim=-1)
        batch, n, _ = x.shape
        out = self.conv(x.reshape(batch * n, -1), batched_edge_index(adjacency))
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
        adjacency, ``bias[index]`` per map); profiling on 50-node maps showed DenseGATConv's
        ``(B, N, N, heads)`` layout spending most of its time in ``masked_fill``/``softmax`` over a
        strided axis. The attention itself runs in :class:`_ChunkedAttention`.
        """
        conv = self.conv
        batch, n, _ = x.shape
        heads, channels = self.heads, self.out_channels
        h = self._project(x, encoding).view(batch, n, heads, channels).transpose(1, 2).contiguous()
        alpha_src = (h * conv.att_src.view(1, heads, 1, channels)).sum(-1)  # (B, H, N)
        alpha_dst = (h * conv.att_dst.view(1, heads, 1, channels)).sum(-1)
        if (self.training and conv.dropout > 0) or heads * n * n < FUSED_MIN_SCORES:
            # Unfused: attention dropout needs the probabilities, and on small graphs the scores of a
            # minibatch are cheap enough that recomputing them in the backward pass costs more than
            # the memory traffic it saves (measured: 50 nodes, 4 heads, B=250: 15% slower fused).
            scores = alpha_dst.unsqueeze(-1) + alpha_src.unsqueeze(-2)  # (B, H, N_target, N_source)
            scores = nn.functional.leaky_relu(scores, conv.negative_slope) + bias[index]
            alpha = nn.functional.dropout(th.softmax(scores, dim=-1), p=conv.dropout, training=self.training)
            out = th.matmul(alpha, h)
        else:
            chunk = max(1, CHUNK_FLOATS // (heads * n * n))
            out = _ChunkedAttention.apply(alpha_dst, alpha_src, h, bias, index, conv.negative_slope, chunk)
        out = out.mean(1)  # heads averaged (concat=False)
        return out + conv.bias if conv.bias is not None else out

    def __repr__(self) -> str:
        name = type(self).__name__
        return (
            f"{name}({self.in_channels}, {self.out_channels}, heads={self.heads}, backend={self.backend!r})"
        )


class GraphTransformer(nn.Module):
    """A single-head graph-transformer layer (:class:`torch_geometric.nn.TransformerConv`) with a dense twin.

    ``out_i = W_skip x_i + sum_j softmax_j(q_i . k_j / sqrt(C)) v_j`` over the neighbours ``j`` of
    ``i`` in the given adjacency (no self loops: the skip term carries the node itself). A node with
    no neighbour receives only its skip term in both kernels.

    Shapes:
        - x: ``(B, N, channels)``; adjacency: ``(B, N, N)``
        - output: ``(B, N, channels)``
    """

    def __init__(self, channels: int, backend: str = "auto") -> None:
        super().__init__()
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.channels, self.backend = channels, backend
        self.conv = TransformerConv(channels, channels, heads=1, concat=True, root_weight=True)

    def reset_parameters(self) -> None:
        self.conv.reset_parameters()

    def forward(self, x: th.Tensor, adjacency: th.Tensor, dense: bool | None = None) -> th.Tensor:
        if dense is None:
            dense = _use_dense(adjacency, self.backend)
        batch, n, _ = x.shape
        eye = th.eye(n, dtype=th.bool, device=adjacency.device)
        edges = (adjacency != 0) & ~eye  # TransformerConv adds no self loops; keep both kernels equal
        if not dense:
            return self.conv(x.reshape(batch * n, -1), batched_edge_index(edges)).view(batch, n, -1)
        conv = self.conv
        query, key, value = conv.lin_query(x), conv.lin_key(x), conv.lin_value(x)
        scores = th.matmul(query, key.transpose(1, 2)) / self.channels**0.5  # (B, N, N), [i, j]
        scores = scores.masked_fill(~edges, float("-inf"))
        # A row with no neighbour is all -inf; its softmax is NaN, and its aggregate must be 0.
        alpha = th.nan_to_num(th.softmax(scores, dim=-1), nan=0.0)
        return th.matmul(alpha, value) + conv.lin_skip(x)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.channels}, backend={self.backend!r})"


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


def laplacian_rows(adjacency: th.Tensor) -> th.Tensor:
    """Rows of ``L = D - A`` scaled by each graph's largest degree (entries in ``[-1, 1]``).

    Shapes:
        - adjacency: ``(B, N, N)``
        - output: ``(B, N, N)``
    """
    adjacency = adjacency.float()  # observations may keep the env's int8
    degree = adjacency.sum(-1)  # (B, N)
    laplacian = th.diag_embed(degree) - adjacency
    scale = degree.amax(-1).clamp(min=1.0)[:, None, None]
    return laplacian / scale


def laplacian_eigen(adjacency: th.Tensor, k: int) -> th.Tensor:
    """The ``k`` eigenvectors of ``L = D - A`` with the smallest eigenvalues, one row per node.

    Eigenvectors are defined up to sign; each is flipped so that its largest-magnitude entry is
    positive, which makes the encoding a deterministic function of the graph (up to ties). Graphs
    with fewer than ``k`` nodes are zero-padded.

    Shapes:
        - adjacency: ``(B, N, N)``
        - output: ``(B, N, k)``
    """
    adjacency = adjacency.float()
    laplacian = th.diag_embed(adjacency.sum(-1)) - adjacency
    _, vectors = th.linalg.eigh(laplacian)  # ascending eigenvalues, columns are eigenvectors
    vectors = vectors[..., :k]
    peak = vectors.gather(-2, vectors.abs().argmax(-2, keepdim=True))  # (B, 1, k)
    vectors = vectors * th.where(peak < 0, -1.0, 1.0)
    if vectors.shape[-1] < k:
        vectors = nn.functional.pad(vectors, (0, k - vectors.shape[-1]))
    return vectors


class GATFeaturesExtractor(BaseFeaturesExtractor):
    """Per-node embeddings of a mental map, flattened for SB3.

    :param observation_space: the map observation ``Dict`` (keys ``nodes``, ``adjacency``,
        ``position``, ``dwell``, ``action_mask``).
    :param hidden_dim: embedding size ``h`` per node.
    :param gat_heads: heads of each multi-head GAT layer (averaged, so the width stays ``h``).
    :param gat_layers: number of multi-head GAT layers (at least 1).
    :param laplacian: ``"rows"`` (paper), ``"eigen"`` or ``"none"`` positional encoding.
    :param laplacian_k: eigenvectors kept by ``laplacian="eigen"``.
    :param extra_attention: add one single-head GAT layer and one graph-transformer layer.
    :param backend: ``"auto"`` (per batch, by size and density), ``"dense"`` or ``"sparse"``.
    :param derived_features: append the projected uncertainty and hop closeness of every node
        (:mod:`sb3_pm.policies.features`) to its input features.

    Shapes:
        - input: the preprocessed dict, ``nodes`` ``(B, N, 5)``, ``adjacency`` ``(B, N, N)``,
          ``position`` ``(B, N)`` one-hot
        - output: ``(B, N * hidden_dim)``; :meth:`node_embeddings` gives ``(B, N, hidden_dim)``
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        hidden_dim: int = 32,
        gat_heads: int = 4,
        gat_layers: int = 2,
        laplacian: str = "rows",
        laplacian_k: int = 8,
        extra_attention: bool = False,
        backend: str = "auto",
        derived_features: bool = False,
    ) -> None:
        if laplacian not in LAPLACIAN_MODES:
            raise ValueError(f"laplacian must be one of {LAPLACIAN_MODES}, got {laplacian!r}")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if gat_layers < 1:
            raise ValueError(f"gat_layers must be at least 1, got {gat_layers}")
        nodes_space = observation_space["nodes"]
        if not isinstance(nodes_space, spaces.Box) or len(nodes_space.shape) != 2:
            raise ValueError("GATFeaturesExtractor needs a mental-map observation with a (N, F) 'nodes' Box")
        n_nodes, n_features = nodes_space.shape
        super().__init__(observation_space, features_dim=n_nodes * hidden_dim)
        self.n_nodes, self.hidden_dim, self.laplacian, self.laplacian_k = (
            n_nodes,
            hidden_dim,
            laplacian,
            laplacian_k,
        )
        self.extra_attention, self.backend = extra_attention, backend
        self.derived_features = bool(derived_features)
        self.u_max = float(nodes_space.high[:, U].max())
        self.inv_high: th.Tensor
        # 1 / high per (node, feature): every node column scaled to [0, 1] (highs of 0 left as is).
        high = th.as_tensor(nodes_space.high, dtype=th.float32)
        self.register_buffer("inv_high", th.where(high > 0, 1.0 / high.clamp(min=1e-12), th.ones_like(high)))
        encoding_dim = {"rows": n_nodes, "eigen": laplacian_k, "none": 0}[laplacian]
        in_dim = n_features + encoding_dim + (len(DERIVED_FEATURES) if self.derived_features else 0)
        self.gat = nn.ModuleList(
            GraphAttention(in_dim if i == 0 else hidden_dim, hidden_dim, heads=gat_heads, backend=backend)
            for i in range(gat_layers)
        )
        if extra_attention:
            self.extra_gat: GraphAttention | None = GraphAttention(
                hidden_dim, hidden_dim, heads=1, backend=backend
            )
            self.transformer: GraphTransformer | None = GraphTransformer(hidden_dim, backend=backend)
        else:
            self.extra_gat = self.transformer = None
        self.activation = nn.ELU()
        #: (adjacencies, dense, encoding, bias) of the last gradient-free small batch, see _graph_inputs.
        self._graph_cache: tuple[th.Tensor, bool, th.Tensor | None, th.Tensor | None] | None = None

    def encoding(self, adjacency: th.Tensor) -> th.Tensor | None:
        """The positional encoding of each adjacency, ``(B, N, encoding)`` (``None`` for ``"none"``)."""
        if self.laplacian == "rows":
            return laplacian_rows(adjacency)
        if self.laplacian == "eigen":
            return laplacian_eigen(adjacency, self.laplacian_k)
        return None

    def node_features(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """Normalized node features, then the derived ones if enabled, ``(B, N, 5 [+ 2])``."""
        x = observations["nodes"] * self.inv_high
        if not self.derived_features:
            return x
        derived = derived_node_features(
            observations["nodes"], observations["adjacency"], observations["position"], self.u_max
        )
        return th.cat((x, derived), dim=-1)

    def node_inputs(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """Node features with the positional encoding, ``(B, N, 5 [+ 2] + encoding)``."""
        x = self.node_features(observations)
        encoding = self.encoding(observations["adjacency"])
        return x if encoding is None else th.cat((x, encoding), dim=-1)

    def _graph_inputs(self, graphs: th.Tensor, dense: bool) -> tuple[th.Tensor | None, th.Tensor | None]:
        """Positional encoding and (dense kernel) attention bias of distinct adjacencies.

        During collection (no gradients, a batch of ``n_envs`` maps) an agent's known adjacency
        changes only when it discovers an edge, so the last result is kept and reused while the
        adjacencies are unchanged; with gradients on, nothing is cached (the cached tensors may be
        inference tensors, which autograd refuses to save).

        Shapes:
            - graphs: ``(U, N, N)``
            - output: ``(U, N, encoding)`` or ``None``, ``(U, 1, N, N)`` or ``None``
        """
        cacheable = not th.is_grad_enabled() and graphs.shape[0] <= UNIQUE_MIN_BATCH
        cached = self._graph_cache
        if cacheable and cached is not None and cached[1] == dense and cached[0].shape == graphs.shape:
            if cached[0].dtype == graphs.dtype and th.equal(cached[0], graphs):
                return cached[2], cached[3]
        encoding = self.encoding(graphs)
        bias = attention_bias(graphs) if dense else None
        if cacheable:
            self._graph_cache = (graphs.clone(), dense, encoding, bias)
        return encoding, bias

    def node_embeddings(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """Per-node embeddings ``H``, ``(B, N, hidden_dim)``."""
        adjacency = observations["adjacency"]
        dense = _use_dense(adjacency, self.backend)  # one decision for all layers of this batch
        x = self.node_features(observations)
        # Everything that depends only on the adjacency is computed once per distinct adjacency.
        graphs, index = unique_graphs(adjacency)
        encoding_u, bias_u = self._graph_inputs(graphs, dense)
        encoding = None if encoding_u is None else (encoding_u, index)
        bias = None if bias_u is None else (bias_u, index)  # shared by every GAT layer
        for i, layer in enumerate(self.gat):
            x = self.activation(
                layer(x, adjacency, dense=dense, bias=bias, encoding=encoding if i == 0 else None)
            )
        if self.extra_gat is not None and self.transformer is not None:
            x = self.activation(self.extra_gat(x, adjacency, dense=dense, bias=bias))
            x = self.activation(self.transformer(x, adjacency, dense=dense))
        return x

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:  # type: ignore[override]
        return self.node_embeddings(observations).flatten(1)
