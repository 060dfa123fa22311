"""A team acting through one pass for all its agents (the policies' own code mapped over their
stacked parameters) computes the logits of one pass per agent, bit for bit, and takes the same
actions on whole episodes, most likely and drawn ones."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest
import torch as th

from sb3_pm.agents.deployment.team_forward import TeamForward, team_problem
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import erdos_renyi

th.set_num_threads(1)
GRAPH = erdos_renyi(14, 0.3, n_targets=4, seed=3)
TINY = {"n_steps": 16, "batch_size": 16, "n_epochs": 1}


def make_team(n_agents: int = 3, seed: int = 0, **policy_kwargs: Any) -> IndependentPPO:
    """An untrained team: its learners are seeded apart, so every policy has its own weights (32
    units: 14 nodes x 32 fill whole blocks of the activations' vector loops)."""
    return IndependentPPO(
        GRAPH,
        n_agents=n_agents,
        seed=seed,
        env_kwargs={"max_cycles": 60},
        hyperparams={**TINY, "policy_kwargs": {"hidden_dim": 32, **policy_kwargs}},
    )


def serial_logits(policy: Any, obs: dict[str, np.ndarray]) -> tuple[th.Tensor, th.Tensor]:
    """What ``policy.predict(obs, deterministic=True, action_masks=...)`` computes before its argmax."""
    tensors, _ = policy.obs_to_tensor(obs)
    with th.no_grad():
        pre = policy._preprocess(tensors)
        u_hat = policy.uncertainty(pre)
        masks = policy._masks(pre, u_hat, np.asarray(obs["action_mask"], dtype=bool))
        return policy._logits(pre, u_hat, masks), masks


def walk(team: Any, n_agents: int, steps: int = 40, env_kwargs: dict[str, Any] | None = None):
    """Yield every step's observations of an episode driven by the team's serial actions."""
    env = persistent_monitoring_v0.parallel_env(
        graph=GRAPH, n_agents=n_agents, max_cycles=60, **(env_kwargs or {})
    )
    observations, _ = env.reset(seed=7)
    team.reset(env, seed=7)
    for _ in range(steps):
        if not observations:
            return
        yield observations
        team.stacked_inference = False
        actions = team.predict_dict(observations)
        team.stacked_inference = True
        observations, *_ = env.step(actions)


def check_equal(team: Any, observations: dict[str, Any], policies: list[Any], together: TeamForward) -> None:
    agents = list(observations)
    result = together.logits(policies, [observations[a] for a in agents])
    assert result is not None, together.refusal
    logits, masks = result
    for k, agent in enumerate(agents):
        expected_logits, expected_masks = serial_logits(policies[k], observations[agent])
        assert th.equal(masks[k], expected_masks[0])
        assert th.equal(logits[k], expected_logits[0]), (
            f"{agent}: {(logits[k] - expected_logits[0]).abs().max()}"
        )
    team.stacked_inference = False
    serial = team.predict_dict(observations)
    team.stacked_inference = True
    assert team.predict_dict(observations) == serial


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        {},
        {"laplacian": "none"},
        {"gat_heads": 4},
        {"use_estimator": False},
        {"hidden_dim": 64},
        {"net_arch": {"pi": [32, 32], "vf": [16, 16]}},
        {"gat_layers": 3, "gat_heads": 2},
        {"dcbf_barrier": True, "freeze_steps": 10},
        {"neglect_bound": 20},
    ],
    ids=[
        "small",
        "no-encoding",
        "4-heads",
        "no-estimator",
        "wide",
        "narrow-actor",
        "3-layers",
        "barrier",
        "bound",
    ],
)
def test_team_logits_and_actions_equal_one_pass_per_agent_bit_for_bit(policy_kwargs: dict[str, Any]) -> None:
    team = make_team(**policy_kwargs)
    team.learn(32)  # a few updates, so the learners' parameters differ by more than their seeds
    policies = [team.models[a].policy for a in team.agents]
    together = TeamForward()
    for observations in walk(team, 3):
        check_equal(team, observations, policies, together)


def play(team: Any, steps: int, seed: int, deterministic: bool = True) -> list[dict[str, int]]:
    """The team's actions over ``steps`` steps of a 3-agent episode."""
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=3, max_cycles=60)
    observations, _ = env.reset(seed=seed)
    team.reset(env, seed=seed)
    chosen = []
    for _ in range(steps):
        chosen.append(team.predict_dict(observations, deterministic=deterministic))
        observations, *_ = env.step(chosen[-1])
    return chosen


def watch_sampled_steps(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """A list that gets, for every sampling call of ``TeamForward.actions``, whether the team's
    pass served it (``False``: the step fell back to one pass per agent)."""
    served: list[bool] = []
    original = TeamForward.actions

    def spy(self: TeamForward, policies: Any, observations: Any, deterministic: bool) -> Any:
        result = original(self, policies, observations, deterministic)
        if not deterministic:
            served.append(result is not None)
        return result

    monkeypatch.setattr(TeamForward, "actions", spy)
    return served


def test_rule_8_is_counted_per_learner_as_in_the_serial_path() -> None:
    counts = []
    for stacked in (False, True):
        team = make_team(neglect_bound=12)
        team.stacked_inference = stacked
        play(team, 60, seed=7)
        counts.append(
            {a: {k: int(v) for k, v in team.models[a].policy.filter_counts.items()} for a in team.agents}
        )
    assert counts[0] == counts[1]
    assert sum(c["forced"] for c in counts[0].values()) > 0  # the bound did force moves


def test_learners_bounding_their_own_territories_stack_and_count_as_serially() -> None:
    """The default's deployment on paper-50: one neglect bound, each learner its own territory."""
    counts, chosen = [], []
    for stacked in (False, True):
        team = make_team()
        team.set_filter(neglect_bound=4, neglect_scope="territory")  # low enough to force moves here
        territories = {team.models[a].policy.dcbf_config.territory for a in team.agents}
        assert len(territories) == len(team.agents)  # the configs do differ
        team.stacked_inference = stacked
        chosen.append(play(team, 60, seed=7))
        counts.append(
            {a: {k: int(v) for k, v in team.models[a].policy.filter_counts.items()} for a in team.agents}
        )
        if stacked:
            policies = [team.models[a].policy for a in team.agents]
            assert TeamForward().problem(policies) is None
            for observations in walk(team, 3):
                check_equal(team, observations, policies, TeamForward())
    assert chosen[0] == chosen[1] and counts[0] == counts[1]
    assert sum(c["forced"] for c in counts[0].values()) > 0  # the bound did force moves


def test_more_agents_than_learners_and_failed_agents_stack_too() -> None:
    team = make_team(n_agents=2)
    together = TeamForward()
    # 5 agents on 2 learners (agent_i acts with learner i mod 2); agent_1 fails after step 10.
    for observations in walk(team, 5, env_kwargs={"failures": {"agent_1": 10}}):
        policies = [team.models[team.learner_for(a)].policy for a in observations]
        check_equal(team, observations, policies, together)


def test_a_transferred_team_stacks_on_its_new_graph() -> None:
    team = make_team(n_agents=2, laplacian="none").on_graph(erdos_renyi(20, 0.25, n_targets=5, seed=9))
    env = persistent_monitoring_v0.parallel_env(graph=team.graph, n_agents=2, max_cycles=30)
    observations, _ = env.reset(seed=1)
    team.reset(env, seed=1)
    together = TeamForward()
    for _ in range(30):
        policies = [team.policies[team.learner_for(a)] for a in observations]
        check_equal(team, observations, policies, together)  # the team's pass ran, and it is exact
        observations, *_ = env.step(team.predict_dict(observations))


def test_maps_for_the_sparse_kernel_run_one_pass_per_agent() -> None:
    team = make_team(gat_backend="sparse")
    policies = [team.models[a].policy for a in team.agents]
    observations = next(walk(team, 3))
    assert TeamForward().logits(policies, [observations[a] for a in team.agents]) is None
    serial = team.predict_dict(observations)
    assert team.predict_dict(observations) == serial


def test_activations_whose_last_elements_would_round_otherwise_run_one_pass_per_agent() -> None:
    """14 nodes x 8 units leave an ELU's last elements to its scalar loop, which rounds otherwise
    on the learners' tensors at once: that team acts one pass per agent, with the same actions."""
    team = make_team(hidden_dim=8)
    policies = [team.models[a].policy for a in team.agents]
    together = TeamForward()
    observations = next(walk(team, 3))
    assert together.logits(policies, [observations[a] for a in team.agents]) is None
    assert "vector loop" in str(together.refusal)
    team._team_forward = together
    team.stacked_inference = False
    serial = team.predict_dict(observations)
    team.stacked_inference = True
    assert team.predict_dict(observations) == serial


def test_observations_of_another_shape_are_left_to_the_serial_path() -> None:
    team = make_team()
    policies = [team.models[a].policy for a in team.agents]
    observations = next(walk(team, 3))
    flat = [
        {**observations[a], "nodes": np.asarray(observations[a]["nodes"]).reshape(-1)} for a in team.agents
    ]
    assert TeamForward().logits(policies, flat) is None


def test_parameters_changed_in_place_are_read_again() -> None:
    team = make_team()
    policies = [team.models[a].policy for a in team.agents]
    together = TeamForward()
    observations = next(walk(team, 3))
    check_equal(team, observations, policies, together)
    team.learn(32)  # optimizer steps change every parameter in place
    check_equal(team, observations, policies, together)
    with th.no_grad():
        policies[1].action_net.bias.add_(5.0)
    check_equal(team, observations, policies, together)
    policies[2].action_net.weight.data.mul_(3.0)  # a write torch's version counter does not see
    check_equal(team, observations, policies, together)


def test_the_policies_modules_hold_their_own_tensors_after_a_team_pass() -> None:
    team = make_team()
    before = {a: dict(team.models[a].policy.state_dict(keep_vars=True)) for a in team.agents}
    observations = next(walk(team, 3))
    team.predict_dict(observations)  # the team's pass
    for a in team.agents:
        after = team.models[a].policy.state_dict(keep_vars=True)
        assert all(after[k] is before[a][k] for k in after)  # no tensor swapped in and left behind
    team.stacked_inference = False
    team.predict_dict(observations)  # the serial path still runs on them


def test_what_cannot_act_together_says_why_and_runs_one_pass_per_agent() -> None:
    assert "sparse" in str(team_problem([make_team(gat_backend="sparse").models["agent_0"].policy]))
    no_hidden = make_team(net_arch={"pi": [], "vf": [32]}).models["agent_0"].policy
    assert "hidden layer" in str(team_problem([no_hidden]))
    mixed = [
        make_team(hidden_dim=32).models["agent_0"].policy,
        make_team(hidden_dim=64).models["agent_0"].policy,
    ]
    assert "differ" in str(team_problem(mixed))
    # A filter changed on one learner after the pass was set up: that step runs one pass per agent.
    team = make_team()
    together = TeamForward()
    policies = [team.models[a].policy for a in team.agents]
    observations = next(walk(team, 3))
    assert together.logits(policies, [observations[a] for a in team.agents]) is not None
    policies[1].dcbf_config = replace(policies[1].dcbf_config, neglect_bound=30.0)
    assert together.logits(policies, [observations[a] for a in team.agents]) is None
    assert "filter" in str(together.refusal)
    team._team_forward = together
    assert set(team.predict_dict(observations)) == set(team.agents)  # one pass per agent instead
    team.set_filter(neglect_bound=30.0)  # every learner alike again: one pass for the team
    assert together.logits(policies, [observations[a] for a in team.agents]) is not None


@pytest.mark.parametrize("temperature", [None, 0.25], ids=["T1", "T0.25"])
def test_sampled_actions_through_the_team_pass_are_one_pass_per_agents_draws(
    temperature: float | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Sampled actions take the team pass's logits and draw agent by agent, as one pass per agent
    does: the same actions on every step of an episode from the same seed, at T = 1 and at a
    deployment temperature, with every step of the team run served by the team's pass."""
    served = watch_sampled_steps(monkeypatch)

    def sharp_team() -> IndependentPPO:
        """Untrained logits differ by about 1e-5, so any row would draw alike; spread them apart
        (the same for both teams) so that a draw depends on its own row and on the temperature."""
        team = make_team(dcbf_barrier=False)  # without rules 2-4 an agent has a choice
        generator = th.Generator().manual_seed(5)
        with th.no_grad():
            for agent in team.agents:
                weight = team.models[agent].policy.action_net.weight
                weight.copy_(th.randn(weight.shape, generator=generator))
        team.deploy_temperature = temperature
        return team

    draws = []
    for stacked in (False, True):
        team = sharp_team()
        team.stacked_inference = stacked
        draws.append(play(team, 30, seed=2, deterministic=False))
    assert draws[0] == draws[1]
    assert len(served) == 30 and all(served)  # one pass per agent never asked; the team pass always
    # the draws are not all the most likely actions (so the test compares draws, not argmaxes)
    assert play(sharp_team(), 30, seed=2, deterministic=True) != draws[0]


def test_a_transferred_team_with_more_agents_and_the_rule_prior_samples_together_as_one_by_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The shipped transfer team's case: a known map, the rule's move as an input with its prior,
    moved to another graph with more agents than learners, sampling at T = 0.25 with a territory
    bound (rule 8), and one learner at another temperature (4): the same draws either way."""
    served = watch_sampled_steps(monkeypatch)
    known = {"max_cycles": 40, "graph_knowledge": "known", "target_knowledge": "known"}
    advice = {**known, "territory_input": True, "advice_input": True}
    other = erdos_renyi(20, 0.25, n_targets=6, seed=9)
    draws = []
    for stacked in (False, True):
        trained = IndependentPPO(
            GRAPH,
            n_agents=2,
            seed=0,
            env_kwargs=advice,
            hyperparams={
                **TINY,
                "policy_kwargs": {"hidden_dim": 32, "laplacian": "none", "advice_prior": 2.0},
            },
        )
        generator = th.Generator().manual_seed(5)
        with th.no_grad():
            for agent in trained.agents:  # spread the logits, as in the test above
                weight = trained.models[agent].policy.action_net.weight
                weight.copy_(th.randn(weight.shape, generator=generator))
        team = trained.on_graph(other)
        team.deploy_temperature = 0.25
        team.policies["agent_1"].sampling_temperature = 4.0
        team.set_filter(neglect_bound=30.0, neglect_scope="territory")
        team.stacked_inference = stacked
        env = persistent_monitoring_v0.parallel_env(graph=other, n_agents=3, **advice)
        observations, _ = env.reset(seed=4)
        team.reset(env, seed=4)
        chosen = []
        while env.agents:
            chosen.append(team.predict_dict(observations))
            observations, *_ = env.step(chosen[-1])
        draws.append(chosen)
    assert len(draws[0]) == 40 and draws[0] == draws[1]
    assert len(served) == 40 and all(served)  # every step of the team run was served by its pass


@pytest.mark.parametrize("deterministic", [True, False], ids=["most-likely", "sampled"])
def test_the_default_team_evaluates_to_the_same_episodes_either_way(
    deterministic: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The shipped configuration on the published 50-node graph (each learner bounding its own
    territory, as deployed): whole evaluated episodes, their traces and metrics, are the same with
    one pass for the team as with one pass per agent, every step served by the team's pass."""
    from sb3_pm.evaluation import evaluate
    from sb3_pm.zoo import load_config

    served: list[bool] = []
    original = TeamForward.actions

    def spy(self: TeamForward, policies: Any, observations: Any, deterministic: bool) -> Any:
        result = original(self, policies, observations, deterministic)
        served.append(result is not None)
        return result

    monkeypatch.setattr(TeamForward, "actions", spy)
    results = []
    for together in (False, True):
        team = IndependentPPO.from_config(load_config("ippo", "paper-50"), "paper-50", seed=0)
        team.stacked_inference = together
        run = evaluate(team, "paper-50", episodes=2, max_cycles=60, seed=3, deterministic=deterministic)
        results.append(run.episodes)
    assert len(served) == 2 * 60 and all(served)  # only the team run asks, and is served every step
    for serial, joint in zip(*results, strict=True):
        assert serial.metrics == joint.metrics
        assert np.array_equal(serial.trace, joint.trace)


def test_most_likely_actions_from_the_allowed_nodes_are_one_pass_per_agents() -> None:
    """On 100 nodes or more a most likely step is decided from the allowed nodes' logits where the
    best leads by more than the margin: the same actions as one pass per agent on every step of an
    episode; with the logits spread apart (as a trained team's are) nearly every step is decided
    so, and an untrained team's (all within about 1e-4) compute every logit."""
    graph = erdos_renyi(100, 0.06, n_targets=8, seed=2)
    for spread in (True, False):
        team = IndependentPPO(
            graph,
            n_agents=3,
            seed=0,
            env_kwargs={"max_cycles": 40},
            hyperparams={**TINY, "policy_kwargs": {"hidden_dim": 32, "dcbf_barrier": False}},
        )
        if spread:
            generator = th.Generator().manual_seed(5)
            with th.no_grad():
                for agent in team.agents:
                    weight = team.models[agent].policy.action_net.weight
                    weight.copy_(th.randn(weight.shape, generator=generator))
        env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=3, max_cycles=40)
        observations, _ = env.reset(seed=1)
        team.reset(env, seed=1)
        steps = 0
        while env.agents:
            team.stacked_inference = False
            serial = team.predict_dict(observations, deterministic=True)
            team.stacked_inference = True
            assert team.predict_dict(observations, deterministic=True) == serial
            observations, *_ = env.step(serial)
            steps += 1
        counts = team._team_forward.counts
        assert steps == 40 and sum(counts.values()) == steps  # every step took the team's pass
        if spread:
            assert counts["allowed"] >= 0.9 * steps
        else:
            assert counts["all"] == steps
