"""The features extractor of the DCBF policy: per-node embeddings ``H`` of one agent's mental map.

It turns one SB3-preprocessed mental-map observation (see :mod:`sb3_pm.envs.persistent_monitoring`)
into embeddings ``(B, N, hidden_dim)``, flattened for SB3 (docs/METHOD.md "Network of one agent"):

1. node features ``[u, age, target, occupied, self]`` divided by the observation space's highs, so
   every column lies in ``[0, 1]`` whatever ``u_max`` and ``max_cycles`` are;
2. a positional encoding of the *known* adjacency (option ``laplacian``,
   :mod:`sb3_pm.policies.encodings`);
3. ``gat_layers`` GAT layers over the known adjacency with self loops (ELU between layers, heads
   averaged); the layer is in :mod:`sb3_pm.policies.layers`.

One kernel choice (dense or sparse, :func:`~sb3_pm.policies.attention.use_dense`) is made per batch
for all layers, and what depends only on the adjacency (encoding, attention mask) is computed once
per distinct adjacency of the batch and shared by the layers.

Maps in the env's edges layout (``edge_index`` and ``edge_mask`` in place of ``adjacency``,
:mod:`sb3_pm.policies.edges`) run the sparse kernel straight on their edge lists when the batch is
sparse and ``laplacian="none"`` (on large sites, :data:`~sb3_pm.policies.edges.LARGE_SITE_NODES`,
summing over neighbours by sparse products, :mod:`sb3_pm.policies.neighbour_sum`); otherwise (the
dense kernel, or the Laplacian encoding, both ``(N, N)`` per map anyway) their dense adjacencies
are built and the batch runs as a dense-layout one. Either way the results are those of the same
maps in the dense layout: bit for bit, except on large sites, where they agree up to rounding.
"""

from __future__ import annotations

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from sb3_pm.errors import InputError
from sb3_pm.policies.attention import BACKENDS, UNIQUE_MIN_BATCH, attention_bias, unique_graphs, use_dense
from sb3_pm.policies.edges import (
    batched_edges,
    dense_adjacency,
    is_edge_layout,
    is_large_site,
    use_dense_edges,
)
from sb3_pm.policies.encodings import LAPLACIAN_MODES, encoding_dim, positional_encoding
from sb3_pm.policies.layers import GraphAttention
from sb3_pm.policies.neighbour_sum import TargetSortedEdges


class GATFeaturesExtractor(BaseFeaturesExtractor):
    """Per-node embeddings of a mental map, flattened for SB3.

    :param observation_space: the map observation ``Dict`` (keys ``nodes``, ``adjacency``,
        ``position``, ``dwell``, ``action_mask``).
    :param hidden_dim: embedding size ``h`` per node.
    :param gat_heads: heads of each multi-head GAT layer (averaged, so the width stays ``h``).
    :param gat_layers: number of multi-head GAT layers (at least 1).
    :param laplacian: ``"rows"`` (paper) or ``"none"`` positional encoding.
    :param backend: ``"auto"`` (per batch, by size and density), ``"dense"`` or ``"sparse"``.
    :param custom_kernel: run large graphs' dense attention through the chunked custom autograd
        kernel (default) or plain autograd (same results, more memory); see
        :func:`~sb3_pm.policies.attention.chunked_attention`. The DCBF policy passes it through
        ``features_extractor_kwargs``.

    Shapes:
        - input: the preprocessed dict, ``nodes`` ``(B, N, F)`` (F = 5, plus one column
          each for the env's ``territory_input`` and ``advice_input``), ``adjacency`` ``(B, N, N)``,
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
        backend: str = "auto",
        custom_kernel: bool = True,
    ) -> None:
        if laplacian not in LAPLACIAN_MODES:
            raise InputError(f"laplacian must be one of {LAPLACIAN_MODES}, got {laplacian!r}")
        if backend not in BACKENDS:
            raise InputError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if gat_layers < 1:
            raise InputError(f"gat_layers must be at least 1, got {gat_layers}")
        nodes_space = observation_space["nodes"]
        if not isinstance(nodes_space, spaces.Box) or len(nodes_space.shape) != 2:
            raise InputError("GATFeaturesExtractor needs a mental-map observation with a (N, F) 'nodes' Box")
        n_nodes, n_features = nodes_space.shape
        super().__init__(observation_space, features_dim=n_nodes * hidden_dim)
        self.n_nodes, self.hidden_dim, self.laplacian = n_nodes, hidden_dim, laplacian
        self.backend = backend
        self.inv_high: th.Tensor
        # 1 / high per (node, feature): every node column scaled to [0, 1] (highs of 0 left as is).
        high = th.as_tensor(nodes_space.high, dtype=th.float32)
        self.register_buffer("inv_high", th.where(high > 0, 1.0 / high.clamp(min=1e-12), th.ones_like(high)))
        in_dim = n_features + encoding_dim(laplacian, n_nodes)
        self.gat = nn.ModuleList(
            GraphAttention(
                in_dim if i == 0 else hidden_dim,
                hidden_dim,
                heads=gat_heads,
                backend=backend,
                custom_kernel=custom_kernel,
            )
            for i in range(gat_layers)
        )
        self.activation = nn.ELU()
        #: (adjacencies, dense, encoding, bias) of the last gradient-free small batch, see _graph_inputs.
        self._graph_cache: tuple[th.Tensor, bool, th.Tensor | None, th.Tensor | None] | None = None

    def encoding(self, adjacency: th.Tensor) -> th.Tensor | None:
        """The positional encoding of each adjacency, ``(B, N, encoding)`` (``None`` for ``"none"``)."""
        return positional_encoding(adjacency, self.laplacian)

    def node_features(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """Node features scaled by the observation space's highs, ``(B, N, F)``."""
        return observations["nodes"] * self.inv_high

    def node_inputs(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """Node features with the positional encoding, ``(B, N, F + encoding)``."""
        x = self.node_features(observations)
        if self.laplacian == "none":
            return x
        encoding = self.encoding(dense_adjacency(observations, self.n_nodes))
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
        """Per-node embeddings ``H``, ``(B, N, hidden_dim)``.

        ``observations`` may carry each map's dense-kernel inputs, computed by the caller:
        ``attention_bias`` ``(B, 1, N, N)`` (:func:`~sb3_pm.policies.attention.attention_bias`) and,
        unless ``laplacian="none"``, ``encoding`` ``(B, N, E)`` (:meth:`encoding`). The dense kernel
        then runs on them, with no decision or search that depends on the values (a team's acting
        pass maps this method over its learners' parameters with ``torch.func.vmap``,
        :mod:`sb3_pm.agents.team_forward`, where such branches cannot run).

        In the edges layout ``observations`` carry ``edge_index`` ``(B, 2, E)`` and ``edge_mask``
        ``(B, E)`` instead of ``adjacency`` (module docstring).
        """
        if is_edge_layout(observations):
            return self._edge_embeddings(observations)
        adjacency = observations["adjacency"]
        x = self.node_features(observations)
        if "attention_bias" in observations:
            dense = True
            index = th.arange(adjacency.shape[0], device=adjacency.device)
            encoding_u, bias_u = observations.get("encoding"), observations["attention_bias"]
            graphs = adjacency
        else:
            dense = use_dense(adjacency, self.backend)  # one decision for all layers of this batch
            # Everything that depends only on the adjacency is computed once per distinct adjacency.
            graphs, index = unique_graphs(adjacency)
            encoding_u, bias_u = self._graph_inputs(graphs, dense)
        encoding = None if encoding_u is None else (encoding_u, index)
        bias = None if bias_u is None else (bias_u, index)  # shared by every GAT layer
        for i, layer in enumerate(self.gat):
            x = self.activation(
                layer(x, adjacency, dense=dense, bias=bias, encoding=encoding if i == 0 else None)
            )
        return x

    def _edge_embeddings(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """:meth:`node_embeddings` of edges-layout maps, ``(B, N, hidden_dim)``."""
        edge_index, edge_mask = observations["edge_index"], observations["edge_mask"]
        if use_dense_edges(edge_mask, self.n_nodes, self.backend) or self.laplacian != "none":
            adjacency = dense_adjacency(observations, self.n_nodes)
            return self.node_embeddings({**observations, "adjacency": adjacency})
        x = self.node_features(observations)
        edges = batched_edges(edge_index, edge_mask, self.n_nodes)  # shared by every GAT layer
        target_sorted = None
        if is_large_site(observations, self.n_nodes):  # sums by sparse products
            target_sorted = TargetSortedEdges.of(edges, x.shape[0] * self.n_nodes)
        for layer in self.gat:
            x = self.activation(layer(x, None, dense=False, edge_index=edges, target_sorted=target_sorted))
        return x

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:  # type: ignore[override]
        return self.node_embeddings(observations).flatten(1)
