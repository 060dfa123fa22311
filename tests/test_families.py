"""Graph families beyond Erdős–Rényi (sb3_pm.graphs.families) and their presets."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from sb3_pm.graphs import (
    FAMILY_PRESETS,
    GraphError,
    from_networkx,
    preset,
    random_geometric,
    random_tree,
    ring_of_cliques,
    rooms,
    small_world,
)


@pytest.mark.parametrize(
    "build",
    [
        lambda seed: random_geometric(40, 0.25, n_targets=5, seed=seed),
        lambda seed: rooms(3, (3, 3), n_targets=4, seed=seed),
        lambda seed: ring_of_cliques(4, 5, n_targets=4, seed=seed),
        lambda seed: from_networkx(nx.karate_club_graph(), n_targets=6, seed=seed, name="karate"),
        lambda seed: small_world(30, 4, 0.2, n_targets=5, seed=seed),
        lambda seed: random_tree(30, n_targets=5, seed=seed),
    ],
    ids=["rgg", "rooms", "cliques", "karate", "small-world", "tree"],
)
def test_seeded_connected_and_deterministic(build) -> None:
    first, again, other = build(1), build(1), build(2)
    assert first.fingerprint == again.fingerprint
    assert first.fingerprint != other.fingerprint
    assert nx.is_connected(first.to_networkx())
    assert not first.adjacency.diagonal().any() and (first.adjacency == first.adjacency.T).all()


def test_rooms_are_joined_by_single_doors() -> None:
    graph = rooms(3, (3, 2), n_targets=2, seed=0)
    size = 6
    cross = graph.adjacency[:size, size:]
    assert cross.sum() == 1 and cross[size - 1, 0]  # the door: room 0's last cell, room 1's first
    # Removing a door disconnects the rooms: a real bottleneck.
    g = graph.to_networkx()
    g.remove_edge(size - 1, size)
    assert not nx.is_connected(g)


def test_ring_of_cliques_structure() -> None:
    graph = ring_of_cliques(5, 4, n_targets=3, seed=0)
    assert graph.n_nodes == 20 and graph.n_targets == 3
    assert graph.n_edges == 5 * 6 + 5  # 5 cliques of 6 edges, 5 ring edges


def test_a_small_world_is_a_ring_lattice_with_few_shortcuts_and_a_tree_has_one_path() -> None:
    lattice = small_world(40, 4, 0.0, n_targets=3, seed=0).to_networkx()
    assert all(degree == 4 for _, degree in lattice.degree())
    assert nx.diameter(lattice) == 10  # 20 nodes away around the ring, 2 per hop
    rewired = small_world(40, 4, 0.1, n_targets=3, seed=0)
    assert rewired.n_edges == 80 and nx.diameter(rewired.to_networkx()) < 10  # shortcuts
    tree = random_tree(40, n_targets=3, seed=0)
    assert tree.n_edges == 39 and nx.is_tree(tree.to_networkx())


def test_presets_resolve_and_have_the_structure_they_claim() -> None:
    diameters = {name: nx.diameter(preset(name).to_networkx()) for name in FAMILY_PRESETS}
    assert diameters["rgg-60"] >= 10 and diameters["rooms-4"] >= 10  # unlike the paper's 3-4 hops
    assert preset("karate").n_nodes == 34
    assert nx.is_tree(preset("tree-50").to_networkx()) and diameters["tree-50"] >= 10
    assert preset("small-world-60").n_edges == 120
    assert nx.diameter(preset("paper-50").to_networkx()) <= 4


def test_bad_input_is_refused() -> None:
    with pytest.raises(GraphError, match="connected"):
        from_networkx(nx.Graph([(0, 1), (2, 3)]), n_targets=1)
    with pytest.raises(GraphError, match="undirected"):
        from_networkx(nx.DiGraph([(0, 1)]), n_targets=1)
    with pytest.raises(GraphError, match="n_targets"):
        rooms(2, (2, 2), n_targets=9)
    with pytest.raises(GraphError, match="even number of neighbours"):
        small_world(20, 3, 0.1, n_targets=2)
    with pytest.raises(GraphError, match="probability"):
        small_world(20, 4, 1.5, n_targets=2)
    with pytest.raises(GraphError, match="at least 2 nodes"):
        random_tree(1, n_targets=1)
    with pytest.raises(GraphError, match="no connected random geometric"):
        random_geometric(30, 0.01, n_targets=2, max_tries=3)
    assert np.isfinite(preset("rooms-4").density)
