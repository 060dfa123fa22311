"""``advice_imitation``: after each PPO update, a pass that teaches the actor the env's advice.

The pass must raise the probability of the advised node on the rollout it learns from, count only
rows whose advice the stored mask allows, leave a learner without it untouched, draw nothing at
random, and refuse what it cannot read.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from sb3_pm.agents.training.team import IndependentPPO
from sb3_pm.errors import InputError
from sb3_pm.evaluation.teams import load_trained_team
from sb3_pm.policies.settings import check_advice_weight
from sb3_pm.ppo_dcbf.imitation import advised_actions, imitation_pass

th.set_num_threads(1)
KNOWN = {"graph_knowledge": "known", "target_knowledge": "known"}


def small_team(
    env_kwargs: dict, advice_imitation: float = 1.0, learning_rate: float = 3e-4, **policy_kwargs
) -> IndependentPPO:
    """A tiny two-agent team on ``paper-50`` with a known map, without the barrier rule (as the
    transfer config), which would mask most advised moves of an untrained estimator."""
    return IndependentPPO(
        "paper-50",
        n_agents=2,
        n_envs=1,
        seed=0,
        env_kwargs={"max_cycles": 40, **KNOWN, **env_kwargs},
        hyperparams={
            "n_steps": 32,
            "batch_size": 16,
            "n_epochs": 1,
            "learning_rate": learning_rate,
            "advice_imitation": advice_imitation,
            "policy_kwargs": {"laplacian": "none", "hidden_dim": 8, "dcbf_barrier": False, **policy_kwargs},
        },
    )


def advice_log_probs(model) -> th.Tensor:
    """The log-probability of the advised node on every counted row of ``model``'s last rollout."""
    buffer = model.rollout_buffer
    samples = buffer._get_samples(np.arange(buffer.buffer_size * buffer.n_envs))
    masks = th.as_tensor(samples.action_masks)
    actions, rows = advised_actions(samples.observations["nodes"], masks)
    with th.no_grad():
        _, log_prob, _ = model.policy.evaluate_actions(samples.observations, actions, action_masks=masks)
    return log_prob[rows]


def test_advised_actions_count_only_advice_the_mask_allows() -> None:
    nodes = th.zeros(3, 4, 6)
    nodes[0, 2, -1] = 1.0  # advised and allowed
    nodes[1, 3, -1] = 1.0  # advised, masked out
    masks = th.tensor([[1, 0, 1, 0], [1, 1, 1, 0], [1, 1, 1, 1]])  # row 2: no advice at all
    actions, rows = advised_actions(nodes, masks)
    assert actions[:2].tolist() == [2, 3]
    assert rows.tolist() == [True, False, False]


def test_the_pass_raises_the_probability_of_the_advised_node_on_its_rollout() -> None:
    """Without a prior the actor starts far from the rule; passes alone (no PPO step) bring the
    advised node's probability up on the rows they learn from."""
    team = small_team({"advice_input": True}, advice_imitation=1.0, learning_rate=0.01)
    team.learn(32)  # one rollout and update, so the buffer holds a rollout
    model = team.models["agent_0"]
    before = advice_log_probs(model)
    assert len(before) > 10
    probabilities = [imitation_pass(model)[1] for _ in range(20)]
    after = advice_log_probs(model)
    assert after.mean() > before.mean() + 0.5, (before.mean(), after.mean())
    assert probabilities[-1] > probabilities[0]
    team.close()


def test_a_learner_without_it_trains_as_before_and_one_with_it_otherwise() -> None:
    """Weight 0 runs no pass: the same parameters as a team built without the key. A positive
    weight changes them."""

    def parameters(weight: float | None) -> list[th.Tensor]:
        kwargs = {} if weight is None else {"advice_imitation": weight}
        team = IndependentPPO(
            "paper-50",
            n_agents=2,
            n_envs=1,
            seed=0,
            env_kwargs={"max_cycles": 40, **KNOWN, "advice_input": True},
            hyperparams={
                "n_steps": 32,
                "batch_size": 16,
                "n_epochs": 1,
                **kwargs,
                "policy_kwargs": {"laplacian": "none", "hidden_dim": 8, "dcbf_barrier": False},
            },
        )
        team.learn(64)
        found = [p.detach().clone() for p in team.models["agent_1"].policy.parameters()]
        team.close()
        return found

    plain, zero, taught = parameters(None), parameters(0.0), parameters(1.0)
    assert all(th.equal(a, b) for a, b in zip(plain, zero))
    assert not all(th.equal(a, b) for a, b in zip(plain, taught))


def test_side_by_side_updates_give_the_same_parameters_with_the_pass() -> None:
    """The pass draws nothing at random, so updates in threads are the serial ones bit for bit."""

    def parameters(concurrent: bool) -> list[th.Tensor]:
        team = IndependentPPO(
            "paper-50",
            n_agents=2,
            n_envs=1,
            seed=3,
            concurrent_updates=concurrent,
            env_kwargs={"max_cycles": 40, **KNOWN, "advice_input": True},
            hyperparams={
                "n_steps": 32,
                "batch_size": 16,
                "n_epochs": 2,
                "advice_imitation": 0.5,
                "policy_kwargs": {
                    "laplacian": "none",
                    "hidden_dim": 8,
                    "dcbf_barrier": False,
                    "advice_prior": 2.0,
                },
            },
        )
        team.learn(96)
        found = [p.detach().clone() for a in team.agents for p in team.models[a].policy.parameters()]
        team.close()
        return found

    assert all(th.equal(a, b) for a, b in zip(parameters(False), parameters(True)))


def test_a_saved_team_keeps_its_weight(tmp_path) -> None:
    team = small_team({"advice_input": True}, advice_imitation=0.5)
    team.learn(32)
    team.save(tmp_path / "team")
    team.close()
    loaded = load_trained_team(tmp_path / "team", "paper-50")
    assert loaded.hyperparams["advice_imitation"] == 0.5


@pytest.mark.parametrize(
    ("env_kwargs", "weight", "message"),
    [
        ({}, 1.0, "advice_imitation teaches the node the env's advice_input flags"),
        (
            {"territory_input": True},
            1.0,
            r"advice_imitation \(set for \['agent_0', 'agent_1'\]\) needs env_kwargs advice_input",
        ),
        ({"advice_input": True}, -0.5, "advice_imitation must be a finite number >= 0, got -0.5"),
        ({"advice_input": True}, float("nan"), "advice_imitation must be a finite number >= 0"),
    ],
)
def test_a_weight_it_cannot_apply_is_refused_by_name(env_kwargs: dict, weight: float, message: str) -> None:
    with pytest.raises(InputError, match=message):
        small_team(env_kwargs, advice_imitation=weight)


def test_the_weight_itself_is_checked() -> None:
    assert check_advice_weight("advice_imitation", 2) == 2.0
    with pytest.raises(InputError, match="got True"):
        check_advice_weight("advice_imitation", True)
