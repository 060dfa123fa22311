"""The multiplexer: one VecEnv per agent over n_envs copies of the parallel env."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch as th
from sb3_contrib import MaskablePPO
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pm.agents.multiplexing.learner_threads import learn_concurrently, raise_first_error
from sb3_pm.agents.multiplexing.multiplexer import ParallelEnvMultiplexer, TeamAborted
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import erdos_renyi

th.set_num_threads(1)
GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)
TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}


def make_hub(
    n_agents: int = 2, n_envs: int = 2, max_cycles: int = 5, illegal_action: str = "raise"
) -> ParallelEnvMultiplexer:
    def make():
        return persistent_monitoring_v0.parallel_env(
            graph=GRAPH, n_agents=n_agents, max_cycles=max_cycles, illegal_action=illegal_action
        )

    return ParallelEnvMultiplexer([make] * n_envs)


def drive(hub: ParallelEnvMultiplexer, steps: int) -> list[list[tuple]]:
    """Step every agent in its own thread with its first legal action; return each agent's results."""
    records: list[list[tuple]] = [[] for _ in hub.agents]

    def run(i: int) -> None:
        venv = hub.vec_envs[i]
        try:
            hub.acquire(i)
            records[i].append(venv.reset())
            for _ in range(steps):
                masks = venv.env_method("action_masks")
                venv.step_async(np.array([int(np.flatnonzero(m)[-1]) for m in masks]))
                records[i].append(venv.step_wait())
        except TeamAborted:
            pass
        finally:
            hub.finish(i)

    threads = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(hub.n_agents)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
        assert not thread.is_alive(), "multiplexer deadlocked"
    return records


def test_spaces_and_masks() -> None:
    hub = make_hub()
    venv = hub.vec_envs[1]
    assert venv.num_envs == 2
    assert venv.observation_space is hub.envs[0].observation_space("agent_1")
    assert venv.has_attr("action_masks")
    assert venv.env_is_wrapped(object) == [False, False]
    assert venv.get_attr("max_cycles") == [5, 5]
    records = drive(hub, steps=1)
    masks = venv.env_method("action_masks")
    assert len(masks) == 2 and masks[0].dtype == bool
    obs = records[1][-1][0]
    np.testing.assert_array_equal(np.stack(masks), obs["action_mask"].astype(bool))
    assert obs["nodes"].shape == (2, GRAPH.n_nodes, 5)
    assert obs["position"].shape == (2,)


def test_truncation_auto_reset_and_episode_info() -> None:
    hub = make_hub(max_cycles=5)
    records = drive(hub, steps=6)
    for agent_records in records:
        for t, (obs, rewards, dones, infos) in enumerate(agent_records[1:], start=1):
            assert rewards.dtype == np.float32 and rewards.shape == (2,)
            if t == 5:
                assert dones.all()
                for k, info in enumerate(infos):
                    assert info["TimeLimit.truncated"] is True
                    terminal = info["terminal_observation"]
                    assert set(terminal) == set(obs)
                    assert info["episode"]["l"] == 5
                    assert isinstance(info["episode"]["r"], float)
                    assert info["metrics"]["steps"] == 5
                    # After auto-reset the returned observation is the new episode's first one.
                    assert obs["dwell"][k, 0] == 0
            else:
                assert not dones.any()
                assert all("terminal_observation" not in info for info in infos)


def test_episode_returns_sum_rewards() -> None:
    hub = make_hub(n_agents=2, n_envs=1, max_cycles=4)
    records = drive(hub, steps=4)
    for agent_records in records:
        total = sum(float(r[1][0]) for r in agent_records[1:])
        assert agent_records[-1][3][0]["episode"]["r"] == pytest.approx(total, abs=1e-5)


def test_each_episode_return_starts_from_zero() -> None:
    hub = make_hub(n_agents=2, n_envs=2, max_cycles=4)
    records = drive(hub, steps=8)
    for agent_records in records:
        for k in range(2):
            second = sum(float(r[1][k]) for r in agent_records[5:9])
            assert agent_records[8][3][k]["episode"]["r"] == pytest.approx(second, abs=1e-5)
            assert agent_records[8][3][k]["episode"]["l"] == 4


def test_a_stuck_learner_stops_the_team_with_a_clear_error() -> None:
    from sb3_pm.agents.multiplexing.multiplexer import TeamTimeout

    release = threading.Event()

    class Stuck(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= 8:
                release.wait(120)  # a learner stuck outside the env, holding the baton
            return True

    team = IndependentPPO(GRAPH, n_agents=2, algo="maskable_ppo", hyperparams=TINY, wait_timeout=1.0)
    try:
        with pytest.raises(TeamTimeout, match="waited more than 1.0 s.*wait_timeout"):
            team.learn(64, callback={"agent_1": Stuck()})
    finally:
        release.set()


def test_same_seed_same_observations() -> None:
    def run() -> np.ndarray:
        hub = make_hub()
        hub.seed(3)
        return drive(hub, steps=3)[0][-1][0]["nodes"]

    np.testing.assert_array_equal(run(), run())


def test_learners_run_with_maskable_and_plain_ppo() -> None:
    for algo in ("maskable_ppo", "ppo"):
        team = IndependentPPO(
            GRAPH, n_agents=2, env_kwargs={"max_cycles": 10}, algo=algo, n_envs=2, hyperparams=TINY
        )
        team.learn(64)
        assert team.num_timesteps == 64
        assert all(len(m.ep_info_buffer) > 0 for m in team.models.values())


def test_raising_learner_does_not_hang() -> None:
    class Boom(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= 20:
                raise RuntimeError("boom")
            return True

    team = IndependentPPO(
        GRAPH, n_agents=3, env_kwargs={"max_cycles": 10}, algo="maskable_ppo", n_envs=2, hyperparams=TINY
    )
    outcome: dict[str, BaseException] = {}

    def target() -> None:
        try:
            team.learn(640, callback={"agent_1": Boom()})
        except BaseException as error:  # noqa: BLE001
            outcome["error"] = error

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(60)
    assert not thread.is_alive(), "team hung after a learner raised"
    assert isinstance(outcome.get("error"), RuntimeError) and str(outcome["error"]) == "boom"
    assert team.num_timesteps < 640


def test_stopping_learner_ends_team() -> None:
    class Stop(BaseCallback):
        def _on_step(self) -> bool:
            return self.num_timesteps < 20

    team = IndependentPPO(
        GRAPH, n_agents=2, env_kwargs={"max_cycles": 10}, algo="maskable_ppo", n_envs=1, hyperparams=TINY
    )
    done = threading.Event()

    def target() -> None:
        team.learn(640, callback=lambda agent: Stop() if agent == "agent_0" else None)
        done.set()

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(60)
    assert done.is_set()
    assert team.hub.aborted is not None and "agent_0" in team.hub.aborted


def test_learn_concurrently_reports_errors_in_order() -> None:
    hub = make_hub(n_agents=2, n_envs=1)
    models = [
        MaskablePPO("MultiInputPolicy", venv, n_steps=16, batch_size=16, n_epochs=1) for venv in hub.vec_envs
    ]
    errors = learn_concurrently(models, hub, [{"total_timesteps": 32}, {"total_timesteps": 32}])
    assert errors == [None, None]
    raise_first_error(errors)
    assert [m.num_timesteps for m in models] == [32, 32]


def test_plain_ppo_single_agent_env() -> None:
    hub = make_hub(n_agents=1, n_envs=2, illegal_action="stay")
    model = PPO("MultiInputPolicy", hub.vec_envs[0], n_steps=16, batch_size=32, n_epochs=1)
    raise_first_error(learn_concurrently([model], hub, [{"total_timesteps": 32}]))
    assert model.num_timesteps == 32
