"""Territories (sb3_pm/graphs/territories.py): a balanced, deterministic split of the targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sb3_pm.graphs import GraphError, erdos_renyi, resolve_graph
from sb3_pm.graphs.territories import target_territories, territory_nodes
from tests.conftest import path_graph


def test_paper_50_splits_into_its_four_pairs_of_nearby_targets() -> None:
    graph = resolve_graph("paper-50")
    owner = target_territories(graph.hop_distances, graph.target_indices, 4)
    groups = sorted(sorted(graph.target_indices[owner == i].tolist()) for i in range(4))
    assert groups == [[3, 46], [9, 40], [19, 36], [20, 32]]


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("n_agents", [1, 3, 4, 7])
def test_territories_are_balanced_deterministic_and_ordered(seed: int, n_agents: int) -> None:
    graph = erdos_renyi(40, 0.12, 0.25, seed=seed)
    targets = graph.target_indices
    owner = target_territories(graph.hop_distances, targets, n_agents)
    again = target_territories(graph.hop_distances, targets, n_agents)
    np.testing.assert_array_equal(owner, again)
    k = min(n_agents, targets.size)
    sizes = np.bincount(owner, minlength=k)
    assert sizes.size == k and sizes.min() >= targets.size // k and sizes.max() <= math.ceil(targets.size / k)
    # Agent i owns the territory with the i-th lowest target index.
    firsts = [targets[owner == i].min() for i in range(k)]
    assert firsts == sorted(firsts)


def test_fewer_targets_than_agents_leaves_the_last_agents_none() -> None:
    graph = path_graph(6, [1, 4])
    owns = territory_nodes(graph.hop_distances, graph.target_indices, 4, graph.n_nodes)
    assert owns.shape == (4, 6)
    assert owns[0].tolist() == [False, True, False, False, False, False]
    assert owns[1].tolist() == [False, False, False, False, True, False]
    assert not owns[2:].any()


def test_near_targets_share_a_territory() -> None:
    # Two clusters on a path: {0, 1} and {8, 9}; two agents take one cluster each.
    graph = path_graph(10, [0, 1, 8, 9])
    owner = target_territories(graph.hop_distances, graph.target_indices, 2)
    assert owner.tolist() == [0, 0, 1, 1]


def test_the_published_100_node_graph_splits_evenly_among_8_agents() -> None:
    # 17 targets: one territory of 3 and seven of 2, none of 1.
    graph = resolve_graph("paper-100")
    owner = target_territories(graph.hop_distances, graph.target_indices, 8)
    assert sorted(np.bincount(owner).tolist()) == [2] * 7 + [3]


def test_territories_are_ordered_by_their_lowest_target_node_whatever_the_input_order() -> None:
    graph = path_graph(10, [0, 1, 8, 9])
    owner = target_territories(graph.hop_distances, np.array([9, 8, 1, 0]), 2)
    assert owner.tolist() == [1, 1, 0, 0]  # agent 0 owns the territory holding node 0


def test_no_agents_is_an_error() -> None:
    graph = path_graph(4, [1])
    with pytest.raises(GraphError, match="at least one agent"):
        target_territories(graph.hop_distances, graph.target_indices, 0)
