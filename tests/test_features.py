"""Breadth-first hop distances over a known adjacency (:mod:`sb3_pm.policies.features`)."""

from __future__ import annotations

import networkx as nx
import numpy as np
import torch as th

from sb3_pm.policies.features import hop_distances


def test_hop_distances_match_networkx_including_unreachable_nodes() -> None:
    rng = np.random.default_rng(0)
    n, batch = 15, 6
    adjacency = np.zeros((batch, n, n), dtype=np.int8)
    for b in range(batch):
        upper = np.triu(rng.random((n, n)) < 0.12, 1)  # sparse: several components
        adjacency[b] = upper | upper.T
    starts = rng.integers(0, n, size=batch)
    start = np.eye(n, dtype=np.float32)[starts]
    got = hop_distances(th.as_tensor(adjacency), th.as_tensor(start)).numpy()
    for b in range(batch):
        lengths = nx.single_source_shortest_path_length(nx.from_numpy_array(adjacency[b]), int(starts[b]))
        expected = np.array([lengths.get(m, -1) for m in range(n)])
        np.testing.assert_array_equal(got[b], expected)


def test_hop_distances_on_an_empty_graph_reach_only_the_start() -> None:
    start = th.zeros(1, 4)
    start[0, 2] = 1.0
    assert hop_distances(th.zeros(1, 4, 4), start).tolist() == [[-1, -1, 0, -1]]
