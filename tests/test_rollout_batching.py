"""A team's rollout passes stacked into one per joint step train the same parameters, bit for bit."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.utils import obs_as_tensor

from sb3_pm.agents import rollout_batching
from sb3_pm.agents.rollout_batching import RolloutBatcher
from sb3_pm.agents.team import IndependentPPO
from sb3_pm.graphs import erdos_renyi

th.set_num_threads(1)
GRAPH = erdos_renyi(14, 0.3, n_targets=4, seed=3)
TINY = {"n_steps": 16, "batch_size": 16, "n_epochs": 2}


def make_team(
    n_envs: int = 2, seed: int = 0, algo: str | None = None, **policy_kwargs: Any
) -> IndependentPPO:
    hyperparams: dict[str, Any] = dict(TINY)
    if algo is None:
        hyperparams["policy_kwargs"] = {"hidden_dim": 8, **policy_kwargs}
    return IndependentPPO(
        GRAPH,
        n_agents=3,
        n_envs=n_envs,
        seed=seed,
        algo=algo,
        env_kwargs={"max_cycles": 20},
        hyperparams=hyperparams,
    )


def parameters(team: IndependentPPO) -> list[th.Tensor]:
    return [th.cat([p.detach().flatten() for p in team.models[a].policy.parameters()]) for a in team.agents]


class Recorded:
    """Records every batcher a team builds (a fresh one per ``learn()``), with its counts."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.batchers: list[RolloutBatcher] = []
        original = rollout_batching.RolloutBatcher.attach

        def attach(batcher: RolloutBatcher) -> None:
            self.batchers.append(batcher)
            original(batcher)

        monkeypatch.setattr(rollout_batching.RolloutBatcher, "attach", attach)


def train_both_ways(steps: int = 64, **kwargs: Any) -> tuple[IndependentPPO, IndependentPPO]:
    teams = []
    for batched in (False, True):
        team = make_team(**kwargs)
        team.batched_rollouts = batched
        team.learn(steps)
        teams.append(team)
    return teams[0], teams[1]


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        {},
        {"laplacian": "eigen", "gat_heads": 2},
        {"use_estimator": False},
        {"hidden_dim": 32, "gat_layers": 3},
        {"dcbf_barrier": True, "freeze_steps": 10},
        {"neglect_bound": 12},
    ],
    ids=["small", "eigen-2-heads", "no-estimator", "wide-3-layers", "barrier", "bound"],
)
def test_batched_rollouts_train_the_same_parameters_bit_for_bit(
    policy_kwargs: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    recorded = Recorded(monkeypatch)
    serial, batched = train_both_ways(**policy_kwargs)
    for a, b in zip(parameters(serial), parameters(batched)):
        assert th.equal(a, b)
    (batcher,) = recorded.batchers
    assert batcher.problem is None
    assert batcher.counts == {"stacked": 32, "serial": 0}  # one pass per joint step (64 steps, 2 copies)
    for agent in serial.agents:  # rule 8's decisions counted per learner as the serial passes count them
        counts = [
            {k: int(v) for k, v in t.models[agent].policy.filter_counts.items()} for t in (serial, batched)
        ]
        assert counts[0] == counts[1]
    if "neglect_bound" in policy_kwargs:
        assert sum(int(batched.models[a].policy.filter_counts["forced"]) for a in batched.agents) > 0


def test_each_learner_is_served_its_own_passes_heads() -> None:
    team = make_team(n_envs=3)
    hub = team.hub
    models = [team.models[a] for a in team.agents]
    hub._joint_reset()  # every agent's first observation published, as a joint reset does
    batcher = RolloutBatcher(hub, models)
    for index, model in enumerate(models):
        obs = hub.published[index]
        served = batcher.heads(index, obs)
        assert served is not None
        with th.no_grad():
            expected = model.policy.rollout_heads(obs_as_tensor(obs, model.device))
        for got, want in zip(served, expected):
            assert th.equal(got, want)
    assert batcher.counts == {"stacked": 1, "serial": 0}  # one pass served all three learners


def test_an_observation_other_than_the_published_one_gets_its_own_pass() -> None:
    team = make_team()
    team.hub._joint_reset()
    models = [team.models[a] for a in team.agents]
    batcher = RolloutBatcher(team.hub, models)
    copy = {key: np.array(value) for key, value in team.hub.published[1].items()}
    assert batcher.heads(1, copy) is None
    assert batcher.counts == {"stacked": 0, "serial": 1}
    assert batcher.heads(1, team.hub.published[1]) is not None


def test_a_stack_that_would_round_differently_leaves_every_pass_serial(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sb3_pm.agents.stacked_inference import StackedInference

    monkeypatch.setattr(
        StackedInference, "_rounds_as_serial", lambda self, stack, maps=1, values=False: False
    )
    recorded = Recorded(monkeypatch)
    serial, batched = train_both_ways(steps=32)
    for a, b in zip(parameters(serial), parameters(batched)):
        assert th.equal(a, b)
    (batcher,) = recorded.batchers
    assert "round" in str(batcher.problem)
    assert batcher.counts["stacked"] == 0 and batcher.counts["serial"] > 0


def test_no_batcher_without_the_baton_or_for_other_learners() -> None:
    team = make_team()
    assert team._rollout_batcher() is not None
    team.batched_rollouts = False
    assert team._rollout_batcher() is None
    free = IndependentPPO(GRAPH, n_agents=2, n_envs=1, strict_order=False, hyperparams=TINY)
    assert free._rollout_batcher() is None
    assert make_team(algo="maskable_ppo")._rollout_batcher() is None


def test_the_hook_is_detached_after_training_and_never_saved(tmp_path: Any) -> None:
    team = make_team()
    team.learn(32)
    assert all(team.models[a].rollout_heads_source is None for a in team.agents)
    team.save(tmp_path / "team")  # (tests/test_checkpoints.py resumes batched runs bit for bit)
    loaded = IndependentPPO.load(tmp_path / "team")
    assert all(loaded.models[a].rollout_heads_source is None for a in loaded.agents)
