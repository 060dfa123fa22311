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


def test_urgency_pays_the_cleared_targets_uncertainty_where_clearing_pays() -> None:
    # Path 0-1-2, target 2. agent_1 waits at 0 while u2 grows; agent_0 clears it alone.
    env = make({"urgency": 1.0}, [0, 0])
    for _ in range(4):  # u2 = 4, nobody on the target: nothing paid
        _, rewards, *_ = env.step({"agent_0": 1, "agent_1": 0})
        assert rewards == {"agent_0": 0.0, "agent_1": 0.0}
    env.step({"agent_0": 1, "agent_1": 0})  # u2 = 5
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 0})  # found at 5 -> 4: 5 / u_max
    assert rewards == {"agent_0": pytest.approx(5 / 100), "agent_1": 0.0}
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 1})  # found at 4 -> 3
    assert rewards["agent_0"] == pytest.approx(4 / 100)
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 2})  # shared: clearing does not pay, nor this
    assert rewards == {"agent_0": 0.0, "agent_1": 0.0}
    for _ in range(3):
        env.step({"agent_0": 2, "agent_1": 1})  # u2 -> 0
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 1})  # guarding a clean target: 0
    assert rewards["agent_0"] == 0.0


def test_urgency_adds_to_clearing_and_leaves_it_unchanged() -> None:
    # Path 0-1-2, target 2. u2 after each step: 1, 2 (walking up), found at 2 -> 1, found at 1 -> 0,
    # away -> 1, found at 1 -> 0, guarding 0. Clearing pays 0.04 per unit lowered, urgency
    # 0.5 * u_before / u_max on the same steps.
    moves = (1, 1, 2, 2, 1, 2, 2)
    clearing_by_hand = [0.0, 0.0, 0.04, 0.04, 0.0, 0.04, 0.0]
    u_before_by_hand = [0, 0, 2, 1, 0, 1, 0]
    plain, both = make({"clearing": 0.04}, [0]), make({"clearing": 0.04, "urgency": 0.5}, [0])
    for destination, clearing, u_before in zip(moves, clearing_by_hand, u_before_by_hand, strict=True):
        _, r_plain, *_ = plain.step({"agent_0": destination})
        _, r_both, *_ = both.step({"agent_0": destination})
        assert r_plain["agent_0"] == clearing  # bit for bit: 0.04 * 1.0, as before the term existed
        assert r_both["agent_0"] == pytest.approx(clearing + 0.5 * u_before / 100)


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


def test_neglect_penalizes_the_worst_known_target_projection() -> None:
    # Path 0-1-2-3-4, targets 0 and 4. The agent starts beside target 0 (node 1) and walks away:
    # its map knows target 0 (seen at u = 0) and projects u + age; target 4 is unknown until seen.
    env = make({"neglect": 1.0}, [1], max_cycles=20, n_nodes=5, targets=(0, 4))
    _, rewards, *_ = env.step({"agent_0": 2})  # target 0 no longer observed: age 1 -> projection 1
    assert rewards["agent_0"] == pytest.approx(-1 / 100)
    _, rewards, *_ = env.step({"agent_0": 3})  # now 2, and target 4 is seen at u = 2
    assert rewards["agent_0"] == pytest.approx(-2 / 100)
    _, rewards, *_ = env.step({"agent_0": 4})  # on target 4 (u falls to 1): target 0's 3 is the worst
    assert rewards["agent_0"] == pytest.approx(-3 / 100)
    # A map that knows no target pays nothing.
    env = make({"neglect": 1.0}, [2], max_cycles=5, n_nodes=5, targets=(0,))
    _, rewards, *_ = env.step({"agent_0": 2})
    assert rewards["agent_0"] == 0.0


def test_crowding_counts_the_teammates_each_agent_observes() -> None:
    # Path 0-1-2-3-4-5-6 with radius-1 sensing. Agents at 0, 1 and 5: agents 0 and 1 see each other,
    # agent 2 sees nobody.
    env = make({"crowding": 0.5}, [0, 1, 5], max_cycles=10, n_nodes=7, targets=(6,))
    _, rewards, *_ = env.step({"agent_0": 0, "agent_1": 1, "agent_2": 5})
    assert [rewards[f"agent_{i}"] for i in range(3)] == [-0.5, -0.5, 0.0]
    _, rewards, *_ = env.step({"agent_0": 1, "agent_1": 2, "agent_2": 4})
    # agent_0 at 1 sees 2 (agent_1); agent_1 at 2 sees 1 (agent_0); agent_2 at 4 sees 3, 5: nobody.
    assert [rewards[f"agent_{i}"] for i in range(3)] == [-0.5, -0.5, 0.0]
    _, rewards, *_ = env.step({"agent_0": 2, "agent_1": 3, "agent_2": 4})
    # 2, 3, 4 in a row: the middle agent sees both others, each end agent sees one.
    assert [rewards[f"agent_{i}"] for i in range(3)] == [-0.5, -1.0, -0.5]
    _, rewards, *_ = env.step({"agent_0": 3, "agent_1": 3, "agent_2": 5})
    # Two agents on node 3 (a collision) count each other; agent_2 at 5 sees 4 and 6: nobody.
    assert [rewards[f"agent_{i}"] for i in range(3)] == [-0.5, -0.5, 0.0]


def test_crowding_ignores_a_failed_teammate() -> None:
    env = persistent_monitoring_v0.parallel_env(
        graph=path_graph(4, [3]),
        n_agents=2,
        initial_positions=[0, 1],
        reward={"crowding": 1.0},
        max_cycles=10,
        failures={"agent_1": 1},
    )
    env.reset(seed=0)
    _, rewards, *_ = env.step({"agent_0": 0, "agent_1": 1})  # agent_1 fails after this step
    assert rewards["agent_0"] == -1.0
    _, rewards, *_ = env.step({"agent_0": 0})
    assert rewards["agent_0"] == 0.0  # the failed agent is on no node


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
