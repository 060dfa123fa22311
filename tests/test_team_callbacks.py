"""An SB3-style team: one callback for every learner, a team evaluation callback that keeps the
best team, team-level scalars, set_logger and get/set_parameters."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.agents.training.team_callbacks import split_team_callbacks
from sb3_pm.errors import InputError
from sb3_pm.evaluation.team_eval_callback import TeamEvalCallback
from tests.test_team import make_team, parameters

th.set_num_threads(1)


class Counting(BaseCallback):
    def _on_step(self) -> bool:
        return True


def test_one_callback_object_serves_every_learner_as_a_copy() -> None:
    team = make_team()
    callback = Counting()
    team.learn(64, callback=callback)
    assert callback.model is team.models["agent_0"]  # the first learner got the object itself
    assert callback.n_calls == 64 // team.n_envs  # its own steps only: the second learner has a copy


def test_one_checkpoint_callback_writes_each_learners_files_apart(tmp_path: Path) -> None:
    from stable_baselines3.common.callbacks import CheckpointCallback

    make_team().learn(64, callback=CheckpointCallback(16, str(tmp_path)))
    for agent in ("agent_0", "agent_1"):
        assert sorted(p.name for p in (tmp_path / agent).iterdir()) == [
            "rl_model_32_steps.zip",
            "rl_model_64_steps.zip",
        ]


def test_team_callbacks_are_split_from_learner_callbacks() -> None:
    evaluation, learner = TeamEvalCallback(), Counting()
    assert split_team_callbacks(evaluation) == (None, [evaluation])
    assert split_team_callbacks([evaluation, learner]) == (learner, [evaluation])
    assert split_team_callbacks([learner, learner]) == ([learner, learner], [])


def test_team_evaluation_keeps_the_best_team_and_changes_no_training(tmp_path: Path) -> None:
    """Evaluating at every rollout barrier leaves the trained parameters bit for bit those of a
    run without it; the best team is saved and loads; every evaluation is logged."""
    plain = make_team()
    plain.learn(96)
    evaluated = make_team()
    callback = TeamEvalCallback(
        eval_freq=1,
        n_eval_episodes=2,
        max_cycles=20,
        best_model_save_path=tmp_path,
        log_path=tmp_path,
        verbose=0,
    )
    evaluated.learn(96, callback=callback)
    assert all(th.equal(a, b) for a, b in zip(parameters(plain), parameters(evaluated)))
    rollouts = 96 // (16 * 2)
    records = json.loads((tmp_path / "evaluations.json").read_text())
    assert len(records) == rollouts and [r["timesteps"] for r in records] == [32, 64, 96]
    assert all(len(r["episodes"]) == 2 for r in records)
    assert callback.best_mean == min(r["avg_uncertainty"] for r in records)
    best = IndependentPPO.load(tmp_path / "team")
    assert best.num_timesteps in [
        r["timesteps"] for r in records if r["avg_uncertainty"] == callback.best_mean
    ]
    assert json.loads((tmp_path / "best.json").read_text())["avg_uncertainty"] == callback.best_mean
    # Another run into the same folder replaces the saved team only with a better one.
    again = TeamEvalCallback(
        eval_freq=1, n_eval_episodes=2, max_cycles=20, best_model_save_path=tmp_path, verbose=0
    )
    make_team(seed=1).learn(32, callback=again)
    worse = again.evaluations[0]["avg_uncertainty"] >= callback.best_mean
    assert (IndependentPPO.load(tmp_path / "team").seed == 0) == worse


def test_team_scalars_and_evaluations_go_to_the_teams_logger(tmp_path: Path) -> None:
    team = make_team()
    team.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    team.learn(64, callback=[TeamEvalCallback(eval_freq=1, n_eval_episodes=1, max_cycles=20, verbose=0)])
    header = (tmp_path / "log" / "progress.csv").read_text().splitlines()[0].split(",")
    assert "eval/avg_uncertainty" in header and "eval/best_avg_uncertainty" in header
    assert "team/train/loss" in header  # the mean of the learners' losses


def test_team_scalars_beside_the_agents_tensorboard_runs(tmp_path: Path) -> None:
    team = make_team(tensorboard_log=str(tmp_path))
    team.learn(64, tb_log_name="run_")
    runs = sorted(p.name for p in tmp_path.iterdir())
    assert "run_team_1" in runs and any(name.startswith("run_agent_0") for name in runs)
    assert list((tmp_path / "run_team_1").glob("events.out.tfevents.*"))


def test_get_and_set_parameters_round_trip() -> None:
    source, target = make_team(seed=0), make_team(seed=1)
    assert not all(th.equal(a, b) for a, b in zip(parameters(source), parameters(target)))
    target.set_parameters(source.get_parameters())
    assert all(th.equal(a, b) for a, b in zip(parameters(source), parameters(target)))
    assert set(source.get_parameters()) == {"agent_0", "agent_1"}
    with pytest.raises(InputError, match="unknown models \\['agent_9'\\]"):
        target.set_parameters({"agent_9": {}})
    with pytest.raises(InputError, match="missing models \\['agent_1'\\]"):
        target.set_parameters({"agent_0": source.get_parameters()["agent_0"]})
