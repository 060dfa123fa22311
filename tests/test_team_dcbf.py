"""IndependentPPO with its default algorithm, DCBFPPO (the paper's method), on a tiny graph."""

from __future__ import annotations

import pytest
import torch as th

pytest.importorskip("sb3_pm.ppo_dcbf")

from sb3_pm.agents.training.team import IndependentPPO  # noqa: E402
from sb3_pm.envs import persistent_monitoring_v0  # noqa: E402
from sb3_pm.graphs import erdos_renyi  # noqa: E402
from sb3_pm.zoo.registry import default_algo  # noqa: E402

th.set_num_threads(1)
GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)
ENV = {"max_cycles": 16}
TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 1, "policy_kwargs": {"hidden_dim": 8, "gat_heads": 1}}


def make_team(seed: int = 0) -> IndependentPPO:
    return IndependentPPO(GRAPH, n_agents=2, env_kwargs=ENV, n_envs=2, seed=seed, hyperparams=TINY)


def actions(team: IndependentPPO) -> list[dict[str, int]]:
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, **ENV)
    observations, _ = env.reset(seed=4)
    team.reset(env, seed=4)
    chosen = []
    for _ in range(10):
        step = team.predict_dict(observations, deterministic=True)
        chosen.append(step)
        observations, *_ = env.step(step)
    return chosen


def test_default_algo_is_dcbf_ppo() -> None:
    assert default_algo() == "dcbf_ppo"
    team = make_team()
    assert team.algo == "dcbf_ppo" and type(team.models["agent_0"]).__name__ == "DCBFPPO"


def test_dcbf_team_learns_deterministically_and_round_trips(tmp_path) -> None:
    first, second = make_team(), make_team()
    first.learn(64)
    second.learn(64)
    for agent in first.agents:
        for a, b in zip(first.models[agent].policy.parameters(), second.models[agent].policy.parameters()):
            assert th.equal(a, b)
    folder = first.save(tmp_path / "team")
    loaded = IndependentPPO.load(folder)
    assert loaded.algo == "dcbf_ppo"
    assert actions(loaded) == actions(first)
    loaded.learn(32, reset_num_timesteps=False)
    assert loaded.num_timesteps == 96
