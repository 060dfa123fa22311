"""Sizes are checked before work starts: a graph too large for the host is refused in one line,
before any run folder exists or any env is built (sb3_pm.zoo.memory)."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.cli import main
from sb3_pm.graphs import GraphSpec
from sb3_pm.zoo import memory
from sb3_pm.zoo.memory import MemoryCheckError, MemoryEstimate, check_memory, training_estimate

GiB = 2**30


def test_training_estimate_arithmetic() -> None:
    """4 nodes (16 pairs), 2 agents, 1 env copy, rollouts of 16 steps, minibatches of 16, 4 heads."""
    estimate = training_estimate(4, 2, n_envs=1, n_steps=16, batch_size=16, heads=4, layers=2)
    parts = dict(estimate.parts)
    assert parts["graph"] == 16 * 14  # adjacency, reachable, hop distances int32, scipy's float64
    assert parts["env copies"] == 16 * (
        2 + 2 * 2
    )  # two observation balls; a map and an observation per agent
    # one buffer per learner: 16 steps x 1 env of (adjacency int8 + 7 float32 features and a mask per node)
    assert parts["rollout buffers"] == 2 * 16 * (16 + 4 * (4 * 7 + 1))
    # the minibatch's adjacency as float32, and two (16, 4, 4, 4) float32 scores per GAT layer
    assert parts["largest minibatch"] == 16 * 16 * 4 * (1 + 4 * 2 * 2)
    assert estimate.total == sum(parts.values())
    sparse = training_estimate(4, 2, n_envs=1, n_steps=16, batch_size=16, dense_attention=False)
    assert dict(sparse.parts)["largest minibatch"] == 16 * 16 * 4
    flat = dict(training_estimate(4, 2, n_envs=1, n_steps=16, batch_size=16, flat_policy=True).parts)
    assert flat["largest minibatch"] == 16 * 16 * 4 and flat["flat policy layers"] == 2 * (
        2 * 64 * 16 * 4 * 4
    )


def test_check_memory_refuses_and_warns(capsys) -> None:
    estimate = MemoryEstimate((("graph", 3 * GiB), ("env copies", 1 * GiB)))
    with pytest.raises(
        MemoryCheckError, match=r"needs about 4\.0 GiB \(graph 3\.0 GiB.*more than the 2\.0 GiB"
    ):
        check_memory(estimate, "training", available=2 * GiB)
    check_memory(estimate, "training", available=6 * GiB)
    assert "warning: training needs about 4.0 GiB" in capsys.readouterr().err
    check_memory(estimate, "training", available=100 * GiB)
    assert capsys.readouterr().err == ""
    assert memory.available_memory() is None or memory.available_memory() > 0


@pytest.fixture(scope="module")
def big_cycle() -> GraphSpec:
    """A 20,000-node cycle: dense (N, N) matrices of any kind make it gigabytes."""
    n = 20_000
    adjacency = np.zeros((n, n), dtype=bool)
    nodes = np.arange(n)
    adjacency[nodes, (nodes + 1) % n] = adjacency[(nodes + 1) % n, nodes] = True
    targets = np.zeros(n, dtype=bool)
    targets[::100] = True
    return GraphSpec(adjacency=adjacency, targets=targets, name="cycle-20000")


@pytest.fixture()
def no_env_built(monkeypatch, big_cycle):
    """The big cycle as the graph every name resolves to, 8 GiB available, and no env constructor."""
    from sb3_pm.envs.core import MonitoringCore
    from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv

    def refuse(*args, **kwargs):
        raise AssertionError("an env was built before the memory check")

    monkeypatch.setattr(PersistentMonitoringEnv, "__init__", refuse)
    monkeypatch.setattr(MonitoringCore, "__init__", refuse)
    monkeypatch.setattr("sb3_pm.graphs.resolve_graph", lambda name: big_cycle)
    monkeypatch.setattr("sb3_pm.graphs.resolve_graph_or_family", lambda name: big_cycle)
    monkeypatch.setattr(memory, "available_memory", lambda: 8 * GiB)
    for attribute in ("hop_distances", "next_hop"):  # derived (N, N) matrices: not computed either
        assert attribute not in vars(big_cycle)
    yield
    for attribute in ("hop_distances", "next_hop"):
        assert attribute not in vars(big_cycle)


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_train_refuses_a_graph_too_large_before_the_run_folder(tmp_path, capsys, no_env_built) -> None:
    out = tmp_path / "run"
    assert main(["train", "--env", "cycle", "--out", str(out), "--no-progress"]) == 2
    err = one_line(capsys)
    assert "training 4 agents on cycle needs about" in err and "rollout buffers" in err
    assert "more than the 8.0 GiB of memory available" in err
    assert not out.exists()


def test_evaluate_refuses_a_graph_too_large_before_the_env(capsys, no_env_built) -> None:
    argv = ["evaluate", "--policy", "random", "--graph", "cycle", "--steps", "20", "--episodes", "1"]
    assert main(argv) == 2
    err = one_line(capsys)
    assert (
        "evaluating random (4 agents) on cycle needs about 8.9 GiB (graph 5.2 GiB, env copies 3.7 GiB)" in err
    )


def test_evaluate_refuses_before_a_saved_team_loads(tmp_path, capsys, monkeypatch, no_env_built) -> None:
    """A saved team builds its training env copies as it loads: the check comes first."""
    import json

    from sb3_pm.agents.training.team import IndependentPPO

    def refuse(*args, **kwargs):
        raise AssertionError("the team loaded before the memory check")

    monkeypatch.setattr(IndependentPPO, "load", refuse)
    team = tmp_path / "team"
    team.mkdir()
    (team / "manifest.json").write_text(
        json.dumps({"n_agents": 2, "n_envs": 2, "agents": ["agent_0", "agent_1"]})
    )
    assert (
        main(["evaluate", "--policy", str(team), "--graph", "cycle", "--steps", "20", "--episodes", "1"]) == 2
    )
    err = one_line(capsys)
    assert f"evaluating {team} (2 agents) on cycle needs about" in err and "forward pass" in err


def test_compare_refuses_a_graph_too_large_before_the_env(tmp_path, capsys, no_env_built) -> None:
    out = tmp_path / "cmp"
    argv = ["compare", "--policies", "random", "--graphs", "cycle", "--steps", "20", "--episodes", "1"]
    assert main([*argv, "--out", str(out)]) == 2
    assert "evaluating random (4 agents) on cycle needs about" in one_line(capsys)
    assert not out.exists()


def test_reproduce_checks_its_cells_before_the_sweep_folder(tmp_path, capsys, monkeypatch) -> None:
    """The largest cell alone, then the cells --jobs runs side by side, before anything is written."""
    from sb3_pm.experiments import load_experiment
    from sb3_pm.experiments.memory_needs import cell_estimate
    from sb3_pm.experiments.runner import plan_cells
    from tests.test_experiments import tiny_experiment

    path = tiny_experiment(tmp_path)
    graph = str(tmp_path / "tiny.graphml")
    experiment = load_experiment(path).with_graphs([graph])
    totals = sorted(
        (cell_estimate(cell, {}).total for cell in plan_cells(experiment, tmp_path / "o")), reverse=True
    )
    assert totals[0] > totals[-1] > 0  # training a learned cell takes more than evaluating a baseline
    argv = ["reproduce", str(path), "--out", str(tmp_path / "o"), "--graphs", graph, "--no-progress"]
    monkeypatch.setattr(memory, "available_memory", lambda: totals[0] - 1)
    assert main([*argv, "--jobs", "1"]) == 2
    assert "tiny: its largest cell needs about" in one_line(capsys)
    monkeypatch.setattr(memory, "available_memory", lambda: totals[0] + totals[1] - 1)
    assert main([*argv, "--jobs", "2"]) == 2
    assert "tiny: 2 cells side by side (--jobs 2) needs about" in one_line(capsys)
    assert not (tmp_path / "o").exists()
