"""Fixtures: tiny hand-built graphs and the folder of the published graphs shipped in the package."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from sb3_pm.graphs import GraphSpec
from sb3_pm.graphs.presets import DATA_DIR

#: The repository root, where child processes run.
ROOT = Path(__file__).resolve().parent.parent

# Tests run two workers on two cores: one torch thread each avoids oversubscription.
torch.set_num_threads(1)


def episode_moves(env, team, seed: int) -> list[dict[str, int]]:
    """Every step's ``{agent: destination}`` of ``team`` over one episode of the parallel ``env``."""
    observations, _ = env.reset(seed=seed)
    team.reset(env, seed=seed)
    moves = []
    while env.agents:
        actions = team.predict_dict(observations)
        moves.append(actions)
        observations, *_ = env.step(actions)
    return moves


def path_graph(n_nodes: int, targets: list[int], name: str = "path") -> GraphSpec:
    """0 - 1 - ... - (n-1), with the given target nodes."""
    adjacency = np.zeros((n_nodes, n_nodes), dtype=bool)
    for i in range(n_nodes - 1):
        adjacency[i, i + 1] = adjacency[i + 1, i] = True
    flags = np.zeros(n_nodes, dtype=bool)
    flags[targets] = True
    return GraphSpec(adjacency=adjacency, targets=flags, name=name)


@pytest.fixture
def published_graphs() -> Path:
    """The folder of the paper's published GraphML files, as the package ships them."""
    assert sorted(path.name for path in DATA_DIR.glob("*.graphml")) == [
        "paper_100n_17t.graphml",
        "paper_200n_41t.graphml",
        "paper_50n_8t.graphml",
    ], f"the package's graph data is incomplete: {DATA_DIR}"
    return DATA_DIR


#: A team config small enough for end-to-end ``sb3-pm train`` runs in a second or two.
TINY_CONFIG = """
default:
  n_timesteps: 100000
  n_envs: 1
  n_agents: 2
  algo: maskable_ppo
  n_steps: 16
  batch_size: 16
  n_epochs: 1
  learning_rate: lin_1e-3
  env_kwargs: {max_cycles: 10}
"""


@pytest.fixture()
def tiny_train(tmp_path: Path) -> tuple[Path, Path, Path]:
    """``(config, graph, out)``: the tiny config, a 12-node GraphML graph and a run folder path."""
    from sb3_pm.graphs import erdos_renyi, save_graphml

    config = tmp_path / "tiny.yml"
    config.write_text(textwrap.dedent(TINY_CONFIG))
    graph = save_graphml(erdos_renyi(12, 0.3, n_targets=3, seed=1), tmp_path / "g12.graphml")
    return config, graph, tmp_path / "run"


def child_result(script: str, timeout: int) -> dict:
    """Run ``script`` in a fresh Python process (its own peak memory, one thread) and return the
    JSON of its last line; the child's error output if it fails."""
    done = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"},
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])
