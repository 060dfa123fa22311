"""The pruned acting pass: the serial path's actions, a margin that falls back, and its refusals."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th

from sb3_pm.agents.deployment import pruned_inference
from sb3_pm.agents.deployment.pruned_inference import PrunedInference, allowed_rows, decide, prune_problem
from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.graphs import erdos_renyi

th.set_num_threads(1)
GRAPH = erdos_renyi(16, 0.3, n_targets=4, seed=3)  # 16 nodes x 8 units: whole vector blocks
TINY = {"n_steps": 16, "batch_size": 16, "n_epochs": 1}


@pytest.fixture(autouse=True)
def small_graphs_prune(monkeypatch: pytest.MonkeyPatch) -> None:
    """The pass runs from MIN_NODES nodes on; these tests exercise it on a 16-node graph."""
    monkeypatch.setattr(pruned_inference, "MIN_NODES", 0)


def make_team(scale: float = 300.0, seed: int = 0, **policy_kwargs: Any) -> IndependentPPO:
    """An untrained 3-agent team whose output layers are scaled by ``scale``: an untrained actor's
    logits all lie within about 1e-4, below the pass's margin; a trained one's are far apart."""
    team = IndependentPPO(
        GRAPH,
        n_agents=3,
        seed=seed,
        env_kwargs={"max_cycles": 60},
        hyperparams={**TINY, "policy_kwargs": {"hidden_dim": 8, **policy_kwargs}},
    )
    with th.no_grad():
        for agent in team.agents:
            team.models[agent].policy.action_net.weight.mul_(scale)
    return team


def play_both_ways(team: IndependentPPO, steps: int = 60, seed: int = 7) -> int:
    """Drive an episode with the serial path's actions, checking at every step that the team's
    default (stacked, pruned) actions are the same; returns the steps checked."""
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=3, max_cycles=60)
    observations, _ = env.reset(seed=seed)
    team.reset(env, seed=seed)
    checked = 0
    for _ in range(steps):
        if not observations:
            break
        team.stacked_inference = False
        serial = team.predict(observations)
        team.stacked_inference = True
        assert team.predict(observations) == serial
        checked += 1
        observations, *_ = env.step(serial)
    return checked


@pytest.mark.parametrize(
    "policy_kwargs",
    [
        {},
        {"laplacian": "none"},
        {"use_estimator": False},
        {"gat_layers": 3, "gat_heads": 2},
        {"net_arch": {"pi": [16, 16], "vf": [16, 16]}},
        {"dcbf_barrier": True, "freeze_steps": 10},
    ],
    ids=["small", "no-encoding", "no-estimator", "3-layers", "narrow-actor", "barrier"],
)
def test_pruned_actions_equal_the_serial_ones(policy_kwargs: dict[str, Any]) -> None:
    team = make_team(**policy_kwargs)
    checked = play_both_ways(team)
    assert team._stacker.prune_problem([team.models[a].policy for a in team.agents]) is None
    assert team._stacker.counts["pruned"] >= 0.9 * checked  # the pruned pass decided nearly every step


def test_pruned_actions_on_a_sparse_graph_of_the_default_size_threshold(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """128 nodes of mean degree about 5 with one attention head (the default configuration's), above
    the real size threshold: earlier layers run on tens of rows and the allowed sets vary, as on
    the published 200-node graph."""
    monkeypatch.setattr(pruned_inference, "MIN_NODES", 100)
    graph = erdos_renyi(128, 0.04, n_targets=12, seed=5)
    team = IndependentPPO(
        graph,
        n_agents=3,
        seed=1,
        env_kwargs={"max_cycles": 30},
        hyperparams={**TINY, "policy_kwargs": {"gat_heads": 1}},
    )
    with th.no_grad():
        for agent in team.agents:
            team.models[agent].policy.action_net.weight.mul_(300.0)
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=3, max_cycles=30)
    observations, _ = env.reset(seed=3)
    team.reset(env, seed=3)
    while env.agents:
        team.stacked_inference = False
        serial = team.predict(observations)
        team.stacked_inference = True
        assert team.predict(observations) == serial
        observations, *_ = env.step(serial)
    assert team._stacker.counts["pruned"] >= 27  # of 30 steps


def test_an_untrained_team_falls_back_to_the_full_pass() -> None:
    team = make_team(scale=1.0)
    checked = play_both_ways(team, steps=20)
    assert team._stacker.counts["full"] == checked and team._stacker.counts["pruned"] == 0


def test_pruned_inference_off_computes_every_logit() -> None:
    team = make_team()
    team.pruned_inference = False
    checked = play_both_ways(team, steps=20)
    assert team._stacker.counts == {"pruned": 0, "full": checked}


def test_decide_takes_the_best_allowed_node_only_beyond_the_margin() -> None:
    rows = th.tensor([[2, 5, 7, 2], [1, 3, 1, 1]])
    candidate = th.tensor([[True, True, False, False], [True, False, False, False]])
    margins = th.tensor([0.01, 0.01], dtype=th.float64)
    logits = th.tensor([[0.5, 1.0, 9.0, 0.5], [-3.0, 7.0, -3.0, -3.0]])
    # map 0: node 5 leads node 2 by 0.5 (node 7 is not allowed); map 1: node 1 is the only one allowed
    assert decide(logits, rows, candidate, margins).tolist() == [5, 1]
    tied = logits.clone()
    tied[0, 0] = 0.995  # within the margin of node 5's 1.0: the full pass must decide
    assert decide(tied, rows, candidate, margins) is None
    assert decide(logits.where(th.arange(4) != 1, th.tensor(float("nan"))), rows, candidate, margins) is None


def test_allowed_rows_list_the_allowed_nodes_then_the_own_node_padded() -> None:
    masks = th.zeros((2, 10), dtype=th.bool)
    masks[0, [3, 1]] = True
    masks[1, [4, 5, 6, 7, 8]] = True
    rows, candidate = allowed_rows(masks, th.tensor([0, 5]), multiple=2)
    assert rows.tolist() == [[1, 3, 0, 1, 1, 1], [4, 5, 6, 7, 8, 4]]  # own node 0 is not allowed
    assert candidate.tolist() == [
        [True, True, False, False, False, False],
        [True, True, True, True, True, False],
    ]


def test_what_cannot_prune_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    team = make_team(activation_fn=th.nn.ReLU)
    assert "Tanh" in str(prune_problem([team.models[a].policy for a in team.agents]))
    checked = play_both_ways(team, steps=10)  # the full stacked pass acts instead
    assert team._stacker.counts["full"] == checked
    monkeypatch.setattr(pruned_inference, "MIN_NODES", 100)
    small = make_team()
    assert "below 100" in str(prune_problem([small.models[a].policy for a in small.agents]))
    odd = erdos_renyi(14, 0.3, n_targets=4, seed=3)  # 14 x 8 units: a last partial vector block
    monkeypatch.setattr(pruned_inference, "MIN_NODES", 0)
    team = IndependentPPO(odd, n_agents=2, seed=0, hyperparams={**TINY, "policy_kwargs": {"hidden_dim": 8}})
    assert "vector loop" in str(prune_problem([team.models[a].policy for a in team.agents]))


def test_a_pass_that_would_round_differently_is_refused_by_its_own_check(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def in_double(policies: Any, hidden: th.Tensor, rows: th.Tensor, n_nodes: int) -> th.Tensor:
        # the same layer summed in float64 and rounded once: the last bit differs on some rows
        layers = [p.action_net for p in policies]
        return th.cat(
            [
                th.nn.functional.linear(hidden[k].double(), layer.weight.double(), layer.bias.double())
                .float()
                .T
                for k, layer in enumerate(layers)
            ]
        )

    monkeypatch.setattr(pruned_inference, "_output_layer", in_double)
    team = make_team()
    checked = play_both_ways(team, steps=10)
    problem = team._stacker.prune_problem([team.models[a].policy for a in team.agents])
    assert "round" in str(problem)
    assert team._stacker.counts == {"pruned": 0, "full": checked}


def test_the_margin_grows_with_the_output_layer() -> None:
    team = make_team(scale=1.0)
    policy = team.models[team.agents[0]].policy
    small = pruned_inference.logit_bound(policy)
    with th.no_grad():
        policy.action_net.weight.mul_(10.0)
    assert pruned_inference.logit_bound(policy) > 5 * small
    assert isinstance(PrunedInference().counts, dict) and np.isfinite(small)
