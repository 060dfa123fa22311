"""Gymnasium registration of the single-agent view: ids, check_env, stock SB3 learners."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from sb3_contrib import MaskablePPO
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env

import sb3_pm
from sb3_pm.baselines import LocalGreedyTeam
from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.evaluation import PolicyError
from sb3_pm.ppo_dcbf import DCBFPPO
from sb3_pm.registration import ENV_IDS, register_envs

th.set_num_threads(1)

PAPER50 = "sb3_pm/PersistentMonitoring-paper50-v0"
# A short episode keeps the learning tests to a few hundred steps of real work.
SHORT = {"max_cycles": 32}


def test_import_registers_ids_without_torch() -> None:
    # A fresh interpreter: importing sb3_pm must register the ids and load neither torch nor SB3.
    code = (
        "import sys, gymnasium as gym, sb3_pm\n"
        "ids = [i for i in gym.envs.registry if i.startswith('sb3_pm/')]\n"
        "assert 'sb3_pm/PersistentMonitoring-paper50-v0' in ids, ids\n"
        "assert 'torch' not in sys.modules and 'stable_baselines3' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_ids_are_registered_once() -> None:
    assert {"paper50", "paper100", "paper200"} <= {i.split("-")[1] for i in ENV_IDS}
    assert register_envs() == list(ENV_IDS)  # idempotent: a second call changes nothing
    for env_id in ENV_IDS:
        spec = gym.spec(env_id)
        assert spec.max_episode_steps is None  # the env truncates itself; no TimeLimit on top


@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_each_id_makes_resets_and_steps(env_id: str) -> None:
    env = gym.make(env_id, **SHORT)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation)
    n_nodes = env.unwrapped.env.graph.n_nodes
    expected = {"paper50": 50, "paper100": 100, "paper200": 200}.get(env_id.split("-")[1], 50)
    assert env.action_space.n == n_nodes == expected
    mask = env.unwrapped.action_masks()
    assert mask.dtype == bool and mask.shape == (n_nodes,) and mask[observation["position"]]
    action = int(np.flatnonzero(mask)[0])
    observation, reward, terminated, truncated, info = env.step(action)
    assert env.observation_space.contains(observation)
    assert isinstance(float(reward), float) and not terminated and not truncated
    env.close()


def test_check_env_passes() -> None:
    env = gym.make(PAPER50, teammates="local_greedy", **SHORT)
    check_env(env.unwrapped, warn=False)
    check_env(env, warn=False)


def test_episode_truncates_at_max_cycles_once() -> None:
    env = gym.make(PAPER50, max_cycles=7)
    env.reset(seed=1)
    for step in range(1, 8):
        _, _, terminated, truncated, info = env.step(int(env.unwrapped.action_masks().argmax()))
        assert not terminated
        assert truncated == (step == 7)
    assert info["metrics"]["steps"] == 7


def test_teammates_by_name_instance_and_none() -> None:
    assert isinstance(gym.make(PAPER50, teammates="local_greedy").unwrapped.teammates, LocalGreedyTeam)
    team = LocalGreedyTeam()
    assert gym.make(PAPER50, teammates=team).unwrapped.teammates is team
    assert gym.make(PAPER50, teammates=None).unwrapped.teammates is None
    env = gym.make("sb3_pm/PersistentMonitoring-v0", graph="paper-100", n_agents=3, agent="agent_2")
    assert isinstance(env.unwrapped, SingleAgentMonitoringEnv)
    assert env.unwrapped.agent == "agent_2" and len(env.unwrapped.teammate_names) == 2
    with pytest.raises(PolicyError):
        gym.make(PAPER50, teammates="no_such_baseline")
    with pytest.raises(TypeError):
        gym.make(PAPER50, teammates=3.5)


def test_same_seed_same_episode() -> None:
    def rollout() -> list[float]:
        env = gym.make(PAPER50, teammates="random", **SHORT)
        env.reset(seed=3)
        rng = np.random.default_rng(0)
        rewards = []
        for _ in range(10):
            action = int(rng.choice(np.flatnonzero(env.unwrapped.action_masks())))
            rewards.append(float(env.step(action)[1]))
        return rewards

    assert rollout() == rollout()


@pytest.mark.parametrize(
    ("algo", "policy"),
    [
        (PPO, "MultiInputPolicy"),
        (MaskablePPO, "MultiInputPolicy"),
        (DCBFPPO, "DCBFPolicy"),
        (DCBFPPO, sb3_pm.ppo_dcbf.policies.DCBFPolicy),  # by dotted path
    ],
)
def test_stock_learners_train_unchanged(algo: type, policy: object) -> None:
    env = gym.make(PAPER50, **SHORT)
    model = algo(policy, env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps == 256
    observation, _ = env.reset(seed=0)
    action, _ = model.predict(observation, deterministic=True)
    assert 0 <= int(action) < env.action_space.n


def test_dcbf_policy_dotted_path_is_the_alias() -> None:
    from sb3_pm.policies.policy import DCBFActorCriticPolicy

    assert sb3_pm.ppo_dcbf.policies.DCBFPolicy is DCBFActorCriticPolicy
    assert DCBFPPO.policy_aliases["DCBFPolicy"] is DCBFActorCriticPolicy
    assert sb3_pm.DCBFPolicy is DCBFActorCriticPolicy
