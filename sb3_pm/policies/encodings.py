"""Positional encodings of a known adjacency, the extra node inputs of the extractor's first layer.

Attention alone cannot tell nodes apart by where they sit in the graph, so each node also gets a
row describing its place in the graph Laplacian ``L = D - A`` of the adjacency the agent knows:

* ``"rows"`` (the paper's): node ``m`` gets row ``m`` of ``L``, scaled by the graph's largest
  degree so its entries stay in ``[-1, 1]`` (:func:`laplacian_rows`);
* ``"eigen"``: the ``k`` eigenvectors of ``L`` with the smallest eigenvalues, sign-fixed
  (:func:`laplacian_eigen`);
* ``"none"``: no encoding.
"""

from __future__ import annotations

import torch as th
from torch import nn

LAPLACIAN_MODES = ("rows", "eigen", "none")


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


def encoding_dim(mode: str, n_nodes: int, k: int) -> int:
    """Columns the encoding ``mode`` adds per node on a graph of ``n_nodes`` nodes."""
    return {"rows": n_nodes, "eigen": k, "none": 0}[mode]


def positional_encoding(adjacency: th.Tensor, mode: str, k: int) -> th.Tensor | None:
    """The encoding ``mode`` of each adjacency, ``(B, N, encoding_dim)`` (``None`` for ``"none"``)."""
    if mode == "rows":
        return laplacian_rows(adjacency)
    if mode == "eigen":
        return laplacian_eigen(adjacency, k)
    return None
