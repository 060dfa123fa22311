"""Large sites (sb3_pm.graphs.large_sites): seeded city, warehouse and campus generators, and their presets.

The default tests stay at 1,000 nodes or fewer: a GraphSpec stores an (N, N) adjacency, and its
hop distances and next hops (computed on first use) are (N, N) too, so no test here touches those.
The 5,000- and 20,000-node presets are built only under ``-m slow``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from sb3_pm.graphs import (
    LARGE_PRESETS,
    PRESETS,
    GraphError,
    GraphSpec,
    campus,
    city_streets,
    preset,
    suggested_agents,
    warehouse,
)
from sb3_pm.graphs.large_sites import _campus_layout

BUILDERS = {
    "city": lambda seed: city_streets(800, seed=seed),
    "warehouse": lambda seed: warehouse(800, seed=seed),
    "campus": lambda seed: campus(800, seed=seed),
}
DENSE_DERIVED = {"hop_distances", "next_hop", "reachable"}


def n_components(spec: GraphSpec) -> int:
    return connected_components(csr_matrix(spec.adjacency), directed=False)[0]


def degrees(spec: GraphSpec) -> np.ndarray:
    return spec.adjacency.sum(axis=1)


def edge_list(spec: GraphSpec) -> np.ndarray:
    matrix = csr_matrix(spec.adjacency).tocoo()
    keep = matrix.row < matrix.col
    return np.stack([matrix.row[keep], matrix.col[keep]], axis=1)


@pytest.mark.parametrize("kind", sorted(BUILDERS))
def test_seeded_connected_and_sized(kind: str) -> None:
    first, again, other = (BUILDERS[kind](seed) for seed in (3, 3, 4))
    assert first.fingerprint == again.fingerprint
    np.testing.assert_array_equal(first.positions, again.positions)
    assert first.fingerprint != other.fingerprint
    # Another seed moves the structure, not only the targets.
    assert not np.array_equal(first.adjacency, other.adjacency)
    assert (first.n_nodes, first.n_targets) == (800, 80)  # one target per 10 nodes by default
    assert n_components(first) == 1
    assert first.positions is not None and np.isfinite(first.positions).all()
    # Nothing (N, N) beyond the adjacency was computed.
    assert not DENSE_DERIVED & set(vars(first))


@pytest.mark.parametrize("build", [city_streets, warehouse, campus], ids=["city", "warehouse", "campus"])
@pytest.mark.parametrize("n_nodes", [173, 1000])
def test_exact_node_and_target_counts(build, n_nodes: int) -> None:
    spec = build(n_nodes, n_targets=7, seed=1)
    assert (spec.n_nodes, spec.n_targets) == (n_nodes, 7)
    assert n_components(spec) == 1


def test_city_degrees_streets_and_avenues() -> None:
    spec = city_streets(1000, seed=2)
    degree = degrees(spec)
    assert 3.0 <= degree.mean() <= 4.0
    assert degree.max() <= 8 and np.mean((degree == 3) | (degree == 4)) > 0.75
    assert spec.positions is not None
    offsets = np.ptp(spec.positions[edge_list(spec)], axis=1)  # (E, 2) |dx|, |dy| per edge
    diagonal = ((offsets > 0.5).all(axis=1)).sum()
    assert diagonal >= 40  # 3 avenues (a 34-column grid) cross much of the city
    plain = city_streets(1000, n_avenues=0, park_fraction=0.0, closed_streets=0.0, seed=2)
    offsets = np.ptp(plain.positions[edge_list(plain)], axis=1)
    assert not (offsets > 0.5).all(axis=1).any()


def test_city_without_parks_closures_or_avenues_is_a_grid() -> None:
    spec = city_streets(100, n_avenues=0, park_fraction=0.0, closed_streets=0.0, seed=0)
    assert spec.n_edges == 2 * 10 * 9  # a 10 x 10 street grid
    closed = city_streets(100, n_avenues=0, park_fraction=0.0, closed_streets=0.3, seed=0)
    assert spec.n_nodes - 1 <= closed.n_edges < spec.n_edges  # closures keep a spanning tree


def test_warehouse_has_long_aisles_and_shelf_targets() -> None:
    spec = warehouse(1000, seed=5)
    degree = degrees(spec)
    assert np.mean(degree == 2) > 0.85  # aisles and cross places: long paths
    assert 2.0 < degree.mean() < 2.3
    assert (degree[spec.target_indices] <= 2).all()  # shelves, never a crossing
    # The longest aisle stretch between cross-aisles: aisles of 45 places, 4 cross rows.
    assert spec.positions is not None
    aisle = spec.positions[:, 0] == 0.0
    rows = np.sort(spec.positions[aisle, 1])
    assert rows.tolist() == list(range(45))


@pytest.mark.parametrize(("cross", "nodes", "edges"), [(0, 34, 35), (1, 36, 39)])
def test_warehouse_counted_by_hand(cross: int, nodes: int, edges: int) -> None:
    # 3 aisles of 10 places (27 aisle edges); each cross row adds 2 places and 4 edges.
    spec = warehouse(nodes, aisle_length=10, n_cross_aisles=cross, n_targets=2, seed=0)
    assert (spec.n_nodes, spec.n_edges) == (nodes, edges)


def test_campus_buildings_are_cut_off_by_few_footpaths() -> None:
    spec = campus(1000, seed=6)
    edges, _, building = _campus_layout(1000, (3, 6), (1, 4), 0.3, np.random.default_rng(6))
    np.testing.assert_array_equal(np.sort(np.sort(edges, axis=1), axis=0), np.sort(edge_list(spec), axis=0))
    assert (building[spec.target_indices] >= 0).all()  # targets are rooms, never footpaths
    n_buildings = building.max() + 1
    assert n_buildings >= 30
    rooms = building >= 0
    # Without the footpaths every building stands alone...
    inside = csr_matrix(spec.adjacency[np.ix_(rooms, rooms)])
    assert connected_components(inside, directed=False)[0] == n_buildings
    # ...and at most four footpaths (one or two edges each end) leave a dense building.
    a, b = building[edges[:, 0]], building[edges[:, 1]]
    for label in range(n_buildings):
        cut = ((a == label) != (b == label)).sum()
        cells = (building == label).sum()
        internal = ((a == label) & (b == label)).sum()
        assert 1 <= cut <= 4
        assert cells < 9 or internal >= 2 * cells - 4  # a box of rooms, not a path
    assert degrees(spec).mean() > 4.0


def test_suggested_agents() -> None:
    assert [suggested_agents(n) for n in (10, 1000, 5000, 20000)] == [1, 12, 62, 250]


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: city_streets(10), "at least 16 nodes"),
        (lambda: city_streets(100, park_fraction=0.7), "park_fraction"),
        (lambda: city_streets(100, n_targets=101), "n_targets"),
        (lambda: warehouse(30, aisle_length=20), "room for 2 aisles"),
        (lambda: warehouse(100, aisle_length=10, n_cross_aisles=8), "n_cross_aisles"),
        (lambda: campus(50), "at least 72 nodes"),
        (lambda: campus(200, building_size=(1, 3)), "building_size"),
        (lambda: campus(200, n_targets=200), "n_targets"),
    ],
)
def test_bad_input_is_refused(call, match: str) -> None:
    with pytest.raises(GraphError, match=match):
        call()


@pytest.mark.parametrize("name", sorted(name for name in LARGE_PRESETS if name.endswith("-1k")))
def test_1k_presets(name: str) -> None:
    spec = preset(name)
    assert (spec.name, spec.n_nodes, spec.n_targets) == (name, 1000, 100)
    assert "1,000 nodes, 100 targets" in PRESETS[name]
    assert not DENSE_DERIVED & set(vars(spec))


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", sorted(name for name in LARGE_PRESETS if not name.endswith("-1k")), ids=lambda name: name
)
def test_large_presets(name: str) -> None:
    """Each 5,000-node preset builds in about a second; ``city-20k`` in about 14 s, and this test
    run alone peaks at about 1.5 GB of memory (measured with ``/usr/bin/time -v``, one thread):
    the dense adjacency is 400 MB, and GraphSpec's checks copy it."""
    spec = build_uncached(name)
    n_nodes = int(name.split("-")[1].removesuffix("k")) * 1000
    assert (spec.name, spec.n_nodes, spec.n_targets) == (name, n_nodes, n_nodes // 10)
    assert f"{n_nodes:,} nodes" in PRESETS[name]
    assert n_components(spec) == 1
    assert 2.0 < degrees(spec).mean() < 6.0
    assert not DENSE_DERIVED & set(vars(spec))


def build_uncached(name: str) -> GraphSpec:
    """The preset, built without :func:`preset`'s cache (which would keep a 20k spec for the session)."""
    return LARGE_PRESETS[name](name)
