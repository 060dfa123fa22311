"""The planner's openings: the first steps played exactly, then a fresh plan."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.baselines import make_team
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.evaluation import evaluate
from sb3_pm.planning.controllers import OpeningController, simulate
from sb3_pm.planning.openings import best_opening, plan_with_openings
from sb3_pm.planning.team_plan import plan_team
from tests.test_planning import optimum, small_cases


@pytest.mark.parametrize("case", range(7))
def test_an_opening_plan_is_between_the_optimum_and_the_plain_plan_and_replays_to_its_figure(
    case: int,
) -> None:
    graph, starts = small_cases()[case]
    max_cycles, u_max = 7, 4
    best, _ = optimum(graph, starts, max_cycles, u_max)
    plain = plan_team(graph, np.array(starts), max_cycles, u_max, search_seconds=2)
    plan = plan_with_openings(graph, np.array(starts), max_cycles, u_max, search_seconds=2)
    assert best - 1e-9 <= plan.simulated <= plain.simulated + 1e-9
    opened = best_opening(graph, np.array(starts), max_cycles, u_max, np.zeros(graph.n_nodes, np.int64), 2)
    assert opened is not None and opened.opening.shape == (2, len(starts))
    controllers = opened.controllers(graph.hop_distances.tolist(), graph.next_hop.tolist())
    replayed = simulate(
        controllers, np.array(starts), graph.target_indices, np.zeros(graph.n_nodes), max_cycles, u_max
    )
    assert replayed == pytest.approx(opened.simulated)


def test_a_crowded_start_is_better_opened_and_the_env_replays_it() -> None:
    """paper-50, env seed 7: two agents start one hop from the same pair of targets."""
    max_cycles = 80
    env = persistent_monitoring_v0.parallel_env(graph="paper-50", max_cycles=max_cycles)
    env.reset(seed=7)
    state = env.unwrapped
    args = (state.graph, np.asarray(state.positions), max_cycles, state.u_max, np.asarray(state.uncertainty))
    plain = plan_team(*args, search_seconds=2)
    plan = plan_with_openings(*args, search_seconds=2)
    assert plan.opening is not None and plan.simulated < plain.simulated - 1e-9
    team = make_team("optimal_planner", search_seconds=2)
    result = evaluate(team, "paper-50", episodes=1, seed=7, max_cycles=max_cycles)
    # the team replays its own plan (a second search may stop elsewhere under its time cap)
    assert team.plan.opening is not None
    assert result.episodes[0].metrics["avg_uncertainty"] == pytest.approx(team.plan.simulated)


def test_the_opening_moves_come_first_then_the_orders() -> None:
    class Stay:
        def move(self, position: int, uncertainty: np.ndarray, remaining: int) -> int:
            return position

    controller = OpeningController([3, 4], Stay())
    u = np.zeros(5)
    assert [controller.move(p, u, 9) for p in (2, 3, 4, 4)] == [3, 4, 4, 4]


def test_no_opening_where_the_first_moves_are_too_many_or_the_episode_too_short(monkeypatch) -> None:
    graph, starts = small_cases()[0]
    zeros = np.zeros(graph.n_nodes, np.int64)
    assert best_opening(graph, np.array(starts), 2, 4, zeros, 1) is None
    from sb3_pm.planning import openings

    monkeypatch.setattr(openings, "MAX_OPENING_MOVES", 1)
    assert best_opening(graph, np.array(starts), 7, 4, zeros, 1) is None
