"""The centralized comparison: one shared map, estimator and network, same model code."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.evaluation import resolve_team
from sb3_pm.graphs import erdos_renyi
from sb3_pm.sharing.centralized import CentralizedPPO
from sb3_pm.zoo import load_config

GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1, name="tiny")
HYPER = {"n_steps": 16, "batch_size": 32, "n_epochs": 1, "policy_kwargs": {"hidden_dim": 8, "gat_heads": 1}}


def make(seed: int = 0) -> CentralizedPPO:
    return CentralizedPPO(GRAPH, n_agents=2, env_kwargs={"max_cycles": 20}, seed=seed, hyperparams=HYPER)


def test_one_network_for_the_team_on_a_shared_map() -> None:
    team = make()
    assert team.env_kwargs["shared_map"] is True
    assert type(team.model).__name__ == "DCBFPPO"
    assert team.model.env.num_envs == 2  # one vector entry per agent: the same network acts for both
    team.learn(32)
    assert team.num_timesteps == 32  # per agent, as IndependentPPO counts


def test_save_load_gives_identical_actions(tmp_path: Path) -> None:
    team = make()
    team.learn(32)
    team.save(tmp_path / "c")
    loaded = resolve_team(str(tmp_path / "c"), graph=GRAPH)
    assert isinstance(loaded, CentralizedPPO)
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, max_cycles=20, shared_map=True)
    observations, _ = env.reset(seed=3)
    while env.agents:
        a, b = team.predict_dict(observations), loaded.predict_dict(observations)
        assert a == b
        observations, *_ = env.step(a)


def test_same_seed_same_parameters() -> None:
    params = []
    for _ in range(2):
        team = make(seed=4)
        team.learn(32)
        params.append(th.nn.utils.parameters_to_vector(team.model.policy.parameters()).detach().numpy())
    np.testing.assert_array_equal(params[0], params[1])


def test_needs_a_shared_map_env() -> None:
    team = make()
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, max_cycles=20)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shared_map=True"):
        team.reset(env, seed=0)


def test_logs_episode_metrics_like_the_decentralized_team(tmp_path: Path) -> None:
    from sb3_pm.experiments.curves import read_scalars

    team = CentralizedPPO(
        GRAPH,
        n_agents=2,
        env_kwargs={"max_cycles": 20},
        seed=0,
        hyperparams=HYPER,
        tensorboard_log=str(tmp_path),
    )
    team.learn(40)  # two 20-step episodes per agent
    [(steps, values)] = read_scalars(tmp_path, "metrics/avg_uncertainty")
    assert len(steps) >= 1 and (values >= 0).all()


def test_a_config_that_sets_learners_apart_is_refused() -> None:
    """One network has one learning rate: the default's spread and per-agent blocks are errors."""
    config = load_config("ippo", "paper-50")
    assert config.learning_rate_spread != 1.0
    with pytest.raises(InputError, match="learning_rate_spread makes no sense for a centralized team"):
        CentralizedPPO.from_config(config, "paper-50")
    config.learning_rate_spread = 1.0
    config.agents = {"agent_1": {"learning_rate": 1e-4}}
    with pytest.raises(InputError, match="per-agent overrides make no sense for a centralized team"):
        CentralizedPPO.from_config(config, "paper-50")
    config.agents = {}
    with pytest.raises(InputError, match="territory reward makes no sense for a centralized team"):
        CentralizedPPO.from_config(config, "paper-50")
