"""``territory_input``: each agent's map carries its own territory as a sixth node feature.

The column must be the split of :mod:`sb3_pm.graphs.territories` for the env's own graph and team
size, on every step, so that a team moved to another graph or team size sees that problem's split.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from pettingzoo.test import parallel_api_test

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.mental_map import FEATURES
from sb3_pm.errors import InputError
from sb3_pm.graphs import erdos_renyi, resolve_graph
from sb3_pm.graphs.territories import territory_nodes

th.set_num_threads(1)
KNOWN = {"graph_knowledge": "known", "target_knowledge": "known"}


def make_env(graph="paper-50", n_agents: int = 4, **kwargs):
    return persistent_monitoring_v0.parallel_env(
        graph=graph, n_agents=n_agents, max_cycles=30, territory_input=True, **{**KNOWN, **kwargs}
    )


@pytest.mark.parametrize(("graph", "n_agents"), [("paper-50", 4), ("paper-50", 3), ("rooms-4", 6)])
def test_the_column_is_each_agents_own_territory_on_every_step(graph: str, n_agents: int) -> None:
    env = make_env(graph, n_agents)
    spec = resolve_graph(graph)
    owns = territory_nodes(spec.hop_distances, spec.target_indices, n_agents, spec.n_nodes)
    assert env.observation_space("agent_0")["nodes"].shape == (spec.n_nodes, len(FEATURES) + 1)
    observations, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(10):
        for i, agent in enumerate(env.possible_agents):
            column = observations[agent]["nodes"][:, -1]
            np.testing.assert_array_equal(column, owns[i].astype(np.float32))
            assert env.observation_space(agent)["nodes"].contains(observations[agent]["nodes"])
        # every target in one territory, nothing else in any
        assert (owns.sum(axis=0) == spec.targets.astype(int)).all()
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, *_ = env.step(actions)


def test_the_other_columns_are_the_maps_unchanged() -> None:
    plain = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4, max_cycles=30, **KNOWN)
    with_input = make_env()
    first, _ = plain.reset(seed=1)
    second, _ = with_input.reset(seed=1)
    for _ in range(5):
        for agent in plain.possible_agents:
            np.testing.assert_array_equal(first[agent]["nodes"], second[agent]["nodes"][:, : len(FEATURES)])
        actions = {a: int(np.flatnonzero(o["action_mask"])[-1]) for a, o in first.items()}
        first, *_ = plain.step(actions)
        second, *_ = with_input.step(actions)


def test_the_pettingzoo_api_holds_with_it_and_with_failures() -> None:
    parallel_api_test(make_env(), num_cycles=40)
    parallel_api_test(make_env(failures={"agent_1": 10}), num_cycles=40)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"graph_knowledge": "discovered"}, "needs graph_knowledge and target_knowledge 'known'"),
        ({"target_knowledge": "discovered"}, "computes its territory from the site plan"),
        ({"observation": "local"}, "needs observation='map'"),
        ({"territory_input": "yes"}, "territory_input must be true or false, got 'yes'"),
    ],
)
def test_what_it_cannot_be_computed_for_is_refused_by_name(kwargs: dict, message: str) -> None:
    options = {"graph": "paper-50", "n_agents": 4, "territory_input": True, **KNOWN, **kwargs}
    with pytest.raises(InputError, match=message):
        persistent_monitoring_v0.parallel_env(**options)


def test_a_transferable_team_sees_each_graphs_own_split() -> None:
    team = IndependentPPO(
        erdos_renyi(16, 0.3, n_targets=5, seed=2),
        n_agents=3,
        n_envs=1,
        seed=0,
        env_kwargs={"max_cycles": 20, "territory_input": True, **KNOWN},
        hyperparams={
            "n_steps": 16,
            "batch_size": 16,
            "n_epochs": 1,
            "policy_kwargs": {"laplacian": "none", "hidden_dim": 8},
        },
    )
    team.learn(16)
    for graph in ("paper-50", erdos_renyi(25, 0.2, n_targets=7, seed=5)):
        moved = team.on_graph(graph)
        env = persistent_monitoring_v0.parallel_env(
            graph=graph, n_agents=3, max_cycles=20, territory_input=True, **KNOWN
        )
        spec = env.graph
        owns = territory_nodes(spec.hop_distances, spec.target_indices, 3, spec.n_nodes)
        observations, _ = env.reset(seed=0)
        moved.reset(env, seed=0)
        for _ in range(5):
            for i, agent in enumerate(env.possible_agents):
                np.testing.assert_array_equal(observations[agent]["nodes"][:, -1], owns[i])
            actions = moved.predict_dict(observations)
            for agent, action in actions.items():
                assert observations[agent]["action_mask"][action] == 1  # legal on the new graph
            observations, *_ = env.step(actions)
    team.close()


def test_on_a_graph_family_each_episode_gives_its_own_split() -> None:
    env = make_env("family:er", reward={"clearing": 0.04, "territory": 0.04})
    for seed in (0, 1, 2):
        observations, _ = env.reset(seed=seed)
        spec = env.graph  # this episode's draw
        owns = territory_nodes(spec.hop_distances, spec.target_indices, 4, spec.n_nodes)
        for i, agent in enumerate(env.possible_agents):
            column = observations[agent]["nodes"][:, -1]
            assert column.shape == (env.space_nodes,)  # padded to the family's largest graph
            np.testing.assert_array_equal(column[: spec.n_nodes], owns[i])
            assert not column[spec.n_nodes :].any()
        _, rewards, *_ = env.step(
            {a: int(np.flatnonzero(o["action_mask"])[0]) for a, o in observations.items()}
        )
        assert set(rewards) == set(env.possible_agents)


def test_on_a_graph_family_the_territory_reward_pays_each_episodes_own_split() -> None:
    """A family episode rewards exactly as an env on that one drawn graph does, step by step."""
    reward = {"clearing": 0.04, "territory": 0.5}
    family = make_env("family:er", reward=reward)
    rng = np.random.default_rng(0)
    for seed in (0, 1):
        observations, _ = family.reset(seed=seed)
        one = make_env(family.graph, reward=reward)
        plain = make_env(family.graph, reward={"clearing": 0.04})  # the same without the term
        start = {"initial_positions": family.core.positions.tolist()}
        alone, _ = one.reset(seed=seed, options=start)
        plain.reset(seed=seed, options=start)
        paid = False
        for _ in range(29):  # max_cycles 30
            actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in alone.items()}
            observations, rewards, *_ = family.step(actions)
            alone, expected, *_ = one.step(actions)
            _, without, *_ = plain.step(actions)
            assert rewards == pytest.approx(expected)
            paid = paid or rewards != pytest.approx(without)
        assert paid  # the territory term did pay in these steps, so the comparison says something
