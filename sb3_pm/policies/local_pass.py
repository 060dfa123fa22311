"""The actor's logits on the allowed nodes alone, from the few hops around them (large sites).

Acting needs a logit only where the DCBF mask allows a move: sb3-contrib's masked distribution
replaces every other logit by its mask constant before it normalizes, so neither the most likely
action nor a draw reads them. An allowed node's logit depends on its embedding and on the own
node's, and after ``L`` GAT layers an embedding depends only on the nodes within ``L`` hops over
the map's known edges (each layer attends over a node's in-neighbours and itself). So on a
5,000-node site, where a full pass embeds all ``N`` nodes of each of 64 maps for the sake of about
five allowed nodes per map, :func:`allowed_logits` runs the policy's own GAT layers on the
``L``-hop neighbourhoods of the allowed and own nodes only, and the policy's own actor on the
allowed rows.

**Same logits up to rounding, not bit for bit.** The subgraph keeps every edge into each node whose
output is used, in the full pass's order, so every attention softmax and sum runs over the same
terms in the same order; but the matrix products run on fewer rows, which torch's CPU kernels may
block (and round) differently: a logit can differ from the full pass's in the last units of its
precision (``tests/test_large_deploy.py`` compares them), so a most likely action or a draw can
differ only where two allowed logits are that close. The env's edges layout is where deployment
takes this path (:func:`~sb3_pm.agents.deployment.rule._grouped_actions`); the dense layout keeps
its bit-for-bit full pass.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch as th

from sb3_pm.policies.edges import is_large_site
from sb3_pm.policies.heads import own_positions


def applies(policy: Any, pre: dict[str, th.Tensor]) -> bool:
    """Whether :func:`allowed_logits` may stand for ``policy``'s full pass on ``pre``: edges-layout
    maps of a large site (:data:`~sb3_pm.policies.edges.LARGE_SITE_NODES`), a GAT without the
    Laplacian encoding (which reads the whole adjacency)."""
    extractor = getattr(policy, "features_extractor", None)
    return (
        is_large_site(pre, getattr(policy, "n_nodes", 0))
        and getattr(extractor, "laplacian", None) == "none"
        and hasattr(extractor, "gat")
    )


def allowed_logits(policy: Any, pre: dict[str, th.Tensor], u_hat: th.Tensor, masks: th.Tensor) -> th.Tensor:
    """``policy``'s logits on the nodes ``masks`` allows, from their neighbourhoods (module
    docstring); 0 on the others, which the masked distribution never reads.

    Shapes:
        - pre: preprocessed edges-layout maps (``nodes`` ``(B, N, F)``, ``edge_index``
          ``(B, 2, E)``, ``edge_mask`` ``(B, E)``, ``position_index`` ``(B,)``); u_hat: ``(B, N)``;
          masks: ``(B, N)`` bool
        - output: ``(B, N)``
    """
    extractor = policy.features_extractor
    batch, n = masks.shape
    device = masks.device
    own = th.arange(batch, device=device) * n + own_positions(pre)  # (B,)
    rows = masks.reshape(-1).nonzero().squeeze(-1)  # (R,) the allowed nodes, global ids
    need = th.unique(th.cat((rows, own)))  # sorted global ids whose last-layer output is used
    edges_of = _shared_edges(pre) if _one_edge_list(pre["edge_index"]) else _all_edges(pre, n)
    # need_l: the nodes whose layer-(L - l) output is used; the edges into need_(L-1) are every
    # edge a used output reads.
    for _ in extractor.gat:
        target, source = edges_of(need)
        kept_target, kept_source = target, source
        need = th.unique(th.cat((need, source)))
    nodes = need  # (M,) global ids of the subgraph, sorted: the full pass's order
    local = th.full((batch * n,), -1, dtype=th.long, device=device)
    local[nodes] = th.arange(nodes.numel(), device=device)
    edges = th.stack((local[kept_source], local[kept_target]))  # (2, K'), PyG's [source, target]
    x = extractor.node_features(pre).reshape(batch * n, -1)[nodes]  # (M, F)
    for layer in extractor.gat:  # GraphAttention's sparse kernel on the subgraph
        x = extractor.activation(layer.conv(x, edges))
    own_embedding = x[local[own]]  # (B, h)
    return policy._allowed_logits(x[local[rows]], own_embedding, u_hat, rows, pre)  # type: ignore[no-any-return]


def _one_edge_list(edge_index: th.Tensor) -> bool:
    """Whether every map of the batch carries the same edge list ``(B, 2, E)`` (the env's: the
    graph's own, sorted by source then target)."""
    return bool((edge_index == edge_index[:1]).all())


EdgeFinder = Callable[[th.Tensor], tuple[th.Tensor, th.Tensor]]


def _shared_edges(pre: dict[str, th.Tensor]) -> EdgeFinder:
    """The known edges into given nodes, found through the shared edge list's row pointers: the
    work grows with the nodes asked about, not with the batch's ``B * E`` edges.

    The returned function maps sorted global node ids ``(S,)`` to the ``(target, source)`` global
    ids of every known edge into them, ``(K,)`` each, sorted by map then edge (the full pass's
    order, :func:`~sb3_pm.policies.edges.batched_edges`).
    """
    index = pre["edge_index"][0].long()  # (2, E), sorted by its first row
    mask = pre["edge_mask"]
    n = pre["nodes"].shape[1]
    pointer = th.searchsorted(index[0].contiguous(), th.arange(n + 1, device=index.device))  # (N + 1,)

    def find(nodes: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        maps, node = nodes // n, nodes % n
        start, count = pointer[node], pointer[node + 1] - pointer[node]
        owner = th.repeat_interleave(th.arange(nodes.numel(), device=nodes.device), count)
        offset = th.arange(owner.numel(), device=nodes.device) - (th.cumsum(count, 0) - count)[owner]
        edge, of_map = start[owner] + offset, maps[owner]
        known = mask[of_map, edge] != 0
        edge, of_map = edge[known], of_map[known]
        # sorted nodes give edges sorted by map, then node, then edge: the full pass's order
        return of_map * n + index[0, edge], of_map * n + index[1, edge]

    return find


def _all_edges(pre: dict[str, th.Tensor], n: int) -> EdgeFinder:
    """:func:`_shared_edges` for maps with edge lists of their own: every known edge of the batch,
    filtered by its target (``O(B * E)`` per call)."""
    b, k = (pre["edge_mask"] != 0).nonzero(as_tuple=True)
    index = pre["edge_index"].long()
    target, source = b * n + index[b, 0, k], b * n + index[b, 1, k]

    def find(nodes: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        wanted = th.zeros(pre["edge_mask"].shape[0] * n, dtype=th.bool, device=nodes.device)
        wanted[nodes] = True
        kept = wanted[target]
        return target[kept], source[kept]

    return find


__all__ = ["allowed_logits", "applies"]
