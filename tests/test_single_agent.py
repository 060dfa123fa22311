"""The single-agent Gymnasium view (one learner among fixed teammates)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from sb3_contrib import MaskablePPO
from stable_baselines3.common.env_checker import check_env

from sb3_pm.envs.single_agent import SingleAgentMonitoringEnv
from sb3_pm.graphs import erdos_renyi
from sb3_pm.team_interface import Team

GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)


def make_env(**kwargs: Any) -> SingleAgentMonitoringEnv:
    return SingleAgentMonitoringEnv(GRAPH, **{"n_agents": 3, "max_cycles": 20, **kwargs})


def rollout(env: SingleAgentMonitoringEnv, seed: int, steps: int = 20) -> list[tuple[Any, ...]]:
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    trace: list[tuple[Any, ...]] = [(obs["position"], obs["nodes"].copy(), obs["adjacency"].copy())]
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(int(rng.choice(np.flatnonzero(env.action_masks()))))
        trace.append(
            (obs["position"], obs["nodes"].copy(), reward, terminated, truncated, tuple(env.env.positions))
        )
    return trace


def same(a: list[tuple[Any, ...]], b: list[tuple[Any, ...]]) -> bool:
    return all(all(np.array_equal(x, y) for x, y in zip(ra, rb)) for ra, rb in zip(a, b))


@pytest.mark.filterwarnings("ignore:Your observation")
def test_check_env() -> None:
    check_env(make_env(), warn=True)


def test_spaces_and_masks() -> None:
    env = make_env(agent="agent_2")
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and info == {}
    mask = env.action_masks()
    assert mask.dtype == bool and mask.shape == (12,)
    assert np.array_equal(mask, GRAPH.reachable[env.env.positions[2]])


def test_truncation_and_metrics() -> None:
    env = make_env()
    env.reset(seed=1)
    for step in range(20):
        _, _, terminated, truncated, info = env.step(int(np.flatnonzero(env.action_masks())[0]))
        assert not terminated
        assert truncated == (step == 19)
    assert {"avg_uncertainty", "max_neglect", "collisions"} <= set(info["metrics"])


def test_same_seed_same_episode_even_after_other_episodes() -> None:
    env = make_env()
    first = rollout(env, seed=4)
    rollout(env, seed=5)  # discovers other edges; a seeded reset must forget them
    assert same(first, rollout(env, seed=4))
    assert not same(first, rollout(env, seed=6))


def test_unseeded_reset_keeps_discovered_edges() -> None:
    env = make_env()
    rollout(env, seed=0)
    known = env.env.maps.adjacency[0].sum()
    env.reset()
    assert env.env.maps.adjacency[0].sum() == known > 0


def test_illegal_action_is_a_stay_and_reported() -> None:
    env = make_env()
    env.reset(seed=0)
    position = env.env.positions[0]
    illegal = int(np.flatnonzero(~env.action_masks())[0])
    _, _, _, _, info = env.step(illegal)
    assert env.env.positions[0] == position and info["illegal_action"] == illegal


class Stay(Team):
    name = "stay"

    def predict_dict(self, observations: dict[str, Any], deterministic: bool = True) -> dict[str, int]:
        return {agent: int(obs["position"]) for agent, obs in observations.items()}


def test_teammates_team_drives_the_others() -> None:
    env = make_env(teammates=Stay())
    env.reset(seed=0)
    start = env.env.positions
    env.step(int(np.flatnonzero(env.action_masks())[0]))
    assert np.array_equal(env.env.positions[1:], start[1:])


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="agent"):
        make_env(agent="agent_9")
    with pytest.raises(ValueError, match="map"):
        make_env(observation="local")


def test_stock_maskable_ppo_learns_a_few_steps() -> None:
    model = MaskablePPO("MultiInputPolicy", make_env(), n_steps=16, batch_size=16, n_epochs=1, seed=0)
    model.learn(32)
    assert model.num_timesteps == 32
    actions = model.rollout_buffer.actions.reshape(-1).astype(int)
    masks = model.rollout_buffer.action_masks.reshape(len(actions), -1).astype(bool)
    assert masks[np.arange(len(actions)), actions].all()
