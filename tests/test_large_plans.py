"""The plan search on large sites: tables towards the targets only, and the search for large teams.

The planner's ``(N, T)`` tables must hold what the all-pairs tables hold, whichever way they were
built; the large-team search must price what it claims (the solo costs recomputed on the all-pairs
tables), never end above the territory split it starts from, and keep every target in one group
or dropped; and a plan for 64 agents on the 5,000-node city must fit in a small process.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from sb3_pm.graphs import GraphSpec, resolve_graph
from sb3_pm.graphs import routes as routes_module
from sb3_pm.graphs.large_sites import city_streets
from sb3_pm.planning import owned_search
from sb3_pm.planning.group_patrol import dropped_cost, solo_cost
from sb3_pm.planning.owned_search import nearest_targets
from sb3_pm.planning.planner import plan_patrol
from sb3_pm.planning.target_tables import TargetTables
from tests.conftest import child_result


def fresh(name: str) -> GraphSpec:
    """A new spec of the graph, with no cached tables of its own."""
    graph = city_streets(300, seed=3) if name == "city-300" else resolve_graph(name)
    return GraphSpec(graph.adjacency, graph.targets, name=graph.name, positions=graph.positions)


@pytest.mark.parametrize("name", ["paper-50", "rooms-4", "city-300"])
@pytest.mark.parametrize("per_target", [False, True])
def test_the_target_tables_hold_the_all_pairs_tables(name: str, per_target: bool, monkeypatch) -> None:
    if per_target:  # the routes of one search per target, as on a large site
        monkeypatch.setattr(routes_module, "DENSE_ROUTES_MAX", 0)
    graph = fresh(name)
    tables = TargetTables(graph)
    targets = graph.target_indices
    assert np.array_equal(tables.node[tables.label], np.arange(graph.n_nodes))
    assert np.array_equal(tables.node[: targets.size], targets)  # targets first, in node order
    node_rows = tables.distances[tables.label]  # (N, T) back in node order
    assert np.array_equal(node_rows, graph.hop_distances[:, targets])
    assert np.array_equal(tables.node[tables.next_hop[tables.label]], graph.next_hop[:, targets])
    assert np.array_equal(tables.between, graph.hop_distances[np.ix_(targets, targets)])


def test_nearest_targets_are_the_closest_others_lowest_label_first() -> None:
    between = np.array([[0, 2, 1, 2], [2, 0, 3, 1], [1, 3, 0, 4], [2, 1, 4, 0]])
    assert nearest_targets(between, 2).tolist() == [[2, 1], [3, 0], [0, 1], [1, 0]]
    assert nearest_targets(between[:1, :1]).shape == (1, 0)


def _recomputed(graph: GraphSpec, starts: np.ndarray, plan, max_cycles: int, u_max: int) -> float:
    """The plan's decomposed avg_uncertainty from the all-pairs tables, targets starting at 0."""
    distances, next_hop = graph.hop_distances.tolist(), graph.next_hop.tolist()
    total = sum(
        solo_cost(int(start), group, [0] * len(group), max_cycles, u_max, distances, next_hop, rule)
        for start, group, rule in zip(starts, plan.groups, plan.rules)
    )
    total += sum(dropped_cost(0, max_cycles, u_max) for _ in plan.dropped)
    return total / max_cycles


@pytest.mark.parametrize("n_agents", [20, 4])
def test_the_large_team_search_prices_what_it_plans_and_ends_below_the_split(
    n_agents: int, monkeypatch
) -> None:
    """With the limit on the exhaustive search lowered, so that a small site takes the other one."""
    monkeypatch.setattr(owned_search, "EXACT_SEARCH_MAX_WALKS", 1000)
    graph = city_streets(600, seed=3)  # 60 targets
    assert not owned_search.exhaustive(n_agents, graph.n_targets)
    starts = np.random.default_rng(0).choice(graph.n_nodes, n_agents, replace=False)
    plan = plan_patrol(graph, starts, 200, 60, search_seconds=600.0, restarts=2, tour_groups=False)
    assert plan.complete
    placed = [t for group in plan.groups for t in group] + list(plan.dropped)
    assert sorted(placed) == sorted(graph.target_indices.tolist())  # each target once
    assert plan.predicted == pytest.approx(_recomputed(graph, starts, plan, 200, 60))
    assert plan.predicted < plan.notes["territory_split"]
    # the search is seeded and counted: the same arguments give the same plan
    assert plan_patrol(graph, starts, 200, 60, search_seconds=600.0, restarts=2, tour_groups=False) == plan


def test_the_exhaustive_search_plans_where_a_round_prices_few_enough_walks() -> None:
    assert owned_search.exhaustive(16, 32) and owned_search.exhaustive(8, 17)  # paper-200, paper-100
    assert not owned_search.exhaustive(12, 100)  # city-1k's 12 agents: about 74,000 walks a round
    assert not owned_search.exhaustive(64, 500) and not owned_search.exhaustive(16, 500)  # city-5k


def test_an_idle_agents_empty_group_may_take_any_target() -> None:
    between = np.array([[0, 1, 5], [1, 0, 5], [5, 5, 0]])
    changes = owned_search._changes([(0, 1), (2,), ()], (), nearest_targets(between, 1))
    moved_to_empty = {moved for changed, moved, _ in changes if (2, moved) in changed}
    assert moved_to_empty == {(0,), (1,), (2,)}


PLAN_5K = textwrap.dedent(
    """
    import json, time
    import numpy as np
    from sb3_pm.graphs import resolve_graph
    from sb3_pm.planning.planner import plan_patrol
    start = time.perf_counter()
    graph = resolve_graph("city-5k")
    starts = np.random.default_rng(0).choice(graph.n_nodes, 64, replace=False)
    plan = plan_patrol(graph, starts, 500, 100, search_seconds=600.0, restarts=0, tour_groups=False)
    status = open("/proc/self/status").read()  # VmHWM: this image's own peak
    print(json.dumps({"complete": plan.complete, "predicted": plan.predicted,
                      "split": plan.notes["territory_split"], "seconds": time.perf_counter() - start,
                      "all_pairs": "hop_distances" in graph.__dict__,
                      "peak_mb": int(status.split("VmHWM:")[1].split()[0]) / 1024}))
    """
)


def test_a_plan_for_64_agents_on_the_5000_node_city_fits_in_a_small_process() -> None:
    result = child_result(PLAN_5K, timeout=600)
    assert result["complete"] and result["predicted"] < result["split"], result
    assert not result["all_pairs"]  # no (N, N) table was built
    assert result["peak_mb"] < 1000, result


def test_the_optimal_planner_refuses_a_site_above_its_size_in_one_line(monkeypatch) -> None:
    from sb3_pm.baselines import make_team
    from sb3_pm.baselines import optimal_planner as planner_module
    from sb3_pm.envs import persistent_monitoring_v0
    from sb3_pm.errors import InputError

    monkeypatch.setattr(planner_module, "MAX_PLANNER_NODES", 49)
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4, max_cycles=20)
    env.reset(seed=0)
    with pytest.raises(
        InputError, match=r"^optimal_planner plans on sites of up to 49 nodes and paper-50 has 50: "
    ):
        make_team("optimal_planner").reset(env, seed=0)
