"""A local sweep worker killed from outside (the out-of-memory killer) is retried once, and the
other jobs go on (sb3_pm.experiments.backends)."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from sb3_pm.experiments.backends import WorkerLost, run_jobs


def killed_on_first_attempt(job: tuple[str, int, int]) -> int:
    """``value * 10``; the first attempt of a job marked ``kills`` times SIGKILLs its own worker.

    A marker file per attempt says which attempt this is (the attempts run in other processes).
    """
    folder, value, kills = job
    attempts = Path(folder) / f"attempts-{value}"
    attempt = len(attempts.read_text()) if attempts.exists() else 0
    attempts.write_text("x" * (attempt + 1))
    if attempt < kills:
        os.kill(os.getpid(), signal.SIGKILL)
    return value * 10


def attempts(folder: Path, value: int) -> int:
    return len((folder / f"attempts-{value}").read_text())


def test_a_killed_worker_is_retried_and_its_siblings_finish(tmp_path, capsys) -> None:
    jobs = [(str(tmp_path), value, 1 if value == 2 else 0) for value in range(6)]
    done: list[int] = []
    results = run_jobs(
        killed_on_first_attempt, jobs, n_jobs=2, on_done=lambda index, result: done.append(index)
    )
    assert results == [value * 10 for value in range(6)]
    assert sorted(done) == list(range(6))  # each job reported once
    assert attempts(tmp_path, 2) == 2
    assert all(attempts(tmp_path, value) <= 2 for value in range(6))  # a sibling at most retried once
    assert "a worker process died (killed; out of memory?) while running" in capsys.readouterr().err


def test_a_job_lost_twice_is_reported_after_the_others_finish(tmp_path) -> None:
    jobs = [(str(tmp_path), value, 2 if value == 1 else 0) for value in range(5)]
    with pytest.raises(
        WorkerLost, match=r"running cell-1 died twice .* the other 4 job\(s\) finished"
    ) as lost:
        run_jobs(killed_on_first_attempt, jobs, n_jobs=2, label=lambda job: f"cell-{job[1]}")
    assert lost.value.lost == [1]
    assert attempts(tmp_path, 1) == 2
    assert all(attempts(tmp_path, value) >= 1 for value in (0, 2, 3, 4))  # every other job ran


def raises(job: int) -> int:
    raise ValueError(f"job {job} is broken")


def test_a_jobs_own_error_still_ends_the_sweep(tmp_path) -> None:
    with pytest.raises(ValueError, match="is broken"):
        run_jobs(raises, [1, 2, 3], n_jobs=2)


def killing_run_cell(cell):
    """The learned seed-0 cell's worker is killed at every attempt; the other cells run."""
    from sb3_pm.experiments import runner

    if cell.variant["key"] == "learned" and cell.seed == 0:
        os.kill(os.getpid(), signal.SIGKILL)
    # forked workers see the patched module; spawned ones import the original
    return getattr(runner, "original_run_cell", runner.run_cell)(cell)


def test_reproduce_reports_a_lost_cell_in_one_line_and_keeps_the_others(
    tmp_path, capsys, monkeypatch
) -> None:
    from sb3_pm.cli import main
    from sb3_pm.experiments import runner
    from tests.test_experiments import tiny_experiment

    path = tiny_experiment(tmp_path)
    monkeypatch.setattr(runner, "original_run_cell", runner.run_cell, raising=False)
    monkeypatch.setattr(runner, "run_cell", killing_run_cell)
    out = tmp_path / "out"
    argv = ["reproduce", str(path), "--out", str(out), "--graphs", str(tmp_path / "tiny.graphml")]
    assert main([*argv, "--jobs", "2", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("sb3-pm reproduce: error: tiny: the worker process running cells/learned/")
    assert "seed0 died twice" in err[-1] and "the other 3 job(s) finished" in err[-1]
    done = sorted(
        str(folder.relative_to(out / "cells"))
        for folder in out.glob("cells/*/*/*")
        if (folder / "DONE").exists()
    )
    assert done == ["learned/tiny/seed1", "random/tiny/seed0", "random/tiny/seed1"]
