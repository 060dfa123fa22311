"""Interrupted training keeps its work: checkpoints, bit-for-bit resume, Ctrl-C and SIGTERM."""

from __future__ import annotations

import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_pm.agents.training.checkpoints import CheckpointError, CheckpointSchedule
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.cli import main
from sb3_pm.graphs import erdos_renyi

th.set_num_threads(1)

GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)
HYPERPARAMS = {"n_steps": 16, "batch_size": 16, "n_epochs": 2, "learning_rate": "lin_1e-3"}


def _team(algo: str) -> IndependentPPO:
    return IndependentPPO(
        GRAPH, n_agents=2, algo=algo, n_envs=2, seed=5, hyperparams=HYPERPARAMS, env_kwargs={"max_cycles": 20}
    )


def _state(team: IndependentPPO) -> list[th.Tensor]:
    """Every learner's parameters and optimizer moments, in a fixed order."""
    tensors: list[th.Tensor] = []
    for agent in team.agents:
        policy = team.models[agent].policy
        tensors += list(policy.state_dict().values())
        for optimizer in (policy.optimizer, getattr(policy, "estimator_optimizer", None)):
            if optimizer is not None:
                for moments in optimizer.state_dict()["state"].values():
                    tensors += [v for v in moments.values() if isinstance(v, th.Tensor)]
    return tensors


def _assert_same(a: list[th.Tensor], b: list[th.Tensor]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert th.equal(x, y)


@pytest.mark.parametrize("algo", ["dcbf_ppo", "maskable_ppo", "ppo"])
def test_resume_from_a_checkpoint_equals_the_uninterrupted_run(tmp_path, algo) -> None:
    steps = 32 * 6  # six rollouts of 16 steps x 2 env copies
    plain = _team(algo).learn(steps)
    checkpointed = _team(algo).learn(steps, checkpoints=CheckpointSchedule(tmp_path, every=2, keep=5))
    # Checkpoints change nothing about the run itself.
    _assert_same(_state(plain), _state(checkpointed))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rollout_000002", "rollout_000004"]

    resumed = IndependentPPO.from_checkpoint(tmp_path / "rollout_000002")
    assert resumed.num_timesteps == 64 and resumed.remaining_timesteps == steps - 64
    before = _state(resumed)
    assert any(not th.equal(x, y) for x, y in zip(before, _state(plain)))  # it really starts earlier
    resumed.learn(resumed.remaining_timesteps, reset_num_timesteps=False)
    _assert_same(_state(plain), _state(resumed))
    assert resumed.num_timesteps == plain.num_timesteps


def test_the_newest_checkpoints_are_kept_and_a_damaged_one_is_skipped(tmp_path, caplog) -> None:
    steps = 32 * 7
    plain = _team("dcbf_ppo").learn(steps)
    _team("dcbf_ppo").learn(steps, checkpoints=CheckpointSchedule(tmp_path, every=2, keep=2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rollout_000004", "rollout_000006"]
    damaged = tmp_path / "rollout_000006" / "state.npz"
    damaged.write_bytes(damaged.read_bytes()[:-10])

    resumed = IndependentPPO.from_checkpoint(tmp_path)
    assert resumed.checkpoint == tmp_path / "rollout_000004"
    assert "rollout_000006" in caplog.text and "damaged" in caplog.text
    assert damaged.exists()  # nothing is deleted
    resumed.learn(resumed.remaining_timesteps, reset_num_timesteps=False)
    _assert_same(_state(plain), _state(resumed))

    with pytest.raises(CheckpointError, match="damaged"):
        IndependentPPO.from_checkpoint(tmp_path / "rollout_000006")
    with pytest.raises(CheckpointError, match="no checkpoint"):
        IndependentPPO.from_checkpoint(tmp_path / "empty")


def test_learn_leaves_the_callers_random_generators_alone() -> None:
    team = _team("maskable_ppo")
    random.seed(1)
    np.random.seed(1)  # noqa: NPY002 - the legacy global generator SB3 draws from
    th.manual_seed(1)
    expected = (random.random(), np.random.random(), th.rand(1).item())  # noqa: NPY002
    random.seed(1)
    np.random.seed(1)  # noqa: NPY002 - the legacy global generator SB3 draws from
    th.manual_seed(1)
    team.learn(32)
    assert (random.random(), np.random.random(), th.rand(1).item()) == expected  # noqa: NPY002


def _train_argv(tiny_train, out: Path, timesteps: int) -> list[str]:
    config, graph, _ = tiny_train
    return [
        "train",
        "--config",
        str(config),
        "--env",
        str(graph),
        "--timesteps",
        str(timesteps),
        "--checkpoint-every",
        "10",
        "--no-progress",
        "--out",
        str(out),
    ]


def _records(folder: Path) -> dict[str, bytes]:
    return {name: (folder / name).read_bytes() for name in ("args.yml", "config.yml", "command.txt")}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_train_resumes_to_the_uninterrupted_team(tiny_train, sig) -> None:
    tmp = tiny_train[2].parent
    timesteps = 16 * 150  # 150 rollouts: interrupted well before the end
    out = tmp / "interrupted"
    command = [sys.executable, "-m", "sb3_pm.cli", *_train_argv(tiny_train, out, timesteps)]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # As from a terminal: a job started in the background (`cmd &`, nohup) inherits an ignored
        # SIGINT, and Python then leaves it ignored, so Ctrl-C could not reach the run at all.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("checkpoints/rollout_*/checkpoint.json")) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert list(out.glob("checkpoints/rollout_*")), "no checkpoint was ever written"
        process.send_signal(sig)
        stdout, stderr = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130, stderr
    assert "continue with: sb3-pm train --resume" in stdout
    assert not (out / "team").exists()
    records = _records(out)

    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert _records(out) == records  # the run's records are kept as they were
    assert "resumed from" in (out / "resumed.txt").read_text()

    assert main([*_train_argv(tiny_train, tmp / "whole", timesteps)]) == 0
    resumed = IndependentPPO.load(out)
    whole = IndependentPPO.load(tmp / "whole")
    assert resumed.num_timesteps == whole.num_timesteps == timesteps
    _assert_same(_state(whole), _state(resumed))


def test_resume_refuses_what_it_cannot_continue(tiny_train, capsys, monkeypatch) -> None:
    tmp = tiny_train[2].parent
    out = tmp / "run"
    assert main(_train_argv(tiny_train, out, 16 * 25)) == 0
    capsys.readouterr()

    assert main(["train", "--resume", str(out)]) == 2
    assert "has finished" in capsys.readouterr().err
    assert main(["train", "--resume", str(out), "--seed", "3"]) == 2
    assert "drop --seed" in capsys.readouterr().err
    assert main(["train", "--resume", str(out), "--threads", "2", "--checkpoint-every", "3"]) == 2
    assert "drop --checkpoint-every, --threads" in capsys.readouterr().err
    assert main(["train", "--resume", str(out), "--device", "cuda", "--threads", "2"]) == 2
    assert "drop --device, --threads" in capsys.readouterr().err
    assert main(["train", "--resume", str(tmp)]) == 2
    assert "not a run folder" in capsys.readouterr().err

    # An unfinished run: its checkpoints are there, its team is not.
    shutil.rmtree(out / "team")
    assert main(_train_argv(tiny_train, out, 16 * 25)) == 2
    assert f"sb3-pm train --resume {out}" in capsys.readouterr().err
    # --update-device may change on resuming (a GPU run continued without one), and is checked
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    assert main(["train", "--resume", str(out), "--update-device", "cuda"]) == 2
    error = capsys.readouterr().err
    assert "cannot resume" in error and "no CUDA device" in error and "--update-device cpu" in error
    shutil.rmtree(out / "checkpoints")
    assert main(["train", "--resume", str(out)]) == 2
    error = capsys.readouterr().err
    assert "no checkpoint" in error and error.count("\n") == 1
    assert (out / "args.yml").exists()  # a refused resume removes nothing


def test_side_by_side_updates_give_the_serial_parameters(monkeypatch) -> None:
    """Concurrent update phases (each learner's train() and estimator fit in its own thread) give
    the parameters of the serial path, bit for bit, and really run side by side."""
    from sb3_pm.agents.multiplexing.multiplexer import ParallelEnvMultiplexer

    side_by_side = []
    enter_update = ParallelEnvMultiplexer.enter_update

    def spy(self, index, draw=None):
        generator = enter_update(self, index, draw)
        side_by_side.append(generator is not None)
        return generator

    monkeypatch.setattr(ParallelEnvMultiplexer, "enter_update", spy)

    def trained(concurrent: bool) -> list[th.Tensor]:
        team = IndependentPPO(
            GRAPH,
            n_agents=3,
            n_envs=2,
            seed=2,
            hyperparams={**HYPERPARAMS, "n_epochs": 3},
            env_kwargs={"max_cycles": 20},
            concurrent_updates=concurrent,
        )
        return _state(team.learn(32 * 4))

    serial = trained(False)
    assert side_by_side and not any(side_by_side)
    side_by_side.clear()
    concurrent = trained(True)
    assert side_by_side and all(side_by_side)
    _assert_same(serial, concurrent)


def test_drawn_minibatch_orders_leave_numpys_generator_alone() -> None:
    """An update running next to others must not draw from NumPy's global generator: with drawn
    orders the buffer's get() draws nothing, and yields the minibatches of those orders."""
    team = _team("dcbf_ppo").learn(32)
    buffer = team.models["agent_0"].rollout_buffer
    buffer.full = True  # the last rollout's data, as train() would see it
    np.random.seed(7)  # noqa: NPY002 - the legacy global generator SB3 draws from
    buffer.draw_orders(2)
    expected = [order.copy() for order in buffer.orders]
    state = np.random.get_state()  # noqa: NPY002
    first = [batch.actions.clone() for batch in buffer.get(8)]
    second = [batch.actions.clone() for batch in buffer.get(8)]
    after = np.random.get_state()  # noqa: NPY002
    assert after[1].tolist() == state[1].tolist() and after[2] == state[2]
    actions = th.as_tensor(buffer.actions)
    assert th.equal(th.cat(first), actions[expected[0]]) and th.equal(th.cat(second), actions[expected[1]])


def test_a_checkpoint_is_also_due_after_every_seconds(tmp_path, monkeypatch) -> None:
    from sb3_pm.agents.training import checkpoints

    clock = [100.0]
    monkeypatch.setattr(checkpoints.time, "monotonic", lambda: clock[0])
    schedule = CheckpointSchedule(tmp_path, every=10, every_seconds=60.0)
    assert not schedule.due(1, stop_requested=False)
    clock[0] += 59.0
    assert not schedule.due(2, stop_requested=False)
    clock[0] += 1.0
    assert schedule.due(3, stop_requested=False)  # 60 s since the start
    assert not schedule.due(4, stop_requested=False)  # the clock restarted at 3
    clock[0] += 30.0
    assert schedule.due(10, stop_requested=False)  # the rollout count still counts, and restarts it
    clock[0] += 59.0
    assert not schedule.due(11, stop_requested=False)
    assert CheckpointSchedule(tmp_path, every=10).due(3, stop_requested=False) is False  # by rollouts only
    from sb3_pm.errors import InputError

    with pytest.raises(InputError, match="every_seconds must be positive"):
        CheckpointSchedule(tmp_path, every_seconds=0)


def test_a_time_due_checkpoint_changes_nothing_about_the_run(tmp_path) -> None:
    steps = 32 * 3
    plain = _team("dcbf_ppo").learn(steps)
    # every_seconds below any rollout's duration: a checkpoint at every barrier, though every=100
    schedule = CheckpointSchedule(tmp_path, every=100, keep=5, every_seconds=1e-9)
    timed = _team("dcbf_ppo").learn(steps, checkpoints=schedule)
    _assert_same(_state(plain), _state(timed))
    # one at every barrier between rollouts (the run's end saves the team, not a checkpoint)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rollout_000001", "rollout_000002"]
