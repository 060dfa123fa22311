"""A team's rollout passes run as one team pass per joint step (the learners' own policy code
mapped over their stacked parameters) train the same parameters as one pass per learner, bit for
bit."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.utils import obs_as_tensor

from sb3_pm.agents.training import rollout_batching
from sb3_pm.agents.training.rollout_batching import RolloutBatcher
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.graphs import erdos_renyi
from sb3_pm.graphs.distributions import ErdosRenyiFamily

th.set_num_threads(1)
GRAPH = erdos_renyi(14, 0.3, n_targets=4, seed=3)
TINY = {"n_steps": 16, "batch_size": 16, "n_epochs": 2}


def make_team(
    n_envs: int = 2,
    seed: int = 0,
    algo: str | None = None,
    graph: Any = GRAPH,
    concurrent_updates: bool = True,
    env_kwargs: dict[str, Any] | None = None,
    **policy_kwargs: Any,
) -> IndependentPPO:
    hyperparams: dict[str, Any] = dict(TINY)
    if algo is None:
        # 32 units: 14 nodes x 32 fill whole blocks of the activations' vector loops (with fewer,
        # the team pass is refused and every learner runs its own pass; see below)
        hyperparams["policy_kwargs"] = {"hidden_dim": 32, **policy_kwargs}
    return IndependentPPO(
        graph,
        n_agents=3,
        n_envs=n_envs,
        seed=seed,
        algo=algo,
        env_kwargs={"max_cycles": 20, **(env_kwargs or {})},
        hyperparams=hyperparams,
        concurrent_updates=concurrent_updates,
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


def train_both_ways(
    steps: int = 64, callback: Any = None, twice: bool = False, **kwargs: Any
) -> tuple[IndependentPPO, IndependentPPO]:
    teams = []
    for batched in (False, True):
        team = make_team(**kwargs)
        team.batched_rollouts = batched
        team.learn(steps, callback=None if callback is None else callback())
        if twice:
            team.learn(steps, reset_num_timesteps=False)
        teams.append(team)
    return teams[0], teams[1]


def assert_same_parameters(serial: IndependentPPO, batched: IndependentPPO) -> None:
    for a, b in zip(parameters(serial), parameters(batched), strict=True):
        assert th.equal(a, b)


def filter_counts(team: IndependentPPO) -> dict[str, dict[str, int]]:
    return {a: {k: int(v) for k, v in team.models[a].policy.filter_counts.items()} for a in team.agents}


#: The territory rule's move as an input (it needs a known map), for ``advice_prior``.
ADVICE = {"advice_input": True, "target_knowledge": "known", "graph_knowledge": "known"}
FAMILY = ErdosRenyiFamily(n_nodes_range=(8, 14), edge_prob=(0.25, 0.4), name="small-er")


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"gat_heads": 2},
        {"use_estimator": False},
        {"hidden_dim": 64, "gat_layers": 3},
        {"dcbf_barrier": True, "freeze_steps": 10},
        {"neglect_bound": 12},
        {"n_envs": 1},
        {"concurrent_updates": False},
        {"twice": True},
        {"graph": FAMILY, "laplacian": "none"},
        {"env_kwargs": ADVICE, "advice_prior": 2.0},
    ],
    ids=[
        "small",
        "2-heads",
        "no-estimator",
        "wide-3-layers",
        "barrier",
        "bound",
        "one-env-copy",
        "serial-updates",
        "learn-twice",
        "graph-family-padded",
        "advice-prior",
    ],
)
def test_batched_rollouts_train_the_same_parameters_bit_for_bit(
    options: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    recorded = Recorded(monkeypatch)
    serial, batched = train_both_ways(**options)
    assert_same_parameters(serial, batched)
    assert filter_counts(serial) == filter_counts(batched)  # rule 8's decisions, counted per learner
    joint_steps = 64 // options.get("n_envs", 2)  # each learn() call: 64 steps per learner
    assert recorded.batchers  # one per learn() call
    for batcher in recorded.batchers:  # one stacked pass per joint step, none left to a learner
        assert batcher.refusal is None
        assert batcher.counts == {"stacked": joint_steps, "serial": 0}
    if "neglect_bound" in options:
        assert sum(counts["forced"] for counts in filter_counts(batched).values()) > 0


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
    assert batcher.counts == {"stacked": 0, "serial": 1} and "published" in str(batcher.refusal)
    assert batcher.heads(1, team.hub.published[1]) is not None


def test_a_team_pass_that_would_round_otherwise_leaves_every_pass_to_its_learner(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """14 nodes x 8 units leave an ELU's last elements to its scalar loop: every step is refused,
    each learner runs its own pass, and the parameters are those of one pass per learner."""
    recorded = Recorded(monkeypatch)
    serial, batched = train_both_ways(steps=32, hidden_dim=8)
    assert_same_parameters(serial, batched)
    (batcher,) = recorded.batchers
    assert "vector loop" in str(batcher.refusal)
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


class StopAt(BaseCallback):
    """Stops its learner's training at ``steps`` (the team then stops too)."""

    def __init__(self, steps: int) -> None:
        super().__init__()
        self.steps = steps

    def _on_step(self) -> bool:
        return self.num_timesteps < self.steps


def test_a_learner_that_stops_early_counts_rule_8_as_its_own_passes_do() -> None:
    def callbacks() -> list[Any]:
        return [None, StopAt(40), None]

    serial, batched = train_both_ways(callback=callbacks, neglect_bound=12)
    assert filter_counts(serial) == filter_counts(batched)
    assert filter_counts(batched)["agent_1"]["masks"] == 40  # it stopped there, counted up to there


class Perturb(BaseCallback):
    """Writes new values into its policy's actor and critic in place, once, mid-rollout."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def _on_step(self) -> bool:
        if self.num_timesteps == self.at:
            with th.no_grad():
                for module in (self.model.policy.action_net, self.model.policy.value_net):
                    for parameter in module.parameters():
                        parameter.mul_(-2.0)
        return True


def test_a_policy_changed_in_place_during_a_rollout_gets_its_own_pass(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    recorded = Recorded(monkeypatch)
    serial, batched = train_both_ways(callback=lambda: [None, Perturb(20), None])
    assert_same_parameters(serial, batched)
    (batcher,) = recorded.batchers
    assert batcher.counts["serial"] == 1 and "changed" in str(batcher.refusal)


def test_what_cannot_stack_says_why() -> None:
    sparse = make_team(gat_backend="sparse")
    sparse.hub._joint_reset()
    batcher = RolloutBatcher(sparse.hub, [sparse.models[a] for a in sparse.agents])
    assert batcher.heads(0, sparse.hub.published[0]) is None
    assert "sparse" in str(batcher.refusal)
    assert batcher.heads(1, sparse.hub.published[1]) is None  # the step is refused once, for all
    assert batcher.counts == {"stacked": 0, "serial": 2}

    big = make_team(n_envs=9, graph=erdos_renyi(120, 0.05, n_targets=10, seed=1))  # 9 x 120 rows
    big.hub._joint_reset()
    batcher = RolloutBatcher(big.hub, [big.models[a] for a in big.agents])
    assert batcher.heads(0, big.hub.published[0]) is None
    assert "gathering" in str(batcher.refusal)
