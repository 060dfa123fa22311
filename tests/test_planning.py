"""The planner and the lower bounds: exhaustive search on small graphs, and agreement with the env."""

from __future__ import annotations

import itertools
import json
from functools import cache

import numpy as np
import pytest

from sb3_pm.baselines import make_team
from sb3_pm.baselines import optimal_planner as planner_module
from sb3_pm.cli import main
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.evaluation import evaluate, markdown_table
from sb3_pm.evaluation.gif import record_gif
from sb3_pm.evaluation.statistics import GAP_METRIC, summarize
from sb3_pm.graphs import GraphSpec, preset
from sb3_pm.graphs.generators import erdos_renyi
from sb3_pm.planning import lower_bound, priced_bound, stepwise_bound
from sb3_pm.planning import planner as planner_search
from sb3_pm.planning import pricer as pricer_module
from sb3_pm.planning.batch_pricing import solo_costs
from sb3_pm.planning.controllers import simulate
from sb3_pm.planning.group_patrol import dropped_cost, solo_cost, tour_move
from sb3_pm.planning.pair_schedule import PairSchedule
from sb3_pm.planning.planner import plan_patrol
from sb3_pm.planning.team_plan import plan_team
from tests.conftest import path_graph


def optimum(
    graph: GraphSpec,
    starts: tuple[int, ...],
    max_cycles: int,
    u_max: int,
    initial: tuple[int, ...] | None = None,
) -> tuple[float, np.ndarray]:
    """The exact least ``avg_uncertainty`` over every joint move sequence, and the least summed
    target ``u`` after each step ``k`` over every team (``(K,)``), by exhaustive dynamic programming.

    :param initial: the targets' ``u`` at reset, in target order (default all 0)."""
    targets = tuple(int(t) for t in graph.target_indices)
    at_reset = tuple(0 for _ in targets) if initial is None else tuple(int(u) for u in initial)
    moves = [tuple(int(v) for v in np.flatnonzero(row)) for row in graph.reachable]

    def advance(positions: tuple[int, ...], values: tuple[int, ...]) -> tuple[int, ...]:
        return tuple(
            (max(u - 1, 0) if t in positions else min(u + 1, u_max)) for t, u in zip(targets, values)
        )

    @cache
    def best(step: int, positions: tuple[int, ...], values: tuple[int, ...]) -> int:
        if step == max_cycles:
            return 0
        return min(
            sum(after) + best(step + 1, nxt, after)
            for nxt in itertools.product(*(moves[p] for p in positions))
            for after in [advance(nxt, values)]
        )

    # the least total after each step over all teams: a forward sweep of the reachable states
    states = {(tuple(starts), at_reset)}
    least = np.empty(max_cycles, dtype=np.int64)
    for k in range(max_cycles):
        states = {
            (nxt, advance(nxt, values))
            for positions, values in states
            for nxt in itertools.product(*(moves[p] for p in positions))
        }
        least[k] = min(sum(values) for _, values in states)
    return best(0, tuple(starts), at_reset) / max_cycles, least


def small_cases() -> list[tuple[GraphSpec, tuple[int, ...]]]:
    cases = [
        (path_graph(5, [0, 2, 4]), (1,)),
        (path_graph(5, [0, 1, 4]), (2, 3)),
        (path_graph(4, [0, 3]), (1,)),
    ]
    for seed in range(4):
        graph = erdos_renyi(6, edge_prob=0.4, n_targets=3, seed=seed)
        rng = np.random.default_rng(seed)
        cases.append(
            (graph, tuple(int(s) for s in rng.choice(graph.n_nodes, size=1 + seed % 2, replace=False)))
        )
    return cases


@pytest.mark.parametrize("case", range(7))
def test_bounds_and_plan_bracket_the_exhaustive_optimum(case: int) -> None:
    graph, starts = small_cases()[case]
    max_cycles, u_max = 7, 4
    best, least = optimum(graph, starts, max_cycles, u_max)
    steps = stepwise_bound(graph, np.array(starts), max_cycles, u_max)
    assert (steps <= least).all(), (steps, least)
    assert lower_bound(graph, np.array(starts), max_cycles, u_max) <= best + 1e-9
    assert priced_bound(graph, np.array(starts), max_cycles, u_max) <= best + 1e-9
    plan = plan_team(graph, np.array(starts), max_cycles, u_max, search_seconds=5)
    assert plan.simulated >= best - 1e-9


@pytest.mark.parametrize(
    ("targets", "start", "max_cycles", "u_max"),
    [([0, 2, 4], 1, 14, 8), ([0, 3], 1, 16, 10), ([1, 4], 0, 16, 6)],
)
def test_the_priced_bound_holds_where_it_is_the_larger(
    targets: list[int], start: int, max_cycles: int, u_max: int
) -> None:
    """Targets with no target neighbour: every arrival costs a walk, which only this bound counts."""
    graph = path_graph(5, targets)
    best, _ = optimum(graph, (start,), max_cycles, u_max)
    priced = priced_bound(graph, np.array([start]), max_cycles, u_max)
    stepwise = float(stepwise_bound(graph, np.array([start]), max_cycles, u_max).mean())
    assert stepwise < priced <= best + 1e-9


def test_a_plan_replays_through_the_env_to_its_simulated_figure() -> None:
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4, max_cycles=120)
    env.reset(seed=3)
    state = env.unwrapped
    team = make_team("optimal_planner", search_seconds=5)
    result = evaluate(team, "paper-50", episodes=1, seed=3, max_cycles=120)
    # the team's own plan (a second search may stop elsewhere under its time cap)
    plan = team.plan
    assert team.acting == "plan"
    assert result.episodes[0].metrics["avg_uncertainty"] == pytest.approx(plan.simulated)
    distances = state.graph.hop_distances.astype(int).tolist()
    next_hop = state.graph.next_hop.astype(int).tolist()
    again = simulate(
        plan.controllers(distances, next_hop),
        state.positions,
        state.graph.target_indices,
        np.zeros(state.graph.n_nodes, dtype=np.int64),
        120,
        state.u_max,
    )
    assert again == pytest.approx(plan.simulated)


def test_the_planner_is_no_worse_than_territory_patrol_and_no_better_than_the_bound() -> None:
    kwargs = dict(episodes=2, seed=11, max_cycles=200)
    for graph in ("paper-50", "rooms-4"):
        planner = evaluate(make_team("optimal_planner", search_seconds=5), graph, **kwargs)
        rule = evaluate(make_team("territory_patrol"), graph, **kwargs)
        for mine, theirs in zip(planner.values("avg_uncertainty"), rule.values("avg_uncertainty")):
            assert mine <= theirs
        env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=4, max_cycles=200)
        for record in planner.episodes:
            env.reset(seed=record.seed)
            bound = lower_bound(env.unwrapped.graph, env.unwrapped.positions, 200, env.unwrapped.u_max)
            assert bound <= record.metrics["avg_uncertainty"] + 1e-9


def test_the_team_plan_is_no_worse_than_the_planned_conventions_plan() -> None:
    """From these starts on rgg-60 the search pricing groups by either rule ends in a plan about a
    tenth worse than the stalest rule's own search: the team plan keeps the better of the two."""
    graph = preset("rgg-60")
    starts = np.array([12, 44, 23, 38])
    either = plan_patrol(graph, starts, 500, 100)
    stalest = plan_patrol(graph, starts, 500, 100, tour_groups=False)
    assert stalest.predicted < either.predicted
    assert plan_team(graph, starts, 500, 100).simulated <= stalest.predicted + 1e-9


def test_the_pair_schedule_prices_what_it_plays_and_beats_the_greedy_rule() -> None:
    graph = path_graph(7, [1, 5])
    distances, next_hop = graph.hop_distances.astype(int).tolist(), graph.next_hop.astype(int).tolist()
    schedule = PairSchedule(graph.hop_distances, graph.next_hop, 1, 5, 60, 10, keep_actions=True)
    for start in range(7):
        cost, entry = schedule.entry(start, 0, 0)
        position, u, played = start, {1: 0, 5: 0}, 0
        for remaining in range(60, 0, -1):
            position = schedule.move(position, entry, u[1], u[5], remaining)
            u = {t: (max(v - 1, 0) if t == position else min(v + 1, 10)) for t, v in u.items()}
            played += u[1] + u[5]
        assert played == cost
        assert cost <= solo_cost(start, (1, 5), [0, 0], 60, 10, distances, next_hop)


@pytest.mark.parametrize("graph_seed", [0, 1, 2])
def test_the_batch_pricer_walks_every_group_as_the_scalar_rules_do(graph_seed: int) -> None:
    """Ties in u and distance are common on these small graphs, so every tie-break is exercised."""
    graph = erdos_renyi(14, edge_prob=0.3, n_targets=7, seed=graph_seed)
    distances, next_hop = graph.hop_distances.astype(int).tolist(), graph.next_hop.astype(int).tolist()
    rng = np.random.default_rng(graph_seed)
    starts, groups, rules, initials = [], [], [], []
    for _ in range(120):
        size = int(rng.integers(0, 6))
        groups.append(tuple(int(t) for t in rng.permutation(graph.target_indices)[:size]))
        rules.append("tour" if size >= 3 and rng.random() < 0.5 else "stalest")
        starts.append(int(rng.integers(graph.n_nodes)))
        initials.append([int(v) for v in rng.integers(0, 9, size)] if rng.random() < 0.5 else [0] * size)
    batch = solo_costs(starts, groups, rules, initials, 70, 8, graph.hop_distances, graph.next_hop)
    one_by_one = [
        solo_cost(start, group, initial, 70, 8, distances, next_hop, rule)
        for start, group, rule, initial in zip(starts, groups, rules, initials)
    ]
    assert batch.tolist() == one_by_one


def test_the_search_finds_the_same_plan_with_the_batch_pricer(monkeypatch) -> None:
    graph = erdos_renyi(16, edge_prob=0.25, n_targets=8, seed=3)
    starts = np.array([0, 5, 9])
    monkeypatch.setattr(pricer_module, "BATCH_MIN_WALKS", 1)
    batched = planner_search.plan_patrol(graph, starts, 120, 20, restarts=3)
    monkeypatch.setattr(pricer_module, "BATCH_MIN_WALKS", 10**9)
    one_by_one = planner_search.plan_patrol(graph, starts, 120, 20, restarts=3)
    assert batched == one_by_one


def test_a_dropped_target_grows_to_the_cap() -> None:
    for initial, steps, cap in [(0, 10, 4), (3, 10, 4), (0, 3, 100), (4, 5, 4)]:
        assert dropped_cost(initial, steps, cap) == sum(min(initial + k, cap) for k in range(1, steps + 1))


def test_bad_input_is_one_line() -> None:
    graph = path_graph(4, [0, 3])
    with pytest.raises(InputError, match="starts"):
        lower_bound(graph, np.array([9]), 10, 5)
    with pytest.raises(InputError, match="max_cycles and u_max"):
        stepwise_bound(graph, np.array([0]), 0, 5)
    with pytest.raises(InputError, match="search_seconds"):
        make_team("optimal_planner", search_seconds=0)
    with pytest.raises(InputError, match="two different targets"):
        PairSchedule(graph.hop_distances, graph.next_hop, 0, 0, 10, 5)


def test_the_tour_rule_walks_its_group_in_order() -> None:
    ring = np.zeros((8, 8), dtype=bool)
    for i in range(8):
        ring[i, (i + 1) % 8] = ring[(i + 1) % 8, i] = True
    flags = np.zeros(8, dtype=bool)
    flags[[0, 2, 4, 6]] = True
    graph = GraphSpec(adjacency=ring, targets=flags, name="ring")
    distances, next_hop = graph.hop_distances.astype(int).tolist(), graph.next_hop.astype(int).tolist()
    tour = (0, 2, 4, 6)
    u = [0] * 8
    position, goal, reached = 1, None, []
    for _ in range(12):
        position, goal = tour_move(position, goal, tour, u, distances, next_hop)
        if position in tour and (not reached or reached[-1] != position):
            reached.append(position)
    assert reached[:5] == [0, 2, 4, 6, 0]


def test_every_episode_records_its_lower_bound_and_gap(tmp_path) -> None:
    result = evaluate(make_team("territory_patrol"), "paper-50", episodes=2, seed=5, max_cycles=80)
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4, max_cycles=80)
    for record in result.episodes:
        env.reset(seed=record.seed)
        state = env.unwrapped
        bound = lower_bound(state.graph, state.positions, 80, state.u_max, state.uncertainty)
        assert record.metrics["lower_bound"] == pytest.approx(bound)
        assert record.metrics["x_lower_bound"] == pytest.approx(record.metrics["avg_uncertainty"] / bound)
        assert record.metrics["x_lower_bound"] >= 1.0 - 1e-9
    table = markdown_table(
        summarize({"territory_patrol": [result]}, ("avg_uncertainty", "max_neglect", GAP_METRIC))
    )
    assert "× Lower Bound" in table.splitlines()[0]


def test_the_bound_command_brackets_each_episode(tmp_path, capsys) -> None:
    out = tmp_path / "bound.json"
    argv = ["bound", "--graph", "paper-50", "--episodes", "2", "--steps", "60", "--planner"]
    assert main([*argv, "--search-seconds", "5", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [row["env_seed"] for row in rows] == [0, 1]
    for row in rows:
        assert row["components"] is not None
        assert row["lower_bound"] == max(row["stepwise"], row["priced"], row["components"])
        assert row["planner"] >= row["lower_bound"] - 1e-9
    # without the planner a quick plan prunes the components bound, which is the same figure
    fast = tmp_path / "fast.json"
    assert main(["bound", "--episodes", "2", "--steps", "60", "--json", str(fast)]) == 0
    assert [row["components"] for row in json.loads(fast.read_text())["rows"]] == [
        row["components"] for row in rows
    ]
    skipped = tmp_path / "skipped.json"
    assert main(["bound", "--episodes", "1", "--steps", "60", "--no-components", "--json", str(skipped)]) == 0
    (row,) = json.loads(skipped.read_text())["rows"]
    assert row["components"] is None and row["lower_bound"] == max(row["stepwise"], row["priced"])
    assert main([*argv, "--search-seconds", "0"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert error[-1] == "sb3-pm bound: error: --search-seconds must be positive, got 0.0"


def test_the_planner_falls_back_to_the_rule_where_the_rule_scores_lower(monkeypatch) -> None:
    """The rule's score on a copy of the env is its real score; a plan priced above it is not used."""
    kwargs = dict(episodes=1, seed=4, max_cycles=100)
    rule = evaluate(make_team("territory_patrol"), "rooms-4", **kwargs).episodes[0].metrics["avg_uncertainty"]
    planner = make_team("optimal_planner", search_seconds=5)
    original = planner_module.plan_with_openings

    def worse_plan(*args, **kw):
        plan = original(*args, **kw)
        plan.simulated = float("inf")
        return plan

    monkeypatch.setattr(planner_module, "plan_with_openings", worse_plan)
    fallen_back = evaluate(planner, "rooms-4", **kwargs).episodes[0].metrics["avg_uncertainty"]
    assert planner.acting == "territory_patrol"
    assert fallen_back == pytest.approx(rule)


def test_the_planner_records_a_gif_and_acts_on_local_observations(tmp_path) -> None:
    """The rule's trial copy leaves the renderer alone, and needs map observations only to compare."""
    record_gif(
        make_team("optimal_planner", search_seconds=2), "paper-50", tmp_path / "plan.gif", max_cycles=15
    )
    assert (tmp_path / "plan.gif").stat().st_size > 0
    local = evaluate(
        make_team("optimal_planner", search_seconds=2),
        "rooms-4",
        episodes=1,
        seed=5,
        max_cycles=60,
        env_kwargs={"observation": "local"},
    )
    assert local.episodes[0].metrics["steps"] == 60


def test_a_plan_replays_from_random_initial_uncertainties() -> None:
    env = persistent_monitoring_v0.parallel_env(
        graph="rooms-4", n_agents=4, max_cycles=80, u_max=20, initial_uncertainty="random"
    )
    env.reset(seed=9)
    assert env.unwrapped.uncertainty.any()  # the episode does start from random uncertainties
    team = make_team("optimal_planner", search_seconds=5)
    result = evaluate(
        team,
        "rooms-4",
        episodes=1,
        seed=9,
        max_cycles=80,
        env_kwargs={"u_max": 20, "initial_uncertainty": "random"},
    )
    # the team's own plan (a second search may stop elsewhere under its time cap)
    plan = team.plan
    assert team.acting == "plan"
    assert result.episodes[0].metrics["avg_uncertainty"] == pytest.approx(plan.simulated)
    assert result.episodes[0].metrics["lower_bound"] <= plan.simulated + 1e-9


@pytest.mark.parametrize(
    ("starts", "initial", "message"),
    [
        ([1.5], None, "starts must be integers"),
        ([1], [0, 0, 0], "initial_uncertainty must be 4 integers in \\[0, 5\\]"),
        ([1], [0, -1, 0, 0], "initial_uncertainty must be 4 integers"),
        ([1], [9, 0, 0, 0], "initial_uncertainty must be 4 integers"),
    ],
)
def test_a_bound_refuses_what_no_episode_can_start_from(starts, initial, message) -> None:
    graph = path_graph(4, [0, 3])
    for bound in (stepwise_bound, priced_bound):
        with pytest.raises(InputError, match=message):
            bound(graph, np.array(starts), 10, 5, None if initial is None else np.array(initial))
