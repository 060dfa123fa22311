"""Positional encodings of a known adjacency, the extra node inputs of the extractor's first layer.

Attention alone cannot tell nodes apart by where they sit in the graph, so each node also gets a
row describing its place in the graph Laplacian ``L = D - A`` of the adjacency the agent knows:

* ``"rows"`` (the paper's): node ``m`` gets row ``m`` of ``L``, scaled by the graph's largest
  degree so its entries stay in ``[-1, 1]`` (:func:`laplacian_rows`);
* ``"none"``: no encoding.
"""

from __future__ import annotations

import torch as th

LAPLACIAN_MODES = ("rows", "none")


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


def encoding_dim(mode: str, n_nodes: int) -> int:
    """Columns the encoding ``mode`` adds per node on a graph of ``n_nodes`` nodes."""
    return {"rows": n_nodes, "none": 0}[mode]


def positional_encoding(adjacency: th.Tensor, mode: str) -> th.Tensor | None:
    """The encoding ``mode`` of each adjacency, ``(B, N, encoding_dim)`` (``None`` for ``"none"``)."""
    if mode == "rows":
        return laplacian_rows(adjacency)
    return None
