"""``sb3-pm train --track`` and ``reproduce --track``: runs mirrored to Weights & Biases, offline here."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from sb3_pm.cli import main

SMALL = ["--env", "karate", "--timesteps", "16", "--hyperparams", "n_steps:8", "batch_size:8", "n_epochs:1"]


def _read_once_written(path: Path, needles: tuple[bytes, ...], seconds: float = 60.0) -> bytes:
    """The file's bytes once they hold every needle, or as they are after ``seconds``: W&B's service
    process writes an offline run's records after ``finish`` returns, so for a moment the file may
    hold its header alone (seen once in CI)."""
    deadline = time.monotonic() + seconds
    data = path.read_bytes()
    while not all(needle in data for needle in needles) and time.monotonic() < deadline:
        time.sleep(0.2)
        data = path.read_bytes()
    return data


def test_a_tracked_run_writes_an_offline_wandb_run_with_its_config(tmp_path: Path, monkeypatch) -> None:
    pytest.importorskip("wandb", reason="--track needs the [track] extra")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    out = tmp_path / "run"
    assert main(["train", *SMALL, "--seed", "3", "--out", str(out), "--track", "--no-progress"]) == 0
    [run] = list((out / "wandb").glob("offline-run-*"))
    [record] = list(run.glob("run-*.wandb"))  # the run, to upload later with wandb sync
    data = _read_once_written(record, (b'"karate"', b"n_timesteps"))
    assert b'"karate"' in data and b"n_timesteps" in data  # its config, as the run resolved it
    synced = {path.name for path in (run / "files").iterdir()}
    assert {"agent_0_1", "agent_1_1", "team_1"} <= synced  # every learner's TensorBoard run and the team's
    assert (out / "team" / "manifest.json").is_file()  # the training itself as without --track


def test_track_without_wandb_is_one_line_before_any_folder(tmp_path: Path, monkeypatch, capsys) -> None:
    import builtins

    real_import = builtins.__import__

    def no_wandb(name: str, *args, **kwargs):
        if name == "wandb":
            raise ImportError("no wandb here")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_wandb)
    out = tmp_path / "run"
    assert main(["train", *SMALL, "--out", str(out), "--track", "--no-progress"]) == 2
    assert "--track needs wandb" in capsys.readouterr().err and not out.exists()
    sweep = ["reproduce", "comparison", "--quick", "--out", str(out), "--track", "--no-progress"]
    assert main(sweep) == 2
    assert "--track needs wandb" in capsys.readouterr().err and not out.exists()


def test_reproduce_tracks_each_training_cell_as_one_offline_run(tmp_path: Path, monkeypatch) -> None:
    pytest.importorskip("wandb", reason="--track needs the [track] extra")
    from tests.test_experiments import tiny_experiment

    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    path, out = tiny_experiment(tmp_path), tmp_path / "sweep"
    graph = str(tmp_path / "tiny.graphml")
    # Two jobs: the cells run in worker processes, which get the tracking from the cells alone.
    argv = ["reproduce", str(path), "--out", str(out), "--graphs", graph, "--seeds", "0"]
    assert main([*argv, "--jobs", "2", "--no-progress", "--track", "--wandb-project", "pm-sweep"]) == 0
    learned = out / "cells" / "learned" / "tiny" / "seed0"
    [run] = list((learned / "wandb").glob("offline-run-*"))
    [record] = list(run.glob("run-*.wandb"))
    needles = (b"pm-sweep", b"learned/tiny/seed0", b"\x04tiny", b"n_timesteps", b"hidden_dim")
    data = _read_once_written(record, needles)
    assert b"pm-sweep" in data and b"learned/tiny/seed0" in data  # the project given; named after the cell
    assert b"\x04tiny" in data  # grouped under the experiment's name (a 4-byte protobuf string)
    assert b"n_timesteps" in data and b"hidden_dim" in data  # the cell's training config
    synced = {p.name for p in (run / "files").iterdir()}
    assert {"agent_0_1", "agent_1_1", "team_1"} <= synced  # every learner's TensorBoard run and the team's
    assert not list((out / "cells" / "random").rglob("wandb"))  # a baseline cell trains nothing: no run
    assert (learned / "DONE").is_file() and "pm-sweep" not in (out / "experiment.yml").read_text()
    assert main([*argv, "--jobs", "1", "--no-progress"]) == 0  # the same sweep, resumed without --track
    assert len(list((learned / "wandb").glob("offline-run-*"))) == 1  # nothing trained again
