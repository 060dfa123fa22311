"""Map observations in the env's edges layout, read by the policy.

With ``layout="edges"`` (:mod:`sb3_pm.envs.known_edges`) a map observation carries, instead of the
known adjacency ``(N, N)``, the graph's directed edge list ``edge_index`` ``(2, E)`` (``[i, j]`` per
edge, sorted by ``i`` then ``j``) and the agent's known edges ``edge_mask`` ``(E,)``. The functions
here turn a batch of them into what the graph layers read:

* :func:`batched_edges`: the sparse kernel's edge list, in exactly the order
  :func:`~sb3_pm.policies.attention.batched_edge_index` lists the same maps' dense adjacencies
  (so the two layouts give the same sums, bit for bit, below :data:`LARGE_SITE_NODES`);
* :func:`edges_to_adjacency`: the dense adjacency, for what needs one (the dense kernel, the
  Laplacian encoding; the neglect bound searches the edge list itself,
  :func:`~sb3_pm.policies.neglect_bound.edge_hop_distances`);
* :func:`use_dense_edges`: :func:`~sb3_pm.policies.attention.use_dense`'s decision from the mask.
"""

from __future__ import annotations

import torch as th

from sb3_pm.policies.attention import dense_by_counts

#: The keys of a map observation in the dense and in the edges layout.
DENSE_MAP_KEYS = ("nodes", "adjacency", "position", "dwell", "action_mask")
EDGE_MAP_KEYS = ("nodes", "edge_index", "edge_mask", "position", "dwell", "action_mask")
#: Nodes per map from which the policy computes edges-layout maps the large-site way: the GAT sums
#: over neighbours by sparse products (:mod:`sb3_pm.policies.neighbour_sum`), and the actor
#: computes logits on the allowed nodes alone (:mod:`sb3_pm.policies.heads` in training,
#: :mod:`sb3_pm.policies.local_pass` when a team acts). The same function, rounded otherwise; below
#: it both layouts give the same results bit for bit, so every recorded training on the published
#: graphs and families repeats.
LARGE_SITE_NODES = 1000


def is_edge_layout(keys: object) -> bool:
    """Whether observations (or an observation space) with these keys are in the edges layout."""
    return "edge_index" in keys and "adjacency" not in keys  # type: ignore[operator]


def _known(edge_index: th.Tensor, edge_mask: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Map, row and column of every known edge, sorted by map then edge.

    Shapes:
        - edge_index: ``(B, 2, E)`` (any real dtype: a rollout buffer stores it as float32);
          edge_mask: ``(B, E)``
        - output: three ``(K,)`` long tensors
    """
    b, k = (edge_mask != 0).nonzero(as_tuple=True)
    index = edge_index.long()
    return b, index[b, 0, k], index[b, 1, k]


def batched_edges(edge_index: th.Tensor, edge_mask: th.Tensor, n_nodes: int) -> th.Tensor:
    """The known edges of a batch of maps as one disjoint union, PyG's ``(2, K)`` ``[source, target]``.

    Edge ``[i, j]`` of map ``b`` is read as "``i`` attends to ``j``", a message from ``b*N + j`` to
    ``b*N + i``, listed in the order of the dense adjacencies' nonzeros.

    Shapes:
        - edge_index: ``(B, 2, E)``; edge_mask: ``(B, E)``
        - output: ``(2, K)`` long
    """
    b, i, j = _known(edge_index, edge_mask)
    return th.stack((b * n_nodes + j, b * n_nodes + i))


def edges_to_adjacency(edge_index: th.Tensor, edge_mask: th.Tensor, n_nodes: int) -> th.Tensor:
    """The known adjacencies ``(B, N, N)`` int8 of a batch of edges-layout maps.

    Shapes:
        - edge_index: ``(B, 2, E)``; edge_mask: ``(B, E)``
        - output: ``(B, N, N)`` int8
    """
    b, i, j = _known(edge_index, edge_mask)
    adjacency = th.zeros((edge_mask.shape[0], n_nodes, n_nodes), dtype=th.int8, device=edge_mask.device)
    adjacency[b, i, j] = 1
    return adjacency


def is_large_site(observations: object, n_nodes: int) -> bool:
    """Whether maps of ``n_nodes`` nodes with these keys take the large-site path
    (:data:`LARGE_SITE_NODES`)."""
    return n_nodes >= LARGE_SITE_NODES and is_edge_layout(observations)


def use_dense_edges(edge_mask: th.Tensor, n_nodes: int, backend: str) -> bool:
    """:func:`~sb3_pm.policies.attention.use_dense` for the maps whose known edges are
    ``edge_mask`` ``(B, E)``: the same decision, from the same counts, without the adjacency."""
    return dense_by_counts(backend, edge_mask.shape[0], n_nodes, lambda: float(th.count_nonzero(edge_mask)))


def dense_adjacency(observations: dict[str, th.Tensor], n_nodes: int) -> th.Tensor:
    """The observations' ``adjacency`` ``(B, N, N)``, built from the edge keys in the edges layout."""
    if "adjacency" in observations:
        return observations["adjacency"]
    return edges_to_adjacency(observations["edge_index"], observations["edge_mask"], n_nodes)


__all__ = [
    "DENSE_MAP_KEYS",
    "EDGE_MAP_KEYS",
    "LARGE_SITE_NODES",
    "batched_edges",
    "dense_adjacency",
    "edges_to_adjacency",
    "is_edge_layout",
    "is_large_site",
    "use_dense_edges",
]
