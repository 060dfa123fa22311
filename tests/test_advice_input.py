"""``advice_input``: each agent's map carries the territory rule's next move as a node feature.

The column must be exactly the move the ``territory_patrol`` baseline makes from the same
observation, on every step, whatever the agent actually does, and on whatever graph and team size
the env has.
"""

from __future__ import annotations

import hashlib
import json
import pickle

import numpy as np
import pytest
import torch as th
from pettingzoo.test import parallel_api_test

from sb3_pm.agents.deployment.team_forward import TeamForward, team_problem
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.baselines.territory_patrol import TerritoryPatrolTeam
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.envs.mental_map import FEATURES
from sb3_pm.envs.territory_rule import TerritoryAdvice
from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import evaluate
from sb3_pm.evaluation.teams import load_trained_team
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
def test_the_advice_is_the_territory_patrol_move_on_every_step_of_several_episodes(
    graph: str, n_agents: int
) -> None:
    """Agents acting at random, over three episodes of one env: the column is the rule's move
    from where each agent stands, with the goal the rule itself kept (the baseline, run beside
    it on the same observations, keeps its goals the same way and drops them at each reset)."""
    env = make_env(graph, n_agents)
    rule = TerritoryPatrolTeam()
    rng = np.random.default_rng(0)
    kept_goals = 0
    for episode in range(3):
        observations, _ = env.reset(seed=episode)
        rule.reset(env, seed=episode)
        while env.agents:
            moves = rule.predict_dict(observations)
            kept_goals += sum(goal is not None for goal in rule.rule.goals)
            for agent, observation in observations.items():
                assert advised(observation) == moves[agent]
                assert env.observation_space(agent)["nodes"].contains(observation["nodes"])
            actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
            observations, *_ = env.step(actions)
    assert kept_goals > 0  # the rule did keep goals, so the comparison covered them


def test_agents_that_follow_the_advice_play_the_territory_patrol_episode() -> None:
    env, baseline = make_env("rooms-4", 4), make_env("rooms-4", 4)
    rule = TerritoryPatrolTeam()
    observations, _ = env.reset(seed=4)
    while env.agents:
        observations, *_ = env.step({agent: advised(o) for agent, o in observations.items()})
    observations, _ = baseline.reset(seed=4)
    rule.reset(baseline, seed=4)
    while baseline.agents:
        observations, *_ = baseline.step(rule.predict_dict(observations))
    assert env.episode_metrics() == baseline.episode_metrics()


def test_the_rule_itself_is_the_territory_patrol_of_before_it_moved() -> None:
    """The baseline's actions, hashed over 3 episodes of 3 settings (discovered maps, known maps
    with 6 agents, 8 agents for 6 targets with a failure). The digest was computed with the
    baseline's code from before the rule moved to ``sb3_pm.envs.territory_rule``: the move kept
    its decisions bit for bit, and any change to the rule shows here."""
    digest = hashlib.sha256()
    cases = [("paper-50", 4, {}), ("rooms-4", 6, KNOWN), ("karate", 8, {"failures": {"agent_2": 40}})]
    for graph, n_agents, kwargs in cases:
        env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=n_agents, max_cycles=120, **kwargs)
        team = TerritoryPatrolTeam()
        for episode in range(3):
            observations, _ = env.reset(seed=episode)
            team.reset(env, seed=episode)
            while env.agents:
                actions = team.predict_dict(observations)
                digest.update(np.array([actions[a] for a in sorted(actions)], dtype=np.int64).tobytes())
                observations, *_ = env.step(actions)
    assert digest.hexdigest() == "5f2df4c59d2ca7358b87dc78af74fa31f7fbea07fd4bd79a6b7ca7c80c22e42c"


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
    assert observations["agent_0"]["nodes"][:, -1].sum() == 1
    for _ in range(3):
        observations, _, terminations, *_ = env.step(
            {a: int(np.flatnonzero(o["action_mask"])[0]) for a, o in observations.items()}
        )
    assert terminations["agent_0"] and "agent_0" not in env.agents
    assert not observations["agent_0"]["nodes"][:, -1].any()  # its last observation: no advice
    assert observations["agent_1"]["nodes"][:, -1].sum() == 1


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


def _plain_copy(env):
    """A copy through the env's plain state, as a checkpoint keeps it."""
    from sb3_pm.plain_state import decode, encode

    arrays: dict = {}
    tree = json.loads(json.dumps(encode(env.state_dict(), arrays)))
    copy = make_env()
    copy.load_state_dict(decode(tree, arrays))
    return copy


@pytest.mark.parametrize(
    "copied", [lambda env: pickle.loads(pickle.dumps(env)), _plain_copy], ids=["pickle", "state"]
)
def test_a_copied_env_resumes_with_the_rules_goals(copied) -> None:
    """Random moves, so the kept goals matter: a copy made mid-episode (a pickle, or the plain state
    a checkpoint keeps) goes on advising what the baseline (which kept its goals) moves."""
    env = make_env()
    rule = TerritoryPatrolTeam()
    rng = np.random.default_rng(1)
    observations, _ = env.reset(seed=3)
    rule.reset(env, seed=3)

    def random_moves(observations):
        return {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}

    for _ in range(15):
        rule.predict_dict(observations)
        observations, *_ = env.step(random_moves(observations))
    copy = copied(env)
    for _ in range(40):
        moves = rule.predict_dict(observations)
        assert {a: advised(o) for a, o in observations.items()} == moves
        observations, *_ = copy.step(random_moves(observations))


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


def small_team(env_kwargs: dict, graph="paper-50", n_agents: int = 2, **policy_kwargs) -> IndependentPPO:
    """A tiny team with a known map and no Laplacian rows (so it can move to other graphs)."""
    return IndependentPPO(
        graph,
        n_agents=n_agents,
        n_envs=1,
        seed=0,
        env_kwargs={"max_cycles": 20, **KNOWN, **env_kwargs},
        hyperparams={
            "n_steps": 16,
            "batch_size": 16,
            "n_epochs": 1,
            "policy_kwargs": {"laplacian": "none", "hidden_dim": 8, **policy_kwargs},
        },
    )


def test_a_saved_team_keeps_the_option_and_acts_legally_on_other_graphs(tmp_path) -> None:
    """A team trained with the column, saved and loaded, is evaluated on other graphs in envs
    that carry it (its saved env settings), and acts legally there."""
    team = small_team(
        {"advice_input": True, "territory_input": True}, erdos_renyi(16, 0.3, n_targets=5, seed=2), 3
    )
    team.learn(16)
    team.save(tmp_path / "team")
    team.close()
    for graph in ("karate", erdos_renyi(25, 0.2, n_targets=7, seed=5)):
        loaded = load_trained_team(tmp_path / "team", graph)
        kwargs = loaded.env_settings()
        assert kwargs["advice_input"] is True
        result = evaluate(loaded, graph, n_agents=3, episodes=1, seed=0)  # the team's own settings
        assert result.config["env_kwargs"]["advice_input"] is True
        env = make_env(graph, 3, max_cycles=20, territory_input=True)
        observations, _ = env.reset(seed=0)
        loaded.reset(env, seed=0)
        for _ in range(5):
            actions = loaded.predict_dict(observations)
            for agent, action in actions.items():
                assert observations[agent]["action_mask"][action] == 1
            observations, *_ = env.step(actions)


def test_the_advice_prior_adds_its_weight_to_the_advised_nodes_logit_only() -> None:
    """The same parameters with and without the prior: the logits differ by ``b`` on the node the
    column flags and by nothing elsewhere, in acting and in training's ``evaluate_actions``."""
    with_prior = small_team({"advice_input": True}, advice_prior=2.5)
    without = small_team({"advice_input": True})
    policy, plain = with_prior.models["agent_0"].policy, without.models["agent_0"].policy
    plain.load_state_dict(policy.state_dict())
    env = make_env(max_cycles=20, n_agents=2)
    observations, _ = env.reset(seed=0)
    for _ in range(5):
        obs, _ = policy.obs_to_tensor(observations["agent_0"])
        pre = policy._preprocess(obs)
        u_hat = policy.uncertainty(pre)
        masks = policy._masks(pre, u_hat, None)
        difference = policy._logits(pre, u_hat, masks) - plain._logits(pre, u_hat, masks)
        expected = 2.5 * th.as_tensor(observations["agent_0"]["nodes"][:, -1])
        th.testing.assert_close(difference[0], expected, rtol=0, atol=1e-6)
        heads, _ = policy._heads(pre, u_hat, masks)
        th.testing.assert_close(heads, policy._logits(pre, u_hat, masks), rtol=0, atol=0)
        observations, *_ = env.step({a: advised(o) for a, o in observations.items()})
    with_prior.close()
    without.close()


def test_a_team_with_the_prior_acts_together_as_it_acts_one_policy_at_a_time_and_saves_it(tmp_path) -> None:
    """The team's pass adds the prior with each policy's own code: the same logits as one pass
    per policy, bit for bit, on every step of an episode."""
    # 32 units: 50 nodes x 8 would leave activation elements outside the vector loop (refused)
    team = small_team({"advice_input": True}, advice_prior=2.0, hidden_dim=32)
    team.learn(16)
    policies = [team.models[a].policy for a in team.agents]
    assert team_problem(policies) is None
    stacked = TeamForward()
    env = make_env(max_cycles=30, n_agents=2)
    observations, _ = env.reset(seed=3)
    compared = 0
    while env.agents:
        ordered = [observations[a] for a in team.agents]
        result = stacked.logits(policies, ordered)
        assert result is not None, stacked.refusal
        logits, masks = result
        for k, (policy, observation) in enumerate(zip(policies, ordered)):
            obs, _ = policy.obs_to_tensor(observation)
            pre = policy._preprocess(obs)
            u_hat = policy.uncertainty(pre)
            serial_masks = policy._masks(pre, u_hat, None)
            assert th.equal(logits[k], policy._logits(pre, u_hat, serial_masks)[0])
            assert th.equal(masks[k], serial_masks[0])
            compared += 1
        observations, *_ = env.step({a: advised(o) for a, o in observations.items()})
    assert compared == 60
    team.save(tmp_path / "team")
    team.close()
    loaded = load_trained_team(tmp_path / "team", "karate")
    assert all(policy.advice_prior == 2.0 for policy in loaded.policies.values())


@pytest.mark.parametrize(
    ("env_kwargs", "prior", "message"),
    [
        ({}, 2.0, "advice_prior adds to the node the env's advice_input flags"),
        (
            {"territory_input": True},
            2.0,
            r"advice_prior \(set for \['agent_0', 'agent_1'\]\) needs env_kwargs advice_input",
        ),
        ({"advice_input": True}, -1.0, "advice_prior must be a finite number >= 0, got -1.0"),
        ({"advice_input": True}, float("inf"), "advice_prior must be a finite number >= 0"),
        ({"advice_input": True}, True, "advice_prior must be a finite number >= 0, got True"),
    ],
)
def test_a_prior_it_cannot_apply_is_refused_by_name(env_kwargs: dict, prior, message: str) -> None:
    with pytest.raises(InputError, match=message):
        small_team(env_kwargs, advice_prior=prior)


def test_a_centralized_team_refuses_a_prior_without_its_column_too() -> None:
    """Without advice_input the map's last column is the territory's: the prior would land there."""
    from sb3_pm.sharing.centralized import CentralizedPPO

    env_kwargs = {"max_cycles": 20, "territory_input": True, **KNOWN}
    hyperparams = {"n_steps": 8, "batch_size": 8, "policy_kwargs": {"advice_prior": 2.0, "laplacian": "none"}}
    with pytest.raises(
        InputError, match=r"advice_prior \(set for \['shared policy'\]\) needs env_kwargs advice_input"
    ):
        CentralizedPPO("paper-50", n_agents=2, env_kwargs=env_kwargs, hyperparams=hyperparams)
