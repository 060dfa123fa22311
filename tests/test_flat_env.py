"""The flat view of the monitoring env (sb3_pm.integrations.flat_env), the one generic MARL
libraries such as BenchMARL train on: flat vectors, the action mask in the infos, failed agents
still reporting."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.integrations.flat_env import FlatMonitoringEnv, flat_parallel_env
from tests.conftest import path_graph


def legal_random(env: FlatMonitoringEnv, infos: dict, rng: np.random.Generator) -> dict[str, int]:
    return {agent: int(rng.choice(np.flatnonzero(infos[agent]["action_mask"]))) for agent in env.agents}


def test_observations_are_flat_scaled_vectors_and_masks_move_to_the_infos() -> None:
    env = flat_parallel_env("paper-50", n_agents=4, max_cycles=30, graph_knowledge="known")
    plain = persistent_monitoring_v0.parallel_env(
        graph="paper-50", n_agents=4, max_cycles=30, graph_knowledge="known"
    )
    observations, infos = env.reset(seed=3)
    originals, _ = plain.reset(seed=3)
    n = 50
    assert env.observation_space("agent_0").shape == (n * 5 + n + 1,)  # known graph: no adjacency
    rng = np.random.default_rng(0)
    for _ in range(30):
        for agent, vector in observations.items():
            original = originals[agent]
            assert vector.dtype == np.float32 and env.observation_space(agent).contains(vector)
            nodes = vector[: n * 5].reshape(n, 5)
            assert np.allclose(nodes[:, 0] * 100, original["nodes"][:, 0])  # u / u_max
            assert np.allclose(nodes[:, 1] * 30, original["nodes"][:, 1])  # age / max_cycles
            assert np.flatnonzero(vector[n * 5 : n * 6]).tolist() == [original["position"]]
            assert np.array_equal(infos[agent]["action_mask"], original["action_mask"])
        actions = legal_random(env, infos, rng)
        observations, rewards, _, truncations, infos = env.step(actions)
        originals, plain_rewards, *_ = plain.step(actions)
        assert rewards == pytest.approx(plain_rewards)
    assert all(truncations.values()) and env.agents == []
    assert all("metrics" in info for info in infos.values())


def test_a_discovered_graph_adds_the_known_adjacency() -> None:
    env = flat_parallel_env("paper-50", n_agents=2, max_cycles=5)
    observations, _ = env.reset(seed=0)
    assert env.observation_space("agent_0").shape == (50 * 5 + 50 + 1 + 50 * 50,)
    assert observations["agent_0"][-2500:].any()  # the edges at its own node, at least


def test_a_failed_agent_keeps_reporting_and_leaves_the_alive_list() -> None:
    env = flat_parallel_env(
        path_graph(5, [0, 4]), n_agents=2, max_cycles=8, initial_positions=[0, 4], failures={"agent_1": 3}
    )
    observations, infos = env.reset(seed=0)
    for step in range(1, 9):
        # an action for the failed agent is given, as a batched library does, and dropped
        observations, rewards, terminations, truncations, infos = env.step({"agent_0": 0, "agent_1": 4})
        assert set(observations) == set(rewards) == set(terminations) == set(infos) == {"agent_0", "agent_1"}
        assert terminations["agent_1"] is (step >= 3) and terminations["agent_0"] is False
        if step > 3:
            assert env.agents == (["agent_0"] if step < 8 else [])
            assert not observations["agent_1"].any() and rewards["agent_1"] == 0.0
    assert all(truncations.values())
    assert infos["agent_1"]["metrics"]["failed_agents"] == 1


def test_bad_settings_are_one_line_errors() -> None:
    with pytest.raises(InputError, match="observation='map'"):
        flat_parallel_env("paper-50", observation="local")
    with pytest.raises(InputError, match="mental-map observation"):
        FlatMonitoringEnv(persistent_monitoring_v0.parallel_env(graph="paper-50", observation="local"))
