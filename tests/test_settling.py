"""Settling places (sb3_pm/evaluation/settling.py): by hand on arrays, through the harness with a
scripted team on a path graph, and through ``sb3-pm evaluate --settling``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sb3_pm.cli import main
from sb3_pm.evaluation import EvaluationResult, evaluate
from sb3_pm.evaluation.settling import settling, settling_table
from sb3_pm.team_interface import Team
from tests.conftest import path_graph


def test_oscillation_is_two_places_and_passing_visits_are_dropped() -> None:
    # Agent 0 walks 0 -> 3 (one step on each), then bounces 3 <-> 4 for 40 steps; agent 1 stays on 9.
    walk = [0, 1, 2] + [3, 4] * 20
    positions = np.array([walk, [9] * len(walk)]).T  # (T, 2)
    targets = np.array([4, 6, 9])
    u = np.tile(np.array([0.5, 80.0, 0.0]), (len(walk), 1))
    result = settling(positions, u, targets, since=0)
    assert result.places == [[3, 4], [9]]  # 0, 1, 2: one step each of 43, below 5%
    assert result.targets_left == [6]
    assert result.target_u == {4: 0.5, 6: 80.0, 9: 0.0}
    # A 60% share keeps neither node of a 50/50 oscillation.
    assert settling(positions, u, targets, since=3, min_share=0.6).places == [[], [9]]
    # The window: with a 10% share the walk's nodes count over its first 6 steps, not after them.
    assert settling(positions, u, targets, since=37, min_share=0.1).places == [[3, 4], [9]]
    assert settling(positions[:6], u[:6], targets, since=0, min_share=0.1).places == [[0, 1, 2, 3, 4], [9]]
    assert settling(positions[:6], u[:6], targets, since=3, min_share=0.1).places == [[3, 4], [9]]


def test_a_failed_agent_settles_nowhere_and_bad_windows_are_refused() -> None:
    positions = np.array([[1, 2]] * 10)
    active = np.ones((10, 2), dtype=bool)
    active[:, 1] = False  # agent 1 failed before the window
    result = settling(positions, np.zeros((10, 1)), np.array([2]), since=5, active=active)
    assert result.places == [[1], []]
    assert result.targets_left == [2]
    for since in (-1, 10):
        with pytest.raises(ValueError, match="since must be in"):
            settling(positions, np.zeros((10, 1)), np.array([2]), since=since)
    with pytest.raises(ValueError, match="min_share"):
        settling(positions, np.zeros((10, 1)), np.array([2]), since=0, min_share=0)
    with pytest.raises(ValueError, match="target_u must be"):
        settling(positions, np.zeros((10, 2)), np.array([2]), since=0)
    with pytest.raises(ValueError, match="active must have"):
        settling(positions, np.zeros((10, 1)), np.array([2]), since=0, active=active[:, :1])


class Bouncer(Team):
    """agent_0 bounces between nodes 1 and 2 from the start; agent_1 walks to node 4 and stays."""

    name = "bouncer"

    def predict_dict(self, observations, deterministic=True):
        positions = self.env.unwrapped.core.positions
        first = 2 if positions[0] == 1 else 1
        second = min(int(positions[1]) + 1, 4)
        return {"agent_0": first, "agent_1": second}


def test_the_harness_records_settling_and_json_keeps_it() -> None:
    graph = path_graph(6, [1, 2, 5])
    result = evaluate(
        Bouncer(), graph, n_agents=2, episodes=2, seed=0, max_cycles=40,
        env_kwargs={"initial_positions": [1, 0]}, settle_since=20,
    )  # fmt: skip
    for record in result.episodes:
        assert record.settling is not None
        assert record.settling.places == [[1, 2], [4]]
        assert record.settling.targets_left == [5]
        assert record.settling.target_u[5] == pytest.approx(np.mean(np.minimum(np.arange(21, 41), 100)))
    restored = EvaluationResult.from_dict(json.loads(json.dumps(result.to_dict())))
    assert [r.settling for r in restored.episodes] == [r.settling for r in result.episodes]
    assert "left: 5 (u 30)" in settling_table(result.episodes)
    plain = evaluate(
        Bouncer(), graph, n_agents=2, episodes=1, max_cycles=40, env_kwargs={"initial_positions": [1, 0]}
    )
    assert plain.episodes[0].settling is None and "settling" not in plain.to_dict()
    with pytest.raises(ValueError, match="settle_since must be in"):
        evaluate(Bouncer(), graph, n_agents=2, episodes=1, max_cycles=40, settle_since=40)


def test_an_agent_failing_after_a_step_stood_on_its_node_during_it() -> None:
    # agent_1 walks 0 -> 4 and fails after step 6; from step 5 it stood on node 4 for 2 steps
    # (steps 5 and 6) of the window's 36, 5.6% >= 5%: it settles there, then is gone.
    graph = path_graph(6, [1, 2, 5])
    result = evaluate(
        Bouncer(), graph, n_agents=2, episodes=1, max_cycles=40,
        env_kwargs={"initial_positions": [1, 0], "failures": {"agent_1": 6}}, settle_since=4,
    )  # fmt: skip
    assert result.episodes[0].settling.places == [[1, 2], [4]]
    result = evaluate(
        Bouncer(), graph, n_agents=2, episodes=1, max_cycles=40,
        env_kwargs={"initial_positions": [1, 0], "failures": {"agent_1": 5}}, settle_since=4,
    )  # fmt: skip
    assert result.episodes[0].settling.places == [[1, 2], []]  # one step on node 4: 2.8%


def test_cli_prints_each_episode_and_refuses_a_bad_window(capsys, tmp_path) -> None:
    out_json = tmp_path / "s.json"
    code = main(
        ["evaluate", "--policy", "sit_on_nodes", "--graph", "paper-50", "--steps", "30",
         "--episodes", "2", "--settling", "--json", str(out_json)]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "where each agent settles in steps 16-30" in out
    assert out.count("episode ") >= 2 and "settles a0:" in out
    payload = json.loads(out_json.read_text())
    assert [entry["since"] for entry in payload["settling"]] == [15, 15]
    for since in ("30", "-1"):
        code = main(
            ["evaluate", "--policy", "random", "--steps", "30", "--episodes", "1", "--settling", since]
        )
        err = capsys.readouterr().err
        assert (
            code != 0 and "--settling SINCE must be in [0, 30)" in err and len(err.strip().splitlines()) == 1
        )
