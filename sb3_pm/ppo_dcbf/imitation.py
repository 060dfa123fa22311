"""Imitation of the env's advice after each PPO update (``advice_imitation``).

With ``advice_input`` the env flags, on each agent's map, the node the territory rule would move
to next (docs/CONFIG.md, "Advice prior"). ``advice_prior`` adds a fixed number to that
node's logit; ``advice_imitation`` also *teaches* the actor to pick it: after PPO's epochs on a
rollout, as many passes (``n_epochs``) over the same rollout take a gradient step per minibatch on

    advice_imitation * mean(-log pi(advice | map, stored mask))

over the rows where the env advised a move that the stored DCBF mask allows (the others carry no
target). It is a cross-entropy to the rule's move, i.e. the KL divergence from the rule's
deterministic choice to the policy, so the learner starts and stays near the rule and leaves it
where PPO's advantages outweigh the pull.

The pass runs after the update, not inside its epochs: PPO's ratio then compares the policy it
sampled from with the one it updates, as PPO assumes, and the pass draws nothing at random (the
minibatches in rollout order), so updates that run side by side stay the same bit for bit.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch as th

if TYPE_CHECKING:
    from sb3_pm.ppo_dcbf.ppo_dcbf import DCBFPPO


def advised_actions(nodes: th.Tensor, masks: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The advised node of each map and whether it counts.

    :param nodes: maps ``(B, N, F)`` whose last column is the env's advice (one 1 or none).
    :param masks: the stored DCBF masks ``(B, N)``.
    :returns: ``actions`` ``(B,)`` (the advised node, 0 where none) and ``rows`` ``(B,)`` bool:
        advised, and allowed by the mask.
    """
    advice = nodes[..., -1]
    actions = advice.argmax(dim=-1)
    advised = advice.amax(dim=-1) > 0.5
    allowed = masks.reshape(advice.shape).bool().gather(1, actions[:, None])[:, 0]
    return actions, advised & allowed


def imitation_pass(model: DCBFPPO, epochs: int | None = None) -> tuple[float, float]:
    """Passes of advice imitation over ``model``'s rollout buffer, after its PPO update.

    The minibatches are ``model.batch_size`` rows of the flattened rollout, in order; each counted
    row weighs the same. Gradients are clipped to ``max_grad_norm`` as in PPO's own steps.

    :param epochs: passes over the rollout; ``None``: ``model.n_epochs``, as many as PPO's.
    :returns: the mean imitation loss ``-log pi(advice)`` and the mean probability of the advised
        node, over the counted rows of the last pass (``nan``, ``nan`` without any).
    """
    policy = model.policy
    buffer = model.rollout_buffer
    total = buffer.buffer_size * buffer.n_envs
    if not buffer.generator_ready:  # train() flattens the rollout; a pass on its own does it here
        buffer._flatten_once()  # type: ignore[attr-defined]
    policy.set_training_mode(True)
    losses: list[float] = []
    probabilities: list[th.Tensor] = []
    for _ in range(model.n_epochs if epochs is None else epochs):
        losses, probabilities = _one_pass(model, total)
    policy.optimizer.zero_grad(set_to_none=True)  # leave no gradient behind for the next update
    policy.set_training_mode(False)
    if not losses:
        return float("nan"), float("nan")
    return float(np.mean(losses)), float(th.cat(probabilities).mean())


def _one_pass(model: DCBFPPO, total: int) -> tuple[list[float], list[th.Tensor]]:
    """One pass over the ``total`` rows: each minibatch's loss, and the advised node's
    probability on its counted rows."""
    policy = model.policy
    buffer = model.rollout_buffer
    losses: list[float] = []
    probabilities: list[th.Tensor] = []
    for start in range(0, total, model.batch_size):
        samples = buffer._get_samples(np.arange(start, min(start + model.batch_size, total)))
        masks = th.as_tensor(samples.action_masks, device=policy.device)
        actions, rows = advised_actions(samples.observations["nodes"], masks)
        if not bool(rows.any()):
            continue
        _, log_prob, _ = policy.evaluate_actions(samples.observations, actions, action_masks=masks)
        loss = -log_prob[rows].mean()
        policy.optimizer.zero_grad(set_to_none=True)
        (model.advice_imitation * loss).backward()
        th.nn.utils.clip_grad_norm_(policy.parameters(), model.max_grad_norm)
        policy.optimizer.step()
        losses.append(float(loss.detach()))
        probabilities.append(log_prob.detach()[rows].exp())
    return losses, probabilities
