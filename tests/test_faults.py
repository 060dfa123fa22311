"""Faults lose nothing: a locked run folder, atomic saves, no stub folders, writable outputs first."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch as th

from sb3_pm.cli import main
from sb3_pm.commands.run_folder import LOCK, lock_owner, locked_run_folder

th.set_num_threads(1)


@pytest.fixture()
def setup(tiny_train):
    """The tiny training command (32 steps per learner) and the test's folder."""
    config, graph, out = tiny_train
    argv = ["train", "--config", str(config), "--env", str(graph), "--timesteps", "32", "--no-progress"]
    return argv, out.parent


def _holder(folder: Path) -> subprocess.Popen:
    """Another process that holds ``folder``'s run lock until it is killed."""
    code = (
        "import sys, time; from pathlib import Path; "
        "from sb3_pm.commands.run_folder import locked_run_folder\n"
        f"with locked_run_folder(Path({str(folder)!r}), overwrite=False) as f:\n"
        "    (f / 'args.yml').write_text('the first run')\n"
        "    print('ready', flush=True); time.sleep(600)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None and process.stdout.readline().strip() == "ready"
    return process


def test_overwrite_refuses_a_folder_in_use_and_takes_over_a_stale_lock(setup, capsys) -> None:
    argv, tmp = setup
    out = tmp / "run"
    holder = _holder(out)
    try:
        assert str(lock_owner(out)).startswith(f"{holder.pid}@")
        assert main([*argv, "--out", str(out), "--overwrite"]) == 2
        assert f"in use by process {holder.pid}" in capsys.readouterr().err
        assert (out / "args.yml").read_text() == "the first run"  # nothing of the first run lost
    finally:
        holder.send_signal(signal.SIGKILL)  # dies without releasing its lock
        holder.wait()
    assert (out / LOCK).exists() and lock_owner(out) is None  # stale: its process is gone
    assert main([*argv, "--out", str(out), "--overwrite"]) == 0
    assert (out / "team" / "manifest.json").exists() and lock_owner(out) is None


def _owner_seen_by_another_process(folder: Path) -> str:
    code = f"from sb3_pm.commands.run_folder import lock_owner; print(lock_owner({str(folder)!r}))"
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()


def test_a_run_holds_its_lock_and_releases_it(tmp_path) -> None:
    with locked_run_folder(tmp_path / "r", overwrite=False) as folder:
        assert (folder / LOCK).read_text().startswith(f"{os.getpid()}@")
        assert lock_owner(folder) is None  # our own lock does not block us
        assert _owner_seen_by_another_process(folder).startswith(f"{os.getpid()}@")
    assert _owner_seen_by_another_process(folder) == "None"


def test_overwrite_removes_only_what_a_run_writes(setup, capsys) -> None:
    argv, tmp = setup
    out = tmp / "mixed"
    out.mkdir()
    (out / "config.yml").write_text("a run's record")
    (out / "notes.txt").write_text("the user's own file")
    assert main([*argv, "--out", str(out), "--overwrite"]) == 2
    assert "holds files no run writes (notes.txt)" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "the user's own file" and (out / "config.yml").exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--seed", "-1"], "--seed must be at least 0"),
        (["--hyperparams", "n_agents:20"], "more agents (20) than nodes (12)"),
        (["--hyperparams", "policy_kwargs:{no_such_option: 1}"], "no_such_option"),
        (["--hyperparams", "n_steps:-5"], "n_steps: expected an integer >= 2, got -5"),
    ],
)
def test_bad_input_leaves_no_stub_folder(setup, capsys, extra, message) -> None:
    argv, tmp = setup
    out = tmp / "never"
    assert main([*argv, "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_team_save_leaves_no_temporary_files(setup) -> None:
    argv, tmp = setup
    assert main([*argv, "--out", str(tmp / "run")]) == 0
    names = sorted(p.name for p in (tmp / "run" / "team").iterdir())
    assert names == ["agent_0.zip", "agent_1.zip", "graph.graphml", "manifest.json"]
    assert [p.name for p in (tmp / "run").iterdir() if p.name.startswith(".")] == [LOCK]


def test_unwritable_json_fails_before_the_evaluation(tmp_path, capsys) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    started = time.perf_counter()
    argv = ["evaluate", "--policy", "grazing", "--episodes", "50", "--json", str(blocker / "r.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--json" in err and "cannot be written" in err and len(err.strip().splitlines()) == 1
    assert time.perf_counter() - started < 20  # 50 episodes were not run first (they take minutes)
    assert blocker.read_text() == "not a folder"


SLOW_EXPERIMENT = """
name: slow
graphs: [{graph}]
seeds: [0, 1]
episodes: 1
max_cycles: 10
n_agents: 2
config: tiny.yml
timesteps: 100000
variants:
  learned: {{kind: independent}}
"""


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads worker processes from /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_sweep_workers_end_with_their_parent(setup, sig) -> None:
    _, tmp = setup
    experiment = tmp / "slow.yml"
    experiment.write_text(SLOW_EXPERIMENT.format(graph=str(tmp / "g12.graphml")))
    out = tmp / "sweep"
    command = [sys.executable, "-m", "sb3_pm.cli", "reproduce", str(experiment), "--out", str(out)]
    parent = subprocess.Popen([*command, "--jobs", "2", "--no-progress"], stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while len(workers := _children(parent.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert len(workers) >= 2, "the sweep never started its workers"
        time.sleep(1.0)  # the workers are training their cells
        parent.send_signal(sig)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 15
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not [pid for pid in workers if _alive(pid)], "workers outlived their parent"
    finally:
        parent.kill()
        for pid in _children(parent.pid):
            os.kill(pid, signal.SIGKILL)
    assert not list(out.glob("cells/*/*/*/DONE"))  # no cell claims to be finished


def test_a_damaged_model_file_is_one_line_naming_it(setup, capsys) -> None:
    import zipfile

    argv, tmp = setup
    assert main([*argv, "--out", str(tmp / "run")]) == 0
    model = tmp / "run" / "team" / "agent_1.zip"
    with zipfile.ZipFile(model) as source:
        members = {name: source.read(name) for name in source.namelist()}
    members["policy.pth"] = members["policy.pth"][: len(members["policy.pth"]) // 2]  # a valid zip
    with zipfile.ZipFile(model, "w") as damaged:
        for name, data in members.items():
            damaged.writestr(name, data)
    capsys.readouterr()
    assert (
        main(["evaluate", "--policy", str(tmp / "run"), "--agents", "2", "--graph", str(tmp / "g12.graphml")])
        == 2
    )
    err = capsys.readouterr().err
    assert "agent_1.zip cannot be loaded" in err and len(err.strip().splitlines()) == 1, err


def test_ray_problems_are_one_line_before_anything_is_written(tmp_path, monkeypatch, capsys) -> None:
    import importlib.util
    import socket

    out = tmp_path / "sweep"
    argv = ["reproduce", "comparison", "--quick", "--out", str(out), "--backend", "ray"]
    # An address where nothing listens: a port just closed on this machine.
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    started = time.perf_counter()
    assert main([*argv, "--ray-address", f"127.0.0.1:{port}"]) == 2
    assert "no Ray cluster answered" in capsys.readouterr().err
    assert time.perf_counter() - started < 30 and not out.exists()
    assert main([*argv, "--ray-address", "nonsense"]) == 2
    assert "expected HOST:PORT" in capsys.readouterr().err
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real_find_spec(name, *a)
    )
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "needs Ray" in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_only_the_projects_errors_become_one_line(monkeypatch, capsys) -> None:
    """A user's mistake is one line; a bug (any other exception) keeps its traceback."""
    from sb3_pm.commands import evaluate
    from sb3_pm.errors import InputError

    def bug(args):
        raise ValueError("an internal invariant broke")

    monkeypatch.setattr(evaluate, "run", bug)
    with pytest.raises(ValueError, match="internal invariant"):
        main(["evaluate", "--policy", "grazing"])

    def mistake(args):
        raise InputError("a value the user can fix")

    monkeypatch.setattr(evaluate, "run", mistake)
    assert main(["evaluate", "--policy", "grazing"]) == 2
    assert capsys.readouterr().err == "sb3-pm evaluate: error: a value the user can fix\n"
