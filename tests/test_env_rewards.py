"""Reward terms (docs/METHOD.md "Reward", paper eq. 5-8) computed by hand on a path graph."""

from __future__ import annotations

import pytest

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.rewards import REWARD_PRESETS, resolve_reward
from sb3_pm.errors import InputError
from tests.conftest import path_graph


def make(reward, positions, max_cycles=50, n_nodes=3, targets=(2,)):
    env = persistent_monitoring_v0.parallel_env(
        graph=path_graph(n_nodes, list(targets)),
        n_agents=len(positions),
        initial_positions=positions,
        reward=reward,
        max_cycles=max_cycles,
    )
    env.reset(seed=0)
    return env


def test_paper_preset_weights() -> None:
    assert resolve_reward("paper") == {"collision": 0.05, "change": 0.05, "momentum": 0.05}
    assert set(REWARD_PRESETS) >= {"paper", "reduction"}


def test_collision_term() -> None:
    env = make({"collision": 1.0}, [0, 2])
    _, rewards, *_ = env.step({"agent_0": 1, "agent_1": 1})
    assert rewards == {"agent_0": -3.0, "agent_1": -3.0}
    _, rewards, *_ = env.step({"agent_0": 0, "agent_1": 1})
    assert rewards == {"agent_0": 0.0, "agent_1": 0.0}


def test_momentum_counter_carries_its_value_and_resets() -> None:
    env = make({"momentum": 1.0}, [0])
    values = []
    for destination in (0, 1, 2, 2, 2, 2):
        # u2 before each arrival: -, -, 2 (grew 0->1->2), 1, 0, 0
        _, rewards, *_ = env.step({"agent_0": destination})
        values.append(rewards["agent_0"])
    assert values == [-1, -2, -1, 0, -1, -2]
    env.reset(seed=0)
    _, rewards, *_ = env.step({"agent_0": 0})
    assert rewards["agent_0"] == -1


def test_reduction_is_the_marginal_effect() -> None:
    env = make({"reduction": 1.0}, [0, 0])
    env.step({"agent_0": 1, "agent_1": 0})  # u2 = 1
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 0})  # u2: 1 -> 0 instead of 2
    assert rewards == {"agent_0": 2.0, "agent_1": 0.0}
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 1})  # u2 stays 0 instead of 1
    assert rewards["agent_0"] == 1.0
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 2})  # shared: neither alone is needed
    assert rewards == {"agent_0": 0.0, "agent_1": 0.0}


def test_clearing_pays_only_for_lowering_u() -> None:
    env = make({"clearing": 1.0}, [0, 0])
    _, rewards, *_ = env.step({"agent_0": 1, "agent_1": 0})  # u2 = 1, nobody on the target
    assert rewards == {"agent_0": 0.0, "agent_1": 0.0}
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 0})  # u2: 1 -> 0
    assert rewards == {"agent_0": 1.0, "agent_1": 0.0}
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 1})  # u2 stays 0: guarding earns nothing
    assert rewards["agent_0"] == 0.0
    env.step({"agent_0": 1, "agent_1": 1})
    env.step({"agent_0": 1, "agent_1": 1})  # u2 = 2
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 2})  # shared: u2 2 -> 1, but not alone
    assert rewards == {"agent_0": 0.0, "agent_1": 0.0}


def test_change_is_paid_at_the_last_step_against_past_episodes() -> None:
    env = make({"change": 1.0}, [2], max_cycles=2)
    # Episode 1: stay on target 2. Map u sum: step 1 u2 = 0, step 2 u2 = 0 -> U = 0; no history yet.
    _, r1, *_ = env.step({"agent_0": 2})
    _, r2, *_ = env.step({"agent_0": 2})
    assert r1["agent_0"] == 0.0 and r2["agent_0"] == 0.0
    # Episode 2: walk away; node 2 is seen from 1 (u2 = 1), then not seen (stale 1): U = 1 + 1 = 2.
    env.reset(seed=0)
    _, r1, *_ = env.step({"agent_0": 1})
    _, r2, *_ = env.step({"agent_0": 0})
    assert r1["agent_0"] == 0.0
    assert r2["agent_0"] == pytest.approx(0.0 - 2.0)  # mean of past U (0) minus this U (2)
    # Episode 3: past U are {0, 2}: mean 1; stay put on 2 again -> U = 0 -> change = +1.
    env.reset(seed=0)
    env.step({"agent_0": 2})
    _, r2, *_ = env.step({"agent_0": 2})
    assert r2["agent_0"] == pytest.approx(1.0)


def test_unknown_terms_are_rejected() -> None:
    with pytest.raises(ValueError, match="unknown reward terms"):
        resolve_reward({"distance": 1.0})
    with pytest.raises(ValueError, match="at least one term"):
        resolve_reward({})


def test_territory_pays_only_on_the_agents_own_targets() -> None:
    # Path 0-1-2-3-4, targets 0 and 4: territories split them one each, agent_0 owning the target
    # with the lower index (0) and agent_1 the other (4).
    reward = {"clearing": 0.04, "territory": 0.5}
    crossed = make(reward, [3, 1], n_nodes=5, targets=(0, 4))
    crossed.step({"agent_0": 3, "agent_1": 1})  # u0 = u4 = 1
    _, rewards, *_ = crossed.step({"agent_0": 4, "agent_1": 0})  # each clears the other's target
    assert rewards == {"agent_0": 0.04, "agent_1": 0.04}
    own = make(reward, [1, 3], n_nodes=5, targets=(0, 4))
    own.step({"agent_0": 1, "agent_1": 3})
    _, rewards, *_ = own.step({"agent_0": 0, "agent_1": 4})  # each clears its own target
    assert rewards == {"agent_0": pytest.approx(0.54), "agent_1": pytest.approx(0.54)}
    _, rewards, *_ = own.step({"agent_0": 0, "agent_1": 4})  # guarding a clean target pays nothing
    assert rewards == {"agent_0": 0.0, "agent_1": 0.0}


def test_the_territory_reward_is_refused_on_a_graph_family() -> None:
    with pytest.raises(InputError, match="territory reward needs one graph or territory_input"):
        persistent_monitoring_v0.parallel_env(graph="family:er", reward={"clearing": 0.04, "territory": 0.04})
