"""IndependentPPO: the team API (learn, save/load, predict, resume, determinism)."""

from __future__ import annotations

import json

import pytest
import torch as th

from sb3_pm.agents.training.team import IndependentPPO, agent_seed
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import erdos_renyi
from sb3_pm.team_interface import Team

th.set_num_threads(1)
GRAPH = erdos_renyi(12, 0.3, n_targets=3, seed=1)
OTHER = erdos_renyi(12, 0.3, n_targets=3, seed=2)
TINY = {"n_steps": 16, "batch_size": 32, "n_epochs": 2, "learning_rate": "lin_1e-3"}
ENV = {"max_cycles": 20}


def make_team(**kwargs) -> IndependentPPO:
    options = {
        "n_agents": 2,
        "env_kwargs": ENV,
        "algo": "maskable_ppo",
        "n_envs": 2,
        "seed": 0,
        "hyperparams": TINY,
    }
    options.update(kwargs)
    return IndependentPPO(GRAPH, **options)


def rollout_actions(team: IndependentPPO, steps: int = 15, seed: int = 5) -> list[dict[str, int]]:
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=team.n_agents, **ENV)
    observations, _ = env.reset(seed=seed)
    team.reset(env, seed=seed)
    actions = []
    for _ in range(steps):
        chosen = team.predict_dict(observations, deterministic=True)
        for agent, node in chosen.items():
            assert observations[agent]["action_mask"][node] == 1
        actions.append(chosen)
        observations, *_ = env.step(chosen)
    return actions


def parameters(team: IndependentPPO) -> list[th.Tensor]:
    return [p.detach().clone() for agent in team.agents for p in team.models[agent].policy.parameters()]


def test_is_a_team_and_learns() -> None:
    team = make_team()
    assert isinstance(team, Team)
    before = parameters(team)
    team.learn(64)
    assert team.num_timesteps == 64
    assert any(not th.equal(a, b) for a, b in zip(before, parameters(team)))
    # Learners are independent: different seeds, hence different initial weights.
    first, second = (list(team.models[a].policy.parameters())[0] for a in team.agents)
    assert not th.equal(first, second)
    assert agent_seed(0, 1) != agent_seed(1, 0)


def test_same_seed_same_parameters_bit_for_bit() -> None:
    # Both built before either learns: learn() must not depend on what ran since construction.
    teams = [make_team(n_agents=3), make_team(n_agents=3)]
    runs = []
    for team in teams:
        team.learn(64)
        runs.append(parameters(team))
    assert all(th.equal(a, b) for a, b in zip(*runs))
    other = make_team(n_agents=3, seed=1)
    other.learn(64)
    assert any(not th.equal(a, b) for a, b in zip(runs[0], parameters(other)))


def test_save_load_round_trip(tmp_path) -> None:
    team = make_team()
    team.learn(32)
    folder = team.save(tmp_path / "team")
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["graph"]["fingerprint"] == GRAPH.fingerprint
    assert manifest["n_agents"] == 2 and manifest["algo"] == "maskable_ppo"
    assert manifest["env_kwargs"] == ENV and "stable_baselines3" in manifest["versions"]
    assert (folder / "agent_0.zip").exists() and (folder / "agent_1.zip").exists()
    loaded = IndependentPPO.load(folder)
    assert loaded.graph.same_problem(GRAPH)
    assert rollout_actions(loaded) == rollout_actions(team)


def test_save_refuses_to_overwrite(tmp_path) -> None:
    team = make_team()
    team.save(tmp_path / "team")
    with pytest.raises(FileExistsError, match="already holds a saved team"):
        team.save(tmp_path / "team")
    team.save(tmp_path / "team", overwrite=True)


def test_load_errors(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="no saved team"):
        IndependentPPO.load(tmp_path / "missing")
    team = make_team()
    folder = team.save(tmp_path / "team")
    with pytest.raises(ValueError, match=f"{GRAPH.fingerprint}.*{OTHER.fingerprint}"):
        IndependentPPO.load(folder, graph=OTHER)
    (folder / "agent_1.zip").unlink()
    with pytest.raises(FileNotFoundError, match="agent_1.zip"):
        IndependentPPO.load(folder)


def test_reset_on_other_graph_fails() -> None:
    team = make_team()
    env = persistent_monitoring_v0.parallel_env(graph=OTHER, n_agents=2, **ENV)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="trained on graph"):
        team.reset(env, seed=0)


def test_resume_continues_timestep_count(tmp_path) -> None:
    team = make_team()
    team.learn(32)
    folder = team.save(tmp_path / "team")
    loaded = IndependentPPO.load(folder)
    loaded.learn(32, reset_num_timesteps=False)
    assert loaded.num_timesteps == 64
    assert all(m.num_timesteps == 64 for m in loaded.models.values())
    # The same object can continue too, mid-episode.
    loaded.learn(32, reset_num_timesteps=False)
    assert loaded.num_timesteps == 96


def test_mismatched_n_steps_or_n_envs() -> None:
    with pytest.raises(ValueError, match="same n_steps.*agent_1=32"):
        make_team(per_agent={"agent_1": {"n_steps": 32}})
    with pytest.raises(ValueError, match="same n_envs"):
        make_team(per_agent={"agent_0": {"n_envs": 4}})
    with pytest.raises(ValueError, match="unknown agents"):
        make_team(per_agent={"agent_9": {"gamma": 0.9}})


def test_per_agent_overrides() -> None:
    team = make_team(per_agent={"agent_1": {"learning_rate": 1e-4, "gamma": 0.9}})
    assert team.models["agent_0"].gamma == 0.99 and team.models["agent_1"].gamma == 0.9
    assert team.models["agent_0"].lr_schedule(1.0) == pytest.approx(1e-3)
    assert team.models["agent_1"].lr_schedule(1.0) == pytest.approx(1e-4)


def test_predict_with_plain_ppo() -> None:
    team = make_team(algo="ppo")
    assert team.env_kwargs["illegal_action"] == "stay"
    actions = team.predict_dict(
        {
            a: obs
            for a, obs in persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, **ENV)
            .reset(seed=0)[0]
            .items()
        }
    )
    assert set(actions) == {"agent_0", "agent_1"} and all(isinstance(v, int) for v in actions.values())


def test_predict_is_sb3_shaped_around_predict_dict() -> None:
    """``predict`` returns SB3's ``(actions, state)``: ``predict_dict``'s actions, ``state`` as given."""
    import numpy as np

    from sb3_pm.baselines import make_team as make_baseline

    trained = make_team()
    trained.learn(32)
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, **ENV)
    observations, _ = env.reset(seed=0)
    for team in (make_baseline("random"), trained):
        team.reset(env, seed=1)
        expected = team.predict_dict(observations, deterministic=True)
        team.reset(env, seed=1)  # the same draws again (the random baseline)
        result = team.predict(observations)
        assert isinstance(result, tuple) and len(result) == 2
        assert result == (expected, None)
        state = object()
        team.reset(env, seed=1)
        actions, returned = team.predict(
            observations, state=state, episode_start=np.ones(2, dtype=bool), deterministic=True
        )
        assert returned is state and actions == expected
    env.close()


def test_stochastic_evaluation_is_reproducible_and_differs_from_deterministic() -> None:
    from sb3_pm.evaluation import evaluate

    team = make_team()  # untrained: a near-uniform distribution, so samples differ from the argmax

    def run(deterministic: bool) -> list[float]:
        result = evaluate(
            team, GRAPH, n_agents=2, episodes=3, seed=7, max_cycles=20, deterministic=deterministic
        )
        assert result.config["deterministic"] is deterministic
        return [record.metrics["avg_uncertainty"] for record in result.episodes]

    sampled = run(False)
    assert run(False) == sampled  # the team's seeded stream: same episodes, same samples
    assert run(True) != sampled
