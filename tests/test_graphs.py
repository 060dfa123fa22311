"""Graph layer: generators, Algorithm 1, GraphML I/O and every bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sb3_pm.graphs import (
    ER_PRESETS,
    FAMILY_PRESETS,
    LARGE_PRESETS,
    PRESETS,
    PUBLISHED,
    GraphError,
    GraphSpec,
    erdos_renyi,
    hyperrectangle,
    load_graphml,
    preset,
    published_graph_path,
    resolve_graph,
    save_graphml,
)
from tests.conftest import path_graph


def king_edges(counts: tuple[int, ...]) -> int:
    """Edges of the n-D king graph: each cell touches prod(3)-1 offsets, halved, minus the border."""
    return (math.prod(3 * c - 2 for c in counts) - math.prod(counts)) // 2


class TestErdosRenyi:
    def test_connected_with_exact_targets(self) -> None:
        spec = erdos_renyi(40, 0.2, n_targets=7, seed=3)
        assert spec.n_nodes == 40 and spec.n_targets == 7
        assert (spec.hop_distances >= 0).all()  # connected: every distance finite

    def test_seeded(self) -> None:
        a, b, c = erdos_renyi(30, 0.2, seed=1), erdos_renyi(30, 0.2, seed=1), erdos_renyi(30, 0.2, seed=2)
        assert a.same_problem(b)
        assert not a.same_problem(c)

    def test_target_probability(self) -> None:
        spec = erdos_renyi(200, 0.2, target_prob=0.16, seed=0)
        assert 0.08 < spec.n_targets / 200 < 0.26

    def test_sparse_draw_is_redrawn_until_connected(self) -> None:
        spec = erdos_renyi(12, 0.25, n_targets=2, seed=0)
        assert spec.n_nodes == 12

    def test_hopeless_probability_gives_clear_error(self) -> None:
        with pytest.raises(GraphError, match="no connected"):
            erdos_renyi(50, 0.001, n_targets=2, seed=0, max_tries=5)

    @pytest.mark.parametrize("name", sorted(ER_PRESETS))
    def test_er_presets(self, name: str) -> None:
        n_nodes, n_targets, seed = ER_PRESETS[name]
        spec = preset(name)
        assert (spec.n_nodes, spec.n_targets, spec.name) == (n_nodes, n_targets, name)
        assert spec.same_problem(erdos_renyi(n_nodes, 0.2, n_targets=n_targets, seed=seed))


class TestPresets:
    @pytest.mark.parametrize(
        ("name", "nodes", "edges", "targets"),
        [("paper-50", 50, 258, 8), ("paper-100", 100, 934, 17), ("paper-200", 200, 3695, 41)],
    )
    def test_paper_presets_are_the_published_files(self, published_graphs, name, nodes, edges, targets):
        spec = preset(name)
        assert (spec.n_nodes, spec.n_edges, spec.n_targets, spec.name) == (nodes, edges, targets, name)
        assert spec.same_problem(load_graphml(published_graphs / PUBLISHED[name]))

    def test_every_preset_is_described_and_resolves(self) -> None:
        assert set(PRESETS) == set(PUBLISHED) | set(ER_PRESETS) | set(FAMILY_PRESETS) | set(LARGE_PRESETS)
        # The large sites (up to 20,000 nodes, GBs to build dense) resolve in tests/test_large_sites.py.
        for name in set(PRESETS) - set(LARGE_PRESETS):
            assert resolve_graph(name).name == name

    def test_published_and_er_presets_differ(self) -> None:
        assert not preset("paper-50").same_problem(preset("er-50"))

    def test_unknown_preset_names_the_presets(self) -> None:
        with pytest.raises(GraphError, match="paper-50"):
            preset("paper-51")
        with pytest.raises(GraphError, match="not a published graph"):
            published_graph_path("er-50")


class TestHyperrectangle:
    @pytest.mark.parametrize(
        ("lengths", "chunks", "counts"),
        [
            ((10.0,), (2.0,), (5,)),
            ((4, 6), (1, 2), (4, 3)),
            ((2, 3, 4), (1, 1, 2), (2, 3, 2)),
            ((6,), (6,), (1,)),
        ],
    )
    def test_cell_and_edge_counts(self, lengths, chunks, counts) -> None:
        if math.prod(counts) == 1:
            with pytest.raises(GraphError, match="single cell"):
                hyperrectangle(lengths, chunks, targets=[0])
            return
        spec = hyperrectangle(lengths, chunks, targets=[0])
        assert spec.n_nodes == math.prod(counts)
        assert spec.n_edges == king_edges(counts)

    def test_known_small_counts(self) -> None:
        # Counted by hand: a 1-D row of 5 has 4 edges; a 3x3 grid with diagonals has 20.
        assert hyperrectangle((5,), (1,), targets=[2]).n_edges == 4
        assert hyperrectangle((3, 3), (1, 1), targets=[(1, 1)]).n_edges == 20
        # 2x2x2 cube: every pair of the 8 cells touches (28 pairs).
        assert hyperrectangle((2, 2, 2), (1, 1, 1), targets=[0]).n_edges == 28

    def test_adjacency_offsets(self) -> None:
        spec = hyperrectangle((3, 3), (1, 1), targets=[(0, 0)])
        centre = 4  # cell (1, 1) in C order
        assert spec.neighbours(centre).tolist() == [0, 1, 2, 3, 5, 6, 7, 8]
        assert spec.neighbours(0).tolist() == [1, 3, 4]

    def test_tuple_targets_and_random_targets(self) -> None:
        spec = hyperrectangle((4, 4), (1, 1), targets=[(0, 3), (3, 0)])
        assert spec.target_indices.tolist() == [3, 12]
        drawn = hyperrectangle((4, 4), (1, 1), n_targets=5, seed=2)
        assert drawn.n_targets == 5

    def test_chunk_must_divide_length(self) -> None:
        with pytest.raises(GraphError, match="does not divide"):
            hyperrectangle((10, 4), (3, 2), targets=[0])

    def test_needs_targets(self) -> None:
        with pytest.raises(GraphError, match="exactly one"):
            hyperrectangle((4,), (1,))


class TestGraphML:
    def test_round_trip(self, tmp_path) -> None:
        spec = erdos_renyi(25, 0.3, n_targets=4, seed=5, name="rt")
        path = save_graphml(spec, tmp_path / "g.graphml")
        loaded = load_graphml(path)
        assert loaded.same_problem(spec)
        assert loaded.name == "g"

    def test_round_trip_keeps_string_ids_and_positions(self, tmp_path) -> None:
        spec = hyperrectangle((3, 2), (1, 1), targets=[1])
        spec = GraphSpec(spec.adjacency, spec.targets, "box", spec.positions, node_ids=tuple("abcdef"))
        loaded = load_graphml(save_graphml(spec, tmp_path / "box.graphml"))
        assert loaded.node_ids == tuple("abcdef")
        np.testing.assert_allclose(loaded.positions, spec.positions)

    def test_refuses_to_overwrite(self, tmp_path) -> None:
        spec = path_graph(3, [0])
        save_graphml(spec, tmp_path / "p.graphml")
        with pytest.raises(FileExistsError):
            save_graphml(spec, tmp_path / "p.graphml")

    @pytest.mark.parametrize(
        ("file", "nodes", "edges", "targets"),
        [("paper_50n_8t", 50, 258, 8), ("paper_100n_17t", 100, 934, 17), ("paper_200n_41t", 200, 3695, 41)],
    )
    def test_reads_the_published_graphs(self, published_graphs, file, nodes, edges, targets) -> None:
        spec = load_graphml(published_graphs / f"{file}.graphml")
        assert (spec.n_nodes, spec.n_edges, spec.n_targets) == (nodes, edges, targets)
        assert spec.hop_distances.max() == 3

    def test_missing_target_attribute(self, tmp_path) -> None:
        path = tmp_path / "bad.graphml"
        path.write_text(
            '<?xml version="1.0"?><graphml xmlns="http://graphml.graphdrawing.org/xmlns">'
            '<graph edgedefault="undirected"><node id="a"/><node id="b"/>'
            '<edge source="a" target="b"/></graph></graphml>'
        )
        with pytest.raises(GraphError, match="no 'target' attribute"):
            load_graphml(path)

    @staticmethod
    def _directed(tmp_path, edges: list[tuple[str, str]]):
        path = tmp_path / "directed.graphml"
        keys = '<key id="t" for="node" attr.name="target" attr.type="int"/>'
        nodes = "".join(f'<node id="{n}"><data key="t">{int(n == "c")}</data></node>' for n in "abc")
        links = "".join(f'<edge source="{a}" target="{b}"/>' for a, b in edges)
        path.write_text(
            '<?xml version="1.0"?><graphml xmlns="http://graphml.graphdrawing.org/xmlns">'
            f'{keys}<graph edgedefault="directed">{nodes}{links}</graph></graphml>'
        )
        return path

    def test_directed_graph_with_a_one_way_edge_is_refused(self, tmp_path) -> None:
        path = self._directed(tmp_path, [("a", "b"), ("b", "a"), ("b", "c")])
        with pytest.raises(GraphError, match="one-way edge 'b' -> 'c'"):
            load_graphml(path)
        assert path.exists()  # nothing of the user's is touched

    def test_directed_graph_with_every_reverse_edge_is_read(self, tmp_path) -> None:
        path = self._directed(tmp_path, [("a", "b"), ("b", "a"), ("b", "c"), ("c", "b")])
        spec = load_graphml(path)
        assert (spec.n_nodes, spec.n_edges, spec.n_targets) == (3, 2, 1)

    def test_not_graphml(self, tmp_path) -> None:
        path = tmp_path / "junk.graphml"
        path.write_text("this is not xml")
        with pytest.raises(GraphError, match="not a readable GraphML"):
            load_graphml(path)


class TestBadInput:
    def test_missing_file(self, tmp_path) -> None:
        with pytest.raises(FileNotFoundError, match="nope.graphml"):
            resolve_graph(str(tmp_path / "nope.graphml"))

    def test_unknown_name(self) -> None:
        with pytest.raises(GraphError, match="unknown graph 'paper-51'"):
            resolve_graph("paper-51")

    def test_disconnected(self) -> None:
        adjacency = np.zeros((4, 4), dtype=bool)
        adjacency[0, 1] = adjacency[1, 0] = adjacency[2, 3] = adjacency[3, 2] = True
        with pytest.raises(GraphError, match="not connected"):
            GraphSpec(adjacency, np.array([1, 0, 0, 0]))

    def test_no_targets(self) -> None:
        with pytest.raises(GraphError, match="no targets"):
            path_graph(3, [])

    def test_asymmetric_and_self_loops(self) -> None:
        adjacency = np.array([[0, 1], [0, 0]])
        with pytest.raises(GraphError, match="not symmetric"):
            GraphSpec(adjacency, np.array([1, 0]))
        with pytest.raises(GraphError, match="self-loops"):
            GraphSpec(np.array([[1, 1], [1, 0]]), np.array([1, 0]))

    def test_spec_is_immutable(self) -> None:
        spec = path_graph(3, [1])
        with pytest.raises(ValueError):
            spec.adjacency[0, 1] = False


def test_next_hop_follows_shortest_paths() -> None:
    spec = erdos_renyi(30, 0.15, n_targets=3, seed=4)
    dist, hop = spec.hop_distances, spec.next_hop
    for i in range(spec.n_nodes):
        for j in range(spec.n_nodes):
            if i != j:
                assert spec.adjacency[i, hop[i, j]]
                assert dist[hop[i, j], j] == dist[i, j] - 1
