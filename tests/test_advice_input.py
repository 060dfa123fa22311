"""``advice_input``: each agent's map carries the territory rule's next move as a node feature.

The column must be exactly the move the ``territory_patrol`` baseline makes from the same
observation, on every step, whatever the agent actually does, and on whatever graph and team size
the env has.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch as th
from pettingzoo.test import parallel_api_test

from sb3_pm.agents.team import IndependentPPO
from sb3_pm.baselines.territory_patrol import TerritoryPatrolTeam
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.mental_map import FEATURES
from sb3_pm.envs.territory_rule import TerritoryAdvice
from sb3_pm.errors import InputError
from sb3_pm.graphs import erdos_renyi

th.set_num_threads(1)
KNOWN = {"graph_knowledge": "known", "target_knowledge": "known"}


def make_env(graph="paper-50", n_agents: int = 4, **kwargs):
    options = {"max_cycles": 60, "advice_input": True, **KNOWN, **kwargs}
    return persistent_monitoring_v0.parallel_env(graph=graph, n_agents=n_agents, **options)


def advised(observation) -> int:
    """The one node the advice column flags (the test fails if it flags another number)."""
    flagged = np.flatnonzero(observation["nodes"][:, -1])
    assert flagged.size == 1, flagged
    return int(flagged[0])


@pytest.mark.parametrize(("graph", "n_agents"), [("paper-50", 4), ("rooms-4", 6), ("karate", 3)])
def test_following_the_advice_is_the_territory_patrol_baseline_step_for_step(
    graph: str, n_agents: int
) -> None:
    env = make_env(graph, n_agents)
    rule = TerritoryPatrolTeam()
    observations, _ = env.reset(seed=4)
    rule.reset(env, seed=4)
    for _ in range(59):
        moves = rule.predict(observations)
        for agent, observation in observations.items():
            assert advised(observation) == moves[agent]
            assert env.observation_space(agent)["nodes"].contains(observation["nodes"])
        observations, *_ = env.step({agent: advised(o) for agent, o in observations.items()})
    baseline = make_env(graph, n_agents)
    observations, _ = baseline.reset(seed=4)
    rule.reset(baseline, seed=4)
    for _ in range(59):
        observations, *_ = baseline.step(rule.predict(observations))
    assert env.episode_metrics() == baseline.episode_metrics()


def test_the_rule_keeps_its_goal_when_the_agent_goes_elsewhere() -> None:
    """Agents that move at random: the column is still the rule's move from where they stand,
    with the goal the rule itself chose earlier (as the baseline keeps it)."""
    env = make_env("paper-50", 4)
    rng = np.random.default_rng(0)
    observations, _ = env.reset(seed=2)
    rule = TerritoryPatrolTeam()
    rule.reset(env, seed=2)
    changed_goal = False
    for _ in range(59):
        goals_before = dict(rule._goals)
        moves = rule.predict(observations)
        changed_goal = changed_goal or goals_before != rule._goals
        for agent, observation in observations.items():
            assert advised(observation) == moves[agent]
        actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
        observations, *_ = env.step(actions)
    assert changed_goal  # goals were chosen and dropped during the run, so the check meant something


def test_the_other_columns_are_the_maps_and_the_territory_unchanged() -> None:
    plain = persistent_monitoring_v0.parallel_env(
        graph="paper-50", n_agents=4, max_cycles=30, territory_input=True, **KNOWN
    )
    both = make_env(territory_input=True, max_cycles=30)
    assert both.observation_space("agent_0")["nodes"].shape == (50, len(FEATURES) + 2)
    first, _ = plain.reset(seed=1)
    second, _ = both.reset(seed=1)
    for _ in range(5):
        for agent in plain.possible_agents:
            np.testing.assert_array_equal(first[agent]["nodes"], second[agent]["nodes"][:, :-1])
        actions = {a: int(np.flatnonzero(o["action_mask"])[-1]) for a, o in first.items()}
        first, *_ = plain.step(actions)
        second, *_ = both.step(actions)


def test_an_agent_without_territory_or_failed_gets_no_advice() -> None:
    env = make_env("paper-50", 10, failures={"agent_0": 3})  # 8 targets: agents 8 and 9 own none
    observations, _ = env.reset(seed=0)
    for agent in ("agent_8", "agent_9"):
        assert not observations[agent]["nodes"][:, -1].any()
    for _ in range(3):
        observations, *_ = env.step(
            {a: int(np.flatnonzero(o["action_mask"])[0]) for a, o in observations.items()}
        )
    assert "agent_0" not in env.agents
    assert not env._advice_column(env.core.positions)[0].any()


def test_the_pettingzoo_api_holds_with_it_and_with_failures() -> None:
    parallel_api_test(make_env(), num_cycles=40)
    parallel_api_test(make_env(failures={"agent_1": 10}), num_cycles=40)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"graph_knowledge": "discovered"},
            "advice_input needs graph_knowledge and target_knowledge 'known'",
        ),
        ({"observation": "local"}, "advice_input is a node feature of map observations"),
        ({"advice_input": 1}, "advice_input must be true or false, got 1"),
    ],
)
def test_what_it_cannot_be_computed_for_is_refused_by_name(kwargs: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        make_env(**kwargs)


def test_a_pickled_env_resumes_with_the_rules_goals() -> None:
    env = make_env()
    observations, _ = env.reset(seed=3)
    for _ in range(7):
        observations, *_ = env.step({a: advised(o) for a, o in observations.items()})
    copy = pickle.loads(pickle.dumps(env))
    for _ in range(20):
        actions = {a: advised(o) for a, o in observations.items()}
        observations, *_ = env.step(actions)
        again, *_ = copy.step(actions)
        for agent in observations:
            np.testing.assert_array_equal(observations[agent]["nodes"], again[agent]["nodes"])


def test_the_advice_object_alone_matches_the_rule_on_random_maps() -> None:
    """TerritoryAdvice on hand-made maps: dwelling on an own target with u > 0, else a step
    toward the most stale own target by ``u + age``."""
    spec = erdos_renyi(20, 0.3, n_targets=4, seed=1)
    territory = np.zeros((1, 20), dtype=bool)
    territory[0, spec.target_indices] = True
    advice = TerritoryAdvice(territory, spec.hop_distances, spec.next_hop, u_max=100)
    u, age = np.zeros((1, 20), np.float32), np.zeros((1, 20), np.float32)
    here = int(spec.target_indices[0])
    u[0, here] = 3
    assert advice.moves(np.array([here]), u, age, np.array([True]))[0] == here  # dwell
    u[0, here] = 0
    stale = int(spec.target_indices[2])
    age[0, stale] = 50
    move = advice.moves(np.array([here]), u, age, np.array([True]))[0]
    assert spec.hop_distances[move, stale] == spec.hop_distances[here, stale] - 1
    assert advice.goals[0] == stale


def test_a_team_trained_with_it_acts_legally_on_other_graphs() -> None:
    team = IndependentPPO(
        erdos_renyi(16, 0.3, n_targets=5, seed=2),
        n_agents=3,
        n_envs=1,
        seed=0,
        env_kwargs={"max_cycles": 20, "advice_input": True, "territory_input": True, **KNOWN},
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
        env = make_env(graph, 3, max_cycles=20, territory_input=True)
        observations, _ = env.reset(seed=0)
        moved.reset(env, seed=0)
        for _ in range(5):
            actions = moved.predict(observations)
            for agent, action in actions.items():
                assert observations[agent]["action_mask"][action] == 1
            observations, *_ = env.step(actions)
    team.close()
