"""PettingZoo API conformance, determinism over whole episodes, spaces and rendering."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import erdos_renyi

SMALL = erdos_renyi(15, 0.3, n_targets=3, seed=2, name="small")


@pytest.mark.parametrize("observation", ["map", "local"])
def test_parallel_api(observation: str) -> None:
    parallel_api_test(
        persistent_monitoring_v0.parallel_env(graph=SMALL, max_cycles=40, observation=observation),
        num_cycles=100,
    )


def test_parallel_api_with_a_known_map() -> None:
    env = persistent_monitoring_v0.parallel_env(
        graph=SMALL, max_cycles=40, target_knowledge="known", graph_knowledge="known"
    )
    parallel_api_test(env, num_cycles=100)


@pytest.mark.parametrize("observation", ["map", "local"])
def test_aec_api(observation: str) -> None:
    api_test(
        persistent_monitoring_v0.env(graph=SMALL, max_cycles=40, observation=observation), num_cycles=100
    )


def rollout(seed: int, policy_seed: int = 0, steps: int = 120, **kwargs) -> tuple[list, list, list]:
    """A whole episode of a seeded random team; returns positions, uncertainties and rewards per step."""
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, max_cycles=steps, **kwargs)
    observations, _ = env.reset(seed=seed)
    rng = np.random.default_rng(policy_seed)
    positions, uncertainties, rewards = [env.unwrapped.positions.tolist()], [], []
    while env.agents:
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, reward, *_ = env.step(actions)
        positions.append(env.unwrapped.positions.tolist())
        uncertainties.append(env.unwrapped.uncertainty.tolist())
        rewards.append(reward)
    return positions, uncertainties, rewards


def test_same_seed_same_episode() -> None:
    assert rollout(7, initial_uncertainty="random") == rollout(7, initial_uncertainty="random")


def test_different_seed_different_episode() -> None:
    assert rollout(7)[0] != rollout(8)[0]
    assert rollout(7, initial_uncertainty="random")[1] != rollout(8, initial_uncertainty="random")[1]


def test_reset_without_seed_continues_the_stream() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL)
    env.reset(seed=3)
    starts = {tuple(env.unwrapped.positions.tolist())}
    for _ in range(5):
        env.reset()
        starts.add(tuple(env.unwrapped.positions.tolist()))
    assert len(starts) > 1


def test_initial_positions_are_distinct() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, n_agents=6)
    for seed in range(20):
        env.reset(seed=seed)
        assert len(set(env.unwrapped.positions.tolist())) == 6


def test_spaces_are_cached_and_observations_fit() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, max_cycles=10)
    assert env.observation_space("agent_0") is env.observation_space("agent_0")
    observations, _ = env.reset(seed=0)
    for agent, obs in observations.items():
        assert env.observation_space(agent).contains(obs)
        assert obs["action_mask"].dtype == np.int8
        reachable = set(SMALL.neighbours(obs["position"]).tolist()) | {obs["position"]}
        assert set(np.flatnonzero(obs["action_mask"]).tolist()) == reachable


def test_kept_observations_are_not_mutated_by_later_steps() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, max_cycles=30)
    observations, _ = env.reset(seed=0)
    kept = {k: np.array(v, copy=True) for k, v in observations["agent_0"].items()}
    held = observations["agent_0"]
    rng = np.random.default_rng(0)
    for _ in range(20):
        observations, *_ = env.step(
            {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        )
    for key, value in kept.items():
        np.testing.assert_array_equal(np.asarray(held[key]), value, err_msg=key)


def test_render_modes() -> None:
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, render_mode="rgb_array", max_cycles=5)
    env.reset(seed=0)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    env.close()
    env = persistent_monitoring_v0.parallel_env(graph=SMALL, render_mode="ansi")
    env.reset(seed=0)
    text = env.render()
    assert "target" in text and "agents:" in text
    with pytest.raises(ValueError, match="render_mode"):
        persistent_monitoring_v0.parallel_env(graph=SMALL).render()
