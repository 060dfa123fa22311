"""An evaluation stopped by Ctrl-C or SIGTERM keeps the episodes it finished: ``--json`` holds them,
marked partial, and the command says so in one line and exits with 130 (Ctrl-C) or 143 (SIGTERM)."""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_pm.baselines import make_team
from sb3_pm.cli import main
from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv
from sb3_pm.evaluation import EvaluationInterrupted, EvaluationResult, evaluate
from sb3_pm.evaluation.records import load_record

STEPS = 20
ARGV = ["evaluate", "--policy", "grazing", "--agents", "2", "--steps", str(STEPS), "--episodes", "10"]


def interrupt_after(monkeypatch: pytest.MonkeyPatch, finished: int) -> None:
    """Ctrl-C in the middle of episode ``finished`` (counting from 0): ``finished`` episodes done."""
    step = PersistentMonitoringEnv.step
    calls = {"n": 0}

    def stepping(self: PersistentMonitoringEnv, actions: dict) -> tuple:
        calls["n"] += 1
        if calls["n"] == finished * STEPS + STEPS // 2:
            raise KeyboardInterrupt
        return step(self, actions)

    monkeypatch.setattr(PersistentMonitoringEnv, "step", stepping)


def test_ctrl_c_keeps_the_finished_episodes_in_json(tmp_path, monkeypatch, capsys) -> None:
    target = tmp_path / "r.json"
    target.write_text('{"an": "older record"}')
    interrupt_after(monkeypatch, 3)
    assert main([*ARGV, "--json", str(target)]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    said = f"sb3-pm evaluate: interrupted after 3 of 10 episodes; wrote them to {target}, marked partial"
    assert err == [said]
    payload = json.loads(target.read_text())
    assert (payload["partial"], payload["episodes_finished"], payload["episodes_requested"]) == (True, 3, 10)
    assert [episode["seed"] for episode in payload["episodes"]] == [0, 1, 2]
    assert payload["config"]["episodes"] == 10
    record = load_record(target)  # still an evaluation record (sb3-pm effect reads it)
    assert record.partial and len(record.episodes) == 3 and record.episodes_requested == 10


def test_the_partial_episodes_equal_those_of_a_whole_run(monkeypatch) -> None:
    whole = evaluate(make_team("grazing"), "paper-50", n_agents=2, episodes=3, max_cycles=STEPS)
    interrupt_after(monkeypatch, 2)
    with pytest.raises(EvaluationInterrupted) as stopped:
        evaluate(make_team("grazing"), "paper-50", n_agents=2, episodes=3, max_cycles=STEPS)
    partial = stopped.value.result
    assert isinstance(stopped.value, KeyboardInterrupt) and stopped.value.exit_status == 130
    assert [r.metrics for r in partial.episodes] == [r.metrics for r in whole.episodes[:2]]
    copy = pickle.loads(pickle.dumps(stopped.value))  # as a sweep's worker process sends it
    assert isinstance(copy, EvaluationInterrupted) and len(copy.result.episodes) == 2
    restored = EvaluationResult.from_dict(partial.to_dict(traces=True))
    assert restored.partial and restored.episodes_requested == 3
    assert not whole.partial and "partial" not in whole.to_dict()


def test_ctrl_c_before_an_episode_finished_leaves_the_json_alone(tmp_path, monkeypatch, capsys) -> None:
    target = tmp_path / "r.json"
    target.write_text('{"an": "older record"}')
    interrupt_after(monkeypatch, 0)
    assert main([*ARGV, "--json", str(target)]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"sb3-pm evaluate: interrupted after 0 of 10 episodes; {target} left as it was"]
    assert target.read_text() == '{"an": "older record"}'


#: The command line in a child process that says when each episode has finished (so that the test
#: sends SIGTERM after some, not after a guessed time).
CHILD = """
import sys
from sb3_pm.cli import main
from sb3_pm.evaluation import harness
run_episode = harness.run_episode
def told(*args, **kwargs):
    record = run_episode(*args, **kwargs)
    print("episode", flush=True)
    return record
harness.run_episode = told
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_keeps_the_finished_episodes_and_exits_143(tmp_path) -> None:
    target = tmp_path / "r.json"
    argv = ["evaluate", "--policy", "grazing", "--agents", "2", "--steps", "200", "--episodes", "1000"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, *argv, "--json", str(target), "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert child.stdout is not None
        for _ in range(3):  # the third is still being returned: two are surely kept
            assert child.stdout.readline().strip() == "episode"
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 143
    payload = json.loads(target.read_text())
    finished = payload["episodes_finished"]
    assert payload["partial"] is True and 2 <= finished < 1000 and len(payload["episodes"]) == finished
    said = f"sb3-pm evaluate: interrupted after {finished} of 1000 episodes; wrote them to {target}"
    said += ", marked partial"
    assert err.strip().splitlines() == [said]
