"""A trained team's sampled actions at a temperature: softmax(logits / T) over the allowed nodes."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from scipy import stats

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError
from sb3_pm.evaluation import evaluate
from sb3_pm.graphs import erdos_renyi
from sb3_pm.graphs.io import save_graphml

GRAPH = erdos_renyi(12, 0.4, n_targets=3, seed=1)
ENV = {"max_cycles": 30}
# Without the paper's barrier (rules 2-4), which often leaves a single allowed node, and without a
# freeze, so the actor chooses on every step.
TINY = {
    "n_steps": 30,
    "batch_size": 30,
    "n_epochs": 1,
    "policy_kwargs": {"dcbf_barrier": False, "freeze_steps": 0},
}


def make_team() -> IndependentPPO:
    """An untrained DCBF team with a redrawn output layer, so its logits are far apart (an untrained
    actor's are within ~1e-4 of each other, which no temperature would tell apart)."""
    return spread_logits(IndependentPPO(GRAPH, n_agents=2, seed=0, env_kwargs=ENV, hyperparams=TINY), 30.0)


def spread_logits(team: IndependentPPO, scale: float) -> IndependentPPO:
    """``team`` with every learner's output layer redrawn (seeded) at ``scale``, in place."""
    generator = th.Generator().manual_seed(0)
    with th.no_grad():
        for model in team.models.values():
            weight = model.policy.action_net.weight
            weight.copy_(th.randn(weight.shape, generator=generator) * scale)
    return team


def first_observation() -> tuple[dict, np.ndarray]:
    env = persistent_monitoring_v0.parallel_env(graph=GRAPH, n_agents=2, **ENV)
    observations, _ = env.reset(seed=3)
    env.close()
    obs = observations["agent_0"]
    return obs, np.asarray(obs["action_mask"], dtype=bool)


def policy_and_log_probs(team: IndependentPPO) -> tuple[Any, dict, np.ndarray, th.Tensor]:
    """agent_0's policy, the first observation as tensors ``{key: (1, ...)}``, its mask ``(N,)``
    and its masked log-probabilities ``(N,)`` at T = 1."""
    policy = team.models["agent_0"].policy
    obs, mask = first_observation()
    tensor, _ = policy.obs_to_tensor(obs)
    with th.no_grad():
        log_probs = policy.get_distribution(tensor, mask[None]).distribution.logits[0]
    return policy, tensor, mask, log_probs


def tiled(tensor: dict, copies: int) -> dict:
    """``{key: (1, ...)}`` -> ``{key: (copies, ...)}``: one observation as a batch."""
    return {key: value.repeat(copies, *([1] * (value.dim() - 1))) for key, value in tensor.items()}


def test_samples_follow_the_tempered_softmax_over_the_allowed_nodes() -> None:
    team = make_team()
    policy, tensor, mask, logits = policy_and_log_probs(team)
    log_probs = logits.double().numpy()
    allowed = np.flatnonzero(mask)
    assert len(allowed) >= 3
    draws = 6000
    batch = tiled(tensor, draws)
    masks = np.repeat(mask[None], draws, axis=0)
    for temperature in (0.5, 2.0):
        team.set_sampling_temperature(temperature)
        th.manual_seed(0)
        with th.no_grad():
            actions = policy._predict(batch, deterministic=False, action_masks=masks).numpy()
        assert set(actions.tolist()) <= set(allowed.tolist())  # the mask still holds
        expected = np.exp(log_probs[allowed] / temperature)
        expected /= expected.sum()
        counts = np.array([(actions == node).sum() for node in allowed])
        keep = expected * draws >= 5  # the chi-square test's usual condition
        observed = np.append(counts[keep], counts[~keep].sum())
        wanted = np.append(expected[keep], expected[~keep].sum()) * draws
        nonzero = wanted > 0
        observed, wanted = observed[nonzero], wanted[nonzero]
        wanted *= observed.sum() / wanted.sum()  # exact totals, as chisquare requires
        assert stats.chisquare(observed, wanted).pvalue > 1e-3
        # The plain distribution (T = 1) differs from this one: the test can tell them apart.
        plain = np.exp(log_probs[allowed])
        plain /= plain.sum()
        assert np.abs(plain - expected).max() > 0.05


def test_a_tiny_temperature_acts_like_the_most_likely_action_and_training_ignores_it() -> None:
    team = make_team()

    def run(deterministic: bool) -> list[list[float]]:
        result = evaluate(
            team, GRAPH, n_agents=2, episodes=2, seed=5, max_cycles=30, deterministic=deterministic
        )
        return [record.trace.tolist() for record in result.episodes]  # summed uncertainty per step

    greedy, plain = run(True), run(False)
    assert plain != greedy  # sampling at T = 1 strays from the argmax on this team
    team.set_sampling_temperature(1e-4)
    assert run(False) == greedy
    # Rollouts (forward_with_masks) sample at T = 1 whatever the deployment setting.
    policy, tensor, _, _ = policy_and_log_probs(team)
    batch = tiled(tensor, 200)

    def rollout_step() -> tuple[th.Tensor, th.Tensor]:
        th.manual_seed(1)
        with th.no_grad():
            actions, _, log_probs, _ = policy.forward_with_masks(batch)
        return actions, log_probs

    cold = rollout_step()
    team.set_sampling_temperature(1.0)
    plain = rollout_step()
    assert th.equal(cold[0], plain[0]) and th.equal(cold[1], plain[1])


def test_a_tiny_temperature_never_samples_a_forbidden_node_even_if_its_logit_is_the_highest() -> None:
    team = make_team()
    policy, tensor, mask, log_probs = policy_and_log_probs(team)
    best = int(log_probs.argmax())  # allowed, and now forbidden: the top logit is a masked node
    narrower = mask.copy()
    narrower[best] = False
    allowed = np.flatnonzero(narrower)
    assert len(allowed) >= 2
    ranked = sorted(allowed, key=lambda node: float(log_probs[node]), reverse=True)
    # Its lead is far beyond the mask's constant x T, which a plain division would not survive.
    assert float(log_probs[best] - log_probs[ranked[0]]) * 1e8 > 10.0
    batch = tiled(tensor, 500)
    for temperature in (1e-8, 1e-30):
        team.set_sampling_temperature(temperature)
        with th.no_grad():
            actions = policy._predict(
                batch, deterministic=False, action_masks=np.repeat(narrower[None], 500, 0)
            )
        assert set(actions.tolist()) == {int(ranked[0])}


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, True, "0.5"])
def test_a_bad_temperature_is_refused(bad: object) -> None:
    team = make_team()
    with pytest.raises(InputError, match="sampling temperature must be"):
        team.set_sampling_temperature(bad)


def test_a_transferred_team_takes_it_on_its_rebuilt_policies() -> None:
    team = IndependentPPO(
        GRAPH,
        n_agents=2,
        seed=0,
        env_kwargs=ENV,
        hyperparams={**TINY, "policy_kwargs": {"laplacian": "none"}},
    )
    other = erdos_renyi(16, 0.3, n_targets=4, seed=2)
    team.set_sampling_temperature(0.5)
    assert {p.sampling_temperature for p in team.on_graph(other).policies.values()} == {0.5}  # kept
    moved = team.on_graph(other)
    with th.no_grad():
        for policy in moved.policies.values():  # far-apart logits, as in make_team
            policy.action_net.weight.copy_(th.randn(policy.action_net.weight.shape) * 30.0)

    def run(deterministic: bool) -> list[list[float]]:
        result = evaluate(
            moved, other, n_agents=2, episodes=2, seed=5, max_cycles=30, deterministic=deterministic
        )
        return [record.trace.tolist() for record in result.episodes]

    greedy = run(True)
    moved.set_sampling_temperature(1.0)
    assert run(False) != greedy
    moved.set_sampling_temperature(1e-4)
    assert run(False) == greedy


def test_the_command_line_samples_at_a_temperature_and_refuses_it_for_a_baseline(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sb3_pm.cli import main

    team = make_team()
    team.save(tmp_path / "team")
    graph_file = save_graphml(GRAPH, tmp_path / "g.graphml")
    out = tmp_path / "t.json"
    args = ["evaluate", "--policy", str(tmp_path / "team"), "--graph", str(graph_file), "--agents", "2"]
    args += ["--steps", "30", "--episodes", "1", "--temperature", "0.5", "--json", str(out)]
    assert main(args) == 0
    config = json.loads(out.read_text())["config"]
    assert config["temperature"] == 0.5 and config["deterministic"] is False
    assert main(["evaluate", "--policy", "grazing", "--temperature", "0.5", "--episodes", "1"]) == 2
    assert "--temperature needs a trained team" in capsys.readouterr().err
    for bad in ("0", "-1", "nan"):
        assert main([*args[:-4], "--temperature", bad]) == 2
        assert "--temperature must be positive and finite" in capsys.readouterr().err
