"""The components bound: below the exhaustive optimum, above the other bounds where agents must walk."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphSpec, preset
from sb3_pm.graphs.generators import erdos_renyi
from sb3_pm.planning import component_bound, lower_bound, target_components
from sb3_pm.planning.components import component_bound_applies
from tests.conftest import path_graph
from tests.test_planning import optimum, small_cases


def cases() -> list[tuple[GraphSpec, tuple[int, ...]]]:
    more = [
        (path_graph(5, [0, 2, 4]), (1,)),
        (path_graph(3, [0, 2]), (1,)),
        (path_graph(6, [0, 1, 3, 5]), (2, 4)),
        (path_graph(6, [0, 2, 3, 5]), (1, 4)),
        (path_graph(7, [0, 3, 6]), (1,)),
    ]
    more += [(erdos_renyi(7, edge_prob=0.35, n_targets=4, seed=seed), (0, 3)) for seed in range(4, 8)]
    return small_cases() + more


@pytest.mark.parametrize("case", range(16))
def test_the_components_bound_is_below_the_exhaustive_optimum_whatever_the_ceiling(case: int) -> None:
    graph, starts = cases()[case]
    for max_cycles, u_max in [(7, 4), (10, 6)]:
        best, _ = optimum(graph, starts, max_cycles, u_max)
        tight = component_bound(graph, np.array(starts), max_cycles, u_max, ceiling=best)
        loose = component_bound(graph, np.array(starts), max_cycles, u_max, ceiling=3 * best + 5)
        assert tight is not None and tight <= best + 1e-9
        # the ceiling only drops states that cannot lead lower
        assert loose == pytest.approx(tight)


def test_it_sees_the_walks_between_lone_targets_that_the_other_bounds_relax() -> None:
    """One agent between two targets two hops apart: the relaxation is the true problem."""
    graph, starts, max_cycles, u_max = path_graph(3, [0, 2]), np.array([1]), 10, 6
    best, _ = optimum(graph, (1,), max_cycles, u_max)
    assert component_bound(graph, starts, max_cycles, u_max, ceiling=best) == pytest.approx(best)
    assert lower_bound(graph, starts, max_cycles, u_max) < best - 0.5
    graph = path_graph(5, [0, 2, 4])
    best, _ = optimum(graph, (1,), max_cycles, u_max)
    assert component_bound(graph, starts, max_cycles, u_max, ceiling=best) > lower_bound(
        graph, starts, max_cycles, u_max
    )


def test_a_ceiling_below_the_optimum_is_returned_as_the_bound() -> None:
    graph, max_cycles, u_max = path_graph(5, [0, 2, 4]), 10, 6
    best, _ = optimum(graph, (1,), max_cycles, u_max)
    assert component_bound(graph, np.array([1]), max_cycles, u_max, ceiling=best / 2) == pytest.approx(
        np.floor(best / 2 * max_cycles) / max_cycles
    )


def test_components_are_the_targets_joined_by_single_hops() -> None:
    graph = path_graph(8, [0, 1, 3, 5, 6, 7])
    groups = target_components(graph.routes.between_targets())
    names = [graph.target_indices[g].tolist() for g in groups]
    assert names == [[0, 1], [3], [5, 6, 7]]


def test_too_many_placements_are_not_computed_and_bad_input_is_refused() -> None:
    graph = path_graph(17, list(range(0, 17, 2)))  # nine lone targets
    starts = np.arange(1, 17, 4)  # four agents: far more than MAX_PLACEMENTS placements
    assert component_bound(graph, starts, 20, 10, ceiling=1000.0) is None
    assert not component_bound_applies(graph, 4, 10)
    assert component_bound_applies(graph, 1, 10)  # ten placements of one agent
    assert component_bound_applies(preset("paper-50"), 4, 100)  # three components: 35 placements
    with pytest.raises(InputError, match="needs a ceiling"):
        component_bound(graph, starts, 20, 10)
    with pytest.raises(InputError, match="starts"):
        component_bound(graph, np.array([99]), 20, 10, ceiling=1.0)


def test_the_exact_start_only_tightens_and_the_plain_start_is_also_valid(monkeypatch) -> None:
    """Played node by node, the first steps see agents that must sort out their targets; without
    them (too many joint first moves) the agents wait for the hops from their starts."""
    from sb3_pm.planning import components

    max_cycles, u_max = 10, 6
    tighter = 0
    for graph, starts in [*cases(), (path_graph(9, [0, 1]), (8,))]:
        best, _ = optimum(graph, starts, max_cycles, u_max)
        exact = component_bound(graph, np.array(starts), max_cycles, u_max, ceiling=best)
        monkeypatch.setattr(components, "MAX_EXACT_MOVES", 0)
        plain = component_bound(graph, np.array(starts), max_cycles, u_max, ceiling=best)
        monkeypatch.undo()
        assert plain <= exact + 1e-9 <= best + 2e-9
        tighter += exact > plain + 1e-9
    assert tighter >= 2


@pytest.mark.parametrize("case", [0, 2, 6, 9, 12])
def test_the_components_bound_holds_from_random_initial_uncertainties(case: int) -> None:
    graph, starts = cases()[case]
    max_cycles, u_max = 8, 5
    rng = np.random.default_rng(case)
    at_reset = rng.integers(0, u_max + 1, size=graph.n_targets)
    initial = np.zeros(graph.n_nodes, dtype=np.int64)
    initial[graph.target_indices] = at_reset
    best, _ = optimum(graph, starts, max_cycles, u_max, tuple(at_reset.tolist()))
    bound = component_bound(graph, np.array(starts), max_cycles, u_max, initial, ceiling=best)
    assert bound is not None and bound <= best + 1e-9
    assert component_bound(graph, np.array(starts), max_cycles, u_max, initial, ceiling=2 * best + 5) == bound
