"""A final team save that fails (a full disk) leaves a run that ``sb3-pm train --resume`` finishes:
from a checkpoint of the finished training, or from the last periodic one, never from scratch, and
the messages name command-line flags, not Python arguments."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import pytest
import torch as th

from sb3_pm.agents.training import learned_team
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.cli import main
from sb3_pm.commands.run_folder import STAGING

th.set_num_threads(1)

TIMESTEPS = 16 * 25  # 25 rollouts: periodic checkpoints after 10 and 20


def argv(tiny_train, out: Path) -> list[str]:
    config, graph, _ = tiny_train
    return [
        "train", "--config", str(config), "--env", str(graph), "--timesteps", str(TIMESTEPS),
        "--checkpoint-every", "10", "--no-progress", "--out", str(out),
    ]  # fmt: skip


def disk_full(monkeypatch: pytest.MonkeyPatch, rescue_fails: bool) -> None:
    """The disk fills up during the final save, after its first model file; with ``rescue_fails``
    it stays full, so that the checkpoint of the finished training fails too."""
    save = learned_team.save_model_atomic
    full = {"since": False}

    def saving(model, path: Path) -> None:
        if full["since"] or path.parent.name == STAGING and path.name != "agent_0.zip":
            full["since"] = rescue_fails
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        save(model, path)

    monkeypatch.setattr(learned_team, "save_model_atomic", saving)


def parameters(folder: Path) -> list[th.Tensor]:
    team = IndependentPPO.load(folder)
    try:
        return [t for agent in team.agents for t in team.models[agent].policy.state_dict().values()]
    finally:
        team.close()


def assert_same_team(a: Path, b: Path) -> None:
    for x, y in zip(parameters(a), parameters(b), strict=True):
        assert th.equal(x, y)


@pytest.fixture()
def whole(tiny_train) -> Path:
    """The team of the same run, saved without a fault."""
    out = tiny_train[2].parent / "whole"
    assert main(argv(tiny_train, out)) == 0
    return out / "team"


@pytest.mark.parametrize("rescue_fails", [False, True], ids=["finished-training-kept", "disk-stays-full"])
def test_resume_finishes_a_failed_final_save(tiny_train, whole, monkeypatch, capsys, rescue_fails) -> None:
    out = tiny_train[2].parent / "run"
    with monkeypatch.context() as patch:
        disk_full(patch, rescue_fails)
        assert main(argv(tiny_train, out)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    said = f"sb3-pm train: error: saving the team to {out / 'team'} failed"
    assert len(err) == 1 and err[0].startswith(said)
    assert "No space left on device" in err[0] and f"sb3-pm train --resume {out}" in err[0]
    assert "overwrite=" not in err[0]
    assert not (out / "team").exists() and not (out / STAGING).exists()  # no half team under its name
    finished = (out / "checkpoints" / "rollout_000025").is_dir()
    assert finished != rescue_fails

    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert (", 0 to go" in said) == (not rescue_fails)  # the finished training is not trained again
    assert (out / "team" / "manifest.json").is_file()
    assert_same_team(out / "team", whole)


def test_resume_replaces_the_half_team_an_older_failed_save_left(tiny_train, whole, capsys) -> None:
    """What a failed final save left before saves were staged: model files and no manifest."""
    out = tiny_train[2].parent / "run"
    shutil.copytree(whole.parent, out)
    (out / "team" / "manifest.json").unlink()
    assert main(argv(tiny_train, out)) == 2  # not "already exists": an unfinished run
    assert f"continue it with sb3-pm train --resume {out}" in capsys.readouterr().err
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert_same_team(out / "team", whole)
