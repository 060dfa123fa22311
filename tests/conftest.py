"""Shared fixtures: tiny hand-built graphs and the location of the shared reference graphs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from sb3_pm.graphs import GraphSpec

# Tests run two workers on two cores: one torch thread each avoids oversubscription.
torch.set_num_threads(1)

SHARED_GRAPHS = Path(__file__).resolve().parents[1].parent / "shared" / "graphs"


def path_graph(n_nodes: int, targets: list[int], name: str = "path") -> GraphSpec:
    """0 - 1 - ... - (n-1), with the given target nodes."""
    adjacency = np.zeros((n_nodes, n_nodes), dtype=bool)
    for i in range(n_nodes - 1):
        adjacency[i, i + 1] = adjacency[i + 1, i] = True
    flags = np.zeros(n_nodes, dtype=bool)
    flags[targets] = True
    return GraphSpec(adjacency=adjacency, targets=flags, name=name)


@pytest.fixture
def shared_graphs() -> Path:
    """The paper's published GraphML files (``../shared/graphs``); fails loudly if absent."""
    if not SHARED_GRAPHS.is_dir():
        pytest.fail(f"reference graphs not found at {SHARED_GRAPHS}")
    return SHARED_GRAPHS
