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
    # From step 3 on only the oscillation is looked at; with a 60% share even one of its nodes drops.
    assert settling(positions, u, targets, since=3).places == [[3, 4], [9]]
    assert settling(positions, u, targets, since=3, min_share=0.6).places == [[], [9]]


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


class Bouncer(Team):
    """agent_0 bounces between nodes 1 and 2 from the start; agent_1 walks to node 4 and stays."""

    name = "bouncer"

    def predict(self, observations, deterministic=True):
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


def test_cli_prints_each_episode_and_refuses_a_bad_window(capsys, tmp_path) -> None:
    out_json = tmp_path / "s.json"
    code = main(
        ["evaluate", "--policy", "sit_on_nodes", "--graph", "paper-50", "--steps", "30",
         "--episodes", "2", "--settling", "--json", str(out_json)]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "where each agent settles from step 15 on" in out
    assert out.count("episode ") >= 2 and "settles a0:" in out
    payload = json.loads(out_json.read_text())
    assert [entry["since"] for entry in payload["settling"]] == [15, 15]
    code = main(["evaluate", "--policy", "random", "--steps", "30", "--episodes", "1", "--settling", "30"])
    err = capsys.readouterr().err
    assert code != 0 and "--settling SINCE must be in [0, 30)" in err and len(err.strip().splitlines()) == 1
