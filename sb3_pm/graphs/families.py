"""Graph families beyond Erdős–Rényi, for testing a method on structures unlike the paper's.

The paper's graphs are dense G(N, 0.2) draws of small diameter (2 to 4 hops), where any agent
reaches any target in a few steps. Robots patrol buildings, corridors and road networks instead;
these generators give seeded graphs with the structures that make patrolling hard:

* :func:`random_geometric`: nodes in the unit square joined within a radius (sparse, spatial,
  large diameter);
* :func:`rooms`: the paper's Algorithm 1 boxes (rooms) in a row, each joined to the next by one
  door edge (bottlenecks between dense rooms);
* :func:`ring_of_cliques`: cliques joined in a ring by single edges;
* :func:`small_world`: a ring lattice with a few edges rewired into shortcuts (Watts–Strogatz);
* :func:`random_tree`: a uniformly random labelled tree (corridors with dead ends, one path
  between any two nodes);
* :func:`from_networkx`: any connected NetworkX graph with seeded targets, e.g. Zachary's karate
  club (a real social network's shape).

NetworkX builds them once; nothing here is on the environment's per-step path.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_pm.graphs.generators import hyperrectangle
from sb3_pm.graphs.spec import GraphError, GraphSpec


def _targets(n_nodes: int, n_targets: int, rng: np.random.Generator) -> np.ndarray:
    if not 1 <= n_targets <= n_nodes:
        raise GraphError(f"n_targets must be in [1, {n_nodes}], got {n_targets}")
    flags = np.zeros(n_nodes, dtype=bool)
    flags[rng.choice(n_nodes, size=n_targets, replace=False)] = True
    return flags


def from_networkx(graph: Any, n_targets: int, seed: int = 0, name: str | None = None) -> GraphSpec:
    """A connected, undirected NetworkX graph (nodes relabelled ``0..N-1`` in their order) with
    ``n_targets`` targets drawn uniformly with ``seed``; node ``pos`` attributes are kept for drawing.

    :raises GraphError: a directed or disconnected graph.
    """
    import networkx as nx

    if graph.is_directed():
        raise GraphError("from_networkx needs an undirected graph")
    if graph.number_of_nodes() < 2 or not nx.is_connected(graph):
        raise GraphError("from_networkx needs a connected graph with at least 2 nodes")
    nodes = list(graph.nodes)
    adjacency = nx.to_numpy_array(graph, nodelist=nodes, weight=None) > 0
    np.fill_diagonal(adjacency, False)
    positions = None
    if all("pos" in graph.nodes[node] for node in nodes):
        positions = np.array([graph.nodes[node]["pos"] for node in nodes], dtype=float)
    flags = _targets(len(nodes), n_targets, np.random.default_rng(seed))
    return GraphSpec(
        adjacency=adjacency, targets=flags, name=name or graph.name or "graph", positions=positions
    )


def random_geometric(
    n_nodes: int, radius: float, n_targets: int, seed: int = 0, name: str | None = None, max_tries: int = 1000
) -> GraphSpec:
    """Nodes uniform in the unit square, joined when closer than ``radius``; redrawn until connected.

    :raises GraphError: no connected draw in ``max_tries`` (raise the radius).
    """
    import networkx as nx

    rng = np.random.default_rng(seed)
    for _ in range(max_tries):
        points = rng.random((n_nodes, 2))
        graph = nx.random_geometric_graph(n_nodes, radius, pos={i: tuple(p) for i, p in enumerate(points)})
        if nx.is_connected(graph):
            label = name or f"rgg-{n_nodes}-r{radius:g}-s{seed}"
            return from_networkx(graph, n_targets, seed=int(rng.integers(2**31)), name=label)
    raise GraphError(
        f"no connected random geometric graph ({n_nodes} nodes, radius {radius}) in {max_tries} draws"
    )


def rooms(
    n_rooms: int, room_cells: tuple[int, int], n_targets: int, seed: int = 0, name: str | None = None
) -> GraphSpec:
    """``n_rooms`` Algorithm 1 boxes of ``room_cells`` cells in a row, room ``r``'s last cell joined
    to room ``r + 1``'s first by one door edge.

    :raises GraphError: fewer than 2 rooms.
    """
    if n_rooms < 2:
        raise GraphError(f"rooms needs at least 2 rooms, got {n_rooms}")
    room = hyperrectangle(lengths=room_cells, chunk_sizes=(1, 1), targets=[0])
    size = room.n_nodes
    adjacency = np.zeros((n_rooms * size, n_rooms * size), dtype=bool)
    positions = np.zeros((n_rooms * size, 2))
    assert room.positions is not None
    for r in range(n_rooms):
        block = slice(r * size, (r + 1) * size)
        adjacency[block, block] = room.adjacency
        positions[block] = room.positions + np.array([r * (room_cells[0] + 1.0), 0.0])
        if r + 1 < n_rooms:  # the door: last cell of this room, first cell of the next
            a, b = (r + 1) * size - 1, (r + 1) * size
            adjacency[a, b] = adjacency[b, a] = True
    flags = _targets(n_rooms * size, n_targets, np.random.default_rng(seed))
    label = name or f"rooms-{n_rooms}x{room_cells[0]}x{room_cells[1]}-s{seed}"
    return GraphSpec(adjacency=adjacency, targets=flags, name=label, positions=positions)


def ring_of_cliques(
    n_cliques: int, clique_size: int, n_targets: int, seed: int = 0, name: str | None = None
) -> GraphSpec:
    """``n_cliques`` cliques of ``clique_size`` nodes joined in a ring by single edges."""
    import networkx as nx

    if n_cliques < 2 or clique_size < 2:
        raise GraphError(
            f"ring_of_cliques needs at least 2 cliques of 2 nodes, got {n_cliques} x {clique_size}"
        )
    graph = nx.ring_of_cliques(n_cliques, clique_size)
    label = name or f"cliques-{n_cliques}x{clique_size}-s{seed}"
    return from_networkx(graph, n_targets, seed=seed, name=label)


def small_world(
    n_nodes: int, neighbours: int, rewire: float, n_targets: int, seed: int = 0, name: str | None = None
) -> GraphSpec:
    """A Watts–Strogatz graph: a ring where each node is joined to its ``neighbours`` nearest, each
    edge rewired with probability ``rewire``; redrawn (by NetworkX) until connected.

    :raises GraphError: ``neighbours`` not even and in ``[2, n_nodes)``, or ``rewire`` not in [0, 1].
    """
    import networkx as nx

    if neighbours % 2 or not 2 <= neighbours < n_nodes:
        raise GraphError(
            f"small_world needs an even number of neighbours in [2, {n_nodes}), got {neighbours}"
        )
    if not 0.0 <= rewire <= 1.0:
        raise GraphError(f"small_world's rewire must be a probability, got {rewire}")
    rng = np.random.default_rng(seed)
    graph = nx.connected_watts_strogatz_graph(
        n_nodes, neighbours, rewire, tries=1000, seed=int(rng.integers(2**31))
    )
    label = name or f"small-world-{n_nodes}-k{neighbours}-p{rewire:g}-s{seed}"
    return from_networkx(graph, n_targets, seed=int(rng.integers(2**31)), name=label)


def random_tree(n_nodes: int, n_targets: int, seed: int = 0, name: str | None = None) -> GraphSpec:
    """A labelled tree drawn uniformly among those on ``n_nodes`` nodes.

    :raises GraphError: fewer than 2 nodes.
    """
    import networkx as nx

    if n_nodes < 2:
        raise GraphError(f"random_tree needs at least 2 nodes, got {n_nodes}")
    rng = np.random.default_rng(seed)
    graph = nx.random_labeled_tree(n_nodes, seed=int(rng.integers(2**31)))
    label = name or f"tree-{n_nodes}-s{seed}"
    return from_networkx(graph, n_targets, seed=int(rng.integers(2**31)), name=label)


__all__ = ["from_networkx", "random_geometric", "random_tree", "ring_of_cliques", "rooms", "small_world"]
