"""Agent failures (the env's ``failures`` / ``failure_rate``) and deploying a team with another size."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.evaluation import evaluate, resolve_team
from tests.conftest import path_graph


def stay_actions(env: object, observations: dict) -> dict[str, int]:
    return {agent: int(obs["position"]) for agent, obs in observations.items()}


class TestEnvironment:
    @pytest.mark.parametrize(
        "kwargs", [{"failures": {"agent_1": 7, "agent_3": 2}}, {"failure_rate": 0.05}], ids=["steps", "rate"]
    )
    def test_parallel_api_test_passes_with_failures(self, kwargs: dict) -> None:
        env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4, max_cycles=40, **kwargs)
        parallel_api_test(env, num_cycles=100)

    def test_a_failed_agent_leaves_the_pettingzoo_way_and_stops_clearing(self) -> None:
        # Path 0-1-2-3-4, targets 0 and 4; agent_0 sits on 0, agent_1 on 4; agent_1 fails after step 3.
        env = persistent_monitoring_v0.parallel_env(
            graph=path_graph(5, [0, 4]),
            n_agents=2,
            max_cycles=10,
            initial_positions=[0, 4],
            failures={"agent_1": 3},
        )
        observations, _ = env.reset(seed=0)
        for step in range(1, 4):
            observations, rewards, terminations, _, infos = env.step(stay_actions(env, observations))
            assert set(observations) == set(rewards) == {"agent_0", "agent_1"}
            assert terminations["agent_1"] is (step == 3)
        assert infos["agent_1"]["failed"] == 3 and "agent_1" in observations  # final observation
        assert env.agents == ["agent_0"]
        assert env.unwrapped.active.tolist() == [True, False]
        u_before = env.unwrapped.uncertainty[4]
        observations, rewards, terminations, truncations, infos = env.step(stay_actions(env, observations))
        assert set(observations) == set(rewards) == set(terminations) == set(infos) == {"agent_0"}
        # The failed agent still "stands" on node 4 in the core but is on no node: target 4 grows.
        assert env.unwrapped.uncertainty[4] == u_before + 1
        # Its map no longer shows it to anybody; acting for it is not required (nor counted).
        while env.agents:
            observations, *_, infos = env.step(stay_actions(env, observations))
        metrics = infos["agent_0"]["metrics"]
        trace = env.unwrapped.uncertainty_trace()
        assert metrics["failed_agents"] == 1 and metrics["first_failure_step"] == 3
        assert metrics["avg_uncertainty_before_failure"] == pytest.approx(trace[:3].mean())
        assert metrics["avg_uncertainty_after_failure"] == pytest.approx(trace[3:].mean())

    def test_random_failures_follow_the_seed_and_spare_the_last_agent(self) -> None:
        def failure_log(seed: int) -> list[tuple[int, str]]:
            env = persistent_monitoring_v0.parallel_env(
                graph="paper-50", n_agents=4, max_cycles=200, failure_rate=0.05
            )
            observations, _ = env.reset(seed=seed)
            log, step = [], 0
            while env.agents:
                observations, _, _, _, infos = env.step(stay_actions(env, observations))
                step += 1
                log += [(step, agent) for agent, info in infos.items() if "failed" in info]
            assert step == 200  # the last live agent never fails, so the episode runs to the end
            return log

        first = failure_log(3)
        assert first == failure_log(3) and len(first) == 3  # at rate 0.05 over 200 steps, all but one
        assert first != failure_log(4)

    def test_no_failure_keeps_the_metrics_honest(self) -> None:
        env = persistent_monitoring_v0.parallel_env(
            graph="paper-50", n_agents=4, max_cycles=20, failure_rate=1e-9
        )
        observations, _ = env.reset(seed=0)
        while env.agents:
            observations, *_, infos = env.step(stay_actions(env, observations))
        metrics = infos["agent_0"]["metrics"]
        assert metrics["failed_agents"] == 0 and metrics["first_failure_step"] == 20
        assert math.isnan(metrics["avg_uncertainty_after_failure"])
        assert metrics["avg_uncertainty_before_failure"] == pytest.approx(metrics["avg_uncertainty"])

    @pytest.mark.parametrize(
        "kwargs, message",
        [
            ({"failures": {"agent_7": 3}}, "not an agent"),
            ({"failures": {"agent_1": 0}}, "outside 1..9"),
            ({"failures": {"agent_1": 10}}, "outside 1..9"),
            ({"failures": {"agent_1": 2.5}}, "integer step"),
            ({"failures": {"agent_0": 2, "agent_1": 3}}, "every agent"),
            ({"failure_rate": 1.0}, r"failure_rate must be in \[0, 1\)"),
        ],
    )
    def test_bad_failure_options_are_refused(self, kwargs: dict, message: str) -> None:
        with pytest.raises(InputError, match=message):
            persistent_monitoring_v0.parallel_env(
                graph=path_graph(5, [0]), n_agents=2, max_cycles=10, **kwargs
            )

    @pytest.mark.parametrize(
        "baseline", ["grazing", "local_greedy", "random", "sit_on_nodes", "tour_patrol", "territory_patrol"]
    )
    def test_baselines_run_under_failures(self, baseline: str) -> None:
        result = evaluate(
            resolve_team(baseline),
            "paper-50",
            episodes=1,
            max_cycles=60,
            env_kwargs={"failures": {"agent_2": 30}},
        )
        assert result.mean["failed_agents"] == 1 and result.mean["first_failure_step"] == 30

    def test_grazing_no_longer_counts_a_failed_agent(self) -> None:
        # Path 0..6, targets 0 and 6. agent_1 sits on target 6 and fails; grazing's agent_0 must then
        # go to 6 (before, "another agent occupies it" kept it away).
        env_kwargs = {"initial_positions": [0, 6], "failures": {"agent_1": 1}}
        result = evaluate(
            resolve_team("grazing"),
            path_graph(7, [0, 6]),
            n_agents=2,
            episodes=1,
            max_cycles=80,
            env_kwargs=env_kwargs,
        )
        assert result.mean["max_neglect"] < 79


class TestOtherTeamSizes:
    @pytest.fixture(scope="class")
    @classmethod
    def team(cls):  # a 2-agent team; its parameters do not matter for the deployment rule
        from sb3_pm.agents.training.team import IndependentPPO

        return IndependentPPO(
            path_graph(6, [0, 5], name="line6"),
            n_agents=2,
            seed=0,
            env_kwargs={"max_cycles": 20},
            hyperparams={"n_steps": 16, "batch_size": 16},
        )

    def test_the_rule(self, team) -> None:
        assert [team.learner_for(f"agent_{i}") for i in range(5)] == [
            "agent_0",
            "agent_1",
            "agent_0",
            "agent_1",
            "agent_0",
        ]
        with pytest.raises(InputError, match="no learner for 'robot'"):
            team.learner_for("robot")

    @pytest.mark.parametrize("n_agents", [1, 3, 5])
    def test_deploys_with_fewer_or_more_agents(self, team, n_agents: int) -> None:
        env = persistent_monitoring_v0.parallel_env(graph=team.graph, n_agents=n_agents, max_cycles=20)
        observations, _ = env.reset(seed=1)
        team.reset(env, seed=1)
        while env.agents:  # the env raises on any illegal move
            actions = team.predict_dict(observations)
            assert set(actions) == set(observations)
            observations, *_ = env.step(actions)

    def test_under_failures(self, team) -> None:
        result = evaluate(
            team, team.graph, n_agents=3, episodes=1, max_cycles=20, env_kwargs={"failures": {"agent_1": 5}}
        )
        assert result.mean["failed_agents"] == 1


class TestCommandLine:
    def test_fail_flag_parsing(self) -> None:
        import argparse

        from sb3_pm.commands.evaluate import env_overrides
        from sb3_pm.errors import UsageError

        ok = argparse.Namespace(fail=["agent_1:250", "agent_2:10"], failure_rate=0.0)
        assert env_overrides(ok) == {"failures": {"agent_1": 250, "agent_2": 10}}
        for bad in (["agent_1"], ["agent_1:x"], ["agent_1:3", "agent_1:4"]):
            with pytest.raises(UsageError):
                env_overrides(argparse.Namespace(fail=bad, failure_rate=0.0))
        assert env_overrides(argparse.Namespace(fail=[], failure_rate=0.01)) == {"failure_rate": 0.01}


def test_failures_do_not_change_an_episode_without_them() -> None:
    # Same seed, same actions: the trace with an empty schedule equals the plain env's.
    traces = []
    for kwargs in ({}, {"failures": {}}):
        env = persistent_monitoring_v0.parallel_env(graph="paper-50", n_agents=4, max_cycles=50, **kwargs)
        observations, _ = env.reset(seed=5)
        rng = np.random.default_rng(0)
        while env.agents:
            actions = {a: int(rng.choice(np.flatnonzero(o["action_mask"]))) for a, o in observations.items()}
            observations, *_ = env.step(actions)
        traces.append(env.unwrapped.uncertainty_trace())
    assert np.array_equal(*traces)


def test_training_with_failures_is_refused() -> None:
    from sb3_pm.agents.training.team import IndependentPPO

    with pytest.raises(InputError, match="deployment condition"):
        IndependentPPO(path_graph(6, [0, 5]), n_agents=2, env_kwargs={"failures": {"agent_1": 3}})


def test_a_failed_agent_senses_nothing_even_in_a_shared_map() -> None:
    # Path 0..6; agent_1 fails on node 6 after step 1. With a shared map, agent_0 (far away on 0)
    # must not keep seeing node 6 through it: node 6's age grows.
    env = persistent_monitoring_v0.parallel_env(
        graph=path_graph(7, [6]),
        n_agents=2,
        max_cycles=10,
        initial_positions=[0, 6],
        failures={"agent_1": 1},
        shared_map=True,
    )
    observations, _ = env.reset(seed=0)
    observations, *_ = env.step(stay_actions(env, observations))
    for expected_age in (1, 2, 3):
        observations, *_ = env.step(stay_actions(env, observations))
        assert observations["agent_0"]["nodes"][6, 1] == expected_age  # AGE column


def test_the_harness_never_asks_a_failed_agent_to_act() -> None:
    from sb3_pm.baselines import make_team

    class Checked(type(make_team("random"))):  # type: ignore[misc]
        def predict_dict(self, observations, deterministic=True):
            assert set(observations) <= set(self.env.agents)
            return super().predict_dict(observations, deterministic)

    result = evaluate(
        Checked(), "paper-50", episodes=1, max_cycles=30, env_kwargs={"failures": {"agent_2": 10}}
    )
    assert result.mean["failed_agents"] == 1


def test_idle_fraction_counts_only_live_agent_steps() -> None:
    # Two agents on the single target's path; agent_1 fails at once, agent_0 idles on the cleared
    # target 0 for the rest of the episode: idle on every live agent-step after its first.
    env = persistent_monitoring_v0.parallel_env(
        graph=path_graph(3, [0]),
        n_agents=2,
        max_cycles=10,
        initial_positions=[0, 2],
        failures={"agent_1": 1},
    )
    observations, _ = env.reset(seed=0)
    while env.agents:
        observations, *_, infos = env.step(stay_actions(env, observations))
    metrics = infos["agent_0"]["metrics"]
    live_agent_steps = 2 + 9  # step 1 with both agents, then agent_0 alone
    assert metrics["idle_fraction"] == pytest.approx(10 / live_agent_steps)


def test_episodes_without_a_failure_are_left_out_of_the_after_failure_mean() -> None:
    from sb3_pm.evaluation.harness import EpisodeRecord, EvaluationResult
    from sb3_pm.evaluation.statistics import Summary

    records = [
        EpisodeRecord(0, 0, 0, {"avg_uncertainty_after_failure": 10.0}, np.zeros(1)),
        EpisodeRecord(1, 1, 1, {"avg_uncertainty_after_failure": float("nan")}, np.zeros(1)),
        EpisodeRecord(2, 2, 2, {"avg_uncertainty_after_failure": 20.0}, np.zeros(1)),
    ]
    result = EvaluationResult("p", "g", {}, records)
    assert result.mean["avg_uncertainty_after_failure"] == 15.0
    summary = Summary.of(result.values("avg_uncertainty_after_failure"))
    assert (summary.mean, summary.n) == (15.0, 2)
