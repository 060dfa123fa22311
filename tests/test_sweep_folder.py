"""``sb3-pm reproduce`` holds the run-folder lock for its whole sweep, and refuses a folder holding
files it did not write (a user's report.md, results.md, command.txt are never overwritten)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_pm.cli import main
from sb3_pm.commands.run_folder import LOCK, lock_owner

EXPERIMENT = """
name: baselines
graphs: [paper-50]
seeds: [0]
episodes: 1
max_cycles: 5
n_agents: 2
variants:
  random: {kind: baseline, policy: random}
  grazing: {kind: baseline, policy: grazing}
"""


@pytest.fixture()
def sweep(tmp_path: Path) -> list[str]:
    """The command line of a sweep of two baselines (seconds), without ``--out``."""
    path = tmp_path / "baselines.yml"
    path.write_text(EXPERIMENT)
    return ["reproduce", str(path), "--jobs", "1", "--no-progress"]


def holding(folder: Path) -> subprocess.Popen:
    """Another process that holds ``folder``'s lock (a sweep still running there) until killed."""
    code = (
        "import time; from pathlib import Path; from sb3_pm.commands.run_folder import held_lock\n"
        f"with held_lock(Path({str(folder)!r})):\n"
        "    print('ready', flush=True); time.sleep(600)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None and process.stdout.readline().strip() == "ready"
    return process


def test_a_second_sweep_on_a_folder_in_use_is_refused(sweep, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    assert main([*sweep, "--out", str(out)]) == 0  # a first sweep's folder, resumable
    capsys.readouterr()
    report = (out / "report.md").read_text()
    holder = holding(out)
    try:
        assert main([*sweep, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "choose another --out" in err[0]
        assert err[0].startswith(
            f"sb3-pm reproduce: error: run folder {out} is in use by process {holder.pid}@"
        )
        assert (out / "report.md").read_text() == report
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert main([*sweep, "--out", str(out)]) == 0  # the lock died with its process
    assert (out / LOCK).exists() and lock_owner(out) is None


def test_a_sweep_holds_the_lock_while_it_runs(sweep, tmp_path, monkeypatch) -> None:
    out = tmp_path / "out"
    seen = []
    from sb3_pm.experiments import runner

    write_report = runner.write_report

    def watching(folder, *args, **kwargs):
        seen.append((folder / LOCK).read_text())  # our pid@host while the sweep writes its report
        return write_report(folder, *args, **kwargs)

    monkeypatch.setattr(runner, "write_report", watching)
    assert main([*sweep, "--out", str(out)]) == 0
    assert len(seen) == 1 and seen[0].startswith(f"{os.getpid()}@")


def test_a_folder_holding_a_users_files_is_refused_and_left_intact(sweep, tmp_path, capsys) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    files = {"report.md": "my report", "results.md": "my results", "command.txt": "my command"}
    for name, text in files.items():
        (out / name).write_text(text)
    assert main([*sweep, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"sb3-pm reproduce: error: --out {out} holds files no sweep")
    assert "command.txt, report.md, results.md" in err[0] and "experiment.yml" in err[0]
    assert {p.name: p.read_text() for p in out.iterdir()} == files  # nothing written, not even a lock


def test_an_empty_folder_and_a_new_one_are_taken(sweep, tmp_path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main([*sweep, "--out", str(empty)]) == 0
    assert main([*sweep, "--out", str(tmp_path / "new" / "sweep")]) == 0
    assert (tmp_path / "new" / "sweep" / "results.md").is_file()
