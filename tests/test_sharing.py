"""The SuperSuit parameter-sharing path: truncation kept, masks served, seeding works."""

from __future__ import annotations

import numpy as np
from sb3_contrib import MaskablePPO

from sb3_pm.graphs import erdos_renyi
from sb3_pm.sharing import make_parameter_sharing_vec_env

GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1, name="tiny")


def make(n_envs: int = 1):
    return make_parameter_sharing_vec_env(GRAPH, n_envs=n_envs, n_agents=2, env_kwargs={"max_cycles": 8})


def run_episode(venv, seed: int) -> tuple[list, list]:
    venv.seed(seed)
    venv.reset()
    dones, infos, positions = [], [], []
    for _ in range(8):
        masks = np.stack(venv.env_method("action_masks"))
        assert masks.shape == (venv.num_envs, GRAPH.n_nodes)
        actions = np.array([np.flatnonzero(row)[-1] for row in masks])
        observations, _, done, info = venv.step(actions)
        dones.append(done.tolist())
        infos.append(info)
        positions.append(observations["position"].tolist())
    return dones, infos, positions


def test_timeouts_are_marked_as_truncations() -> None:
    dones, infos, _ = run_episode(make(n_envs=2), seed=0)
    assert dones[-1] == [True] * 4 and not any(any(row) for row in dones[:-1])
    for info in infos[-1]:
        assert info["TimeLimit.truncated"] is True
        assert "terminal_observation" in info and "episode" in info


def test_seeding_reproduces_episodes() -> None:
    assert run_episode(make(), seed=5)[2] == run_episode(make(), seed=5)[2]
    assert run_episode(make(), seed=5)[2] != run_episode(make(), seed=6)[2]


def test_maskable_ppo_trains_one_shared_model() -> None:
    venv = make()
    model = MaskablePPO("MultiInputPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, seed=0)
    model.learn(64)
    assert model.num_timesteps >= 64
