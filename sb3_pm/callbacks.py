"""Callbacks for sb3_pm learners.

:class:`EstimatorCallback` trains a :class:`~sb3_pm.policies.DCBFActorCriticPolicy`'s state
estimator (docs/METHOD.md "Estimator loss", paper eq. 3) on each rollout's own transitions, with the
estimator's own optimizer. :class:`~sb3_pm.ppo_dcbf.DCBFPPO` attaches it automatically, so a plain
``model.learn()`` needs no glue.

When the fit happens: the pairs are taken from the buffer at ``on_rollout_end`` but the estimator
is fitted only after PPO's ``train()`` on that same rollout (at the next ``on_rollout_start``, or
``on_training_end`` for the last rollout). ``û`` is an *input* of the actor, so changing the
estimator between collection and ``train()`` would change the policy that PPO's ratio compares
against the stored log-probabilities; fitting afterwards keeps the first-epoch ratio at exactly 1,
as PPO assumes. Every rollout is still used exactly once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np
import torch as th
from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback

from sb3_pm.policies.estimator import transition_pairs

if TYPE_CHECKING:
    from sb3_pm.policies.policy import DCBFActorCriticPolicy

class EstimatorCallback(BaseCallback):
    """Fit the policy's state estimator on each rollout's ``(M_{k-1}, M_k)`` pairs; log ``estimator/loss``.

    Hyperparameters (``estimator_epochs``, ``estimator_batch_size``) are read from the policy, so
    that they travel with its saved kwargs.

    :param verbose: verbosity level.
    """

    def __init__(self, verbose: int = 0) -> None:
        super().__init__(verbose)
        self._pending: tuple[np.ndarray, np.ndarray] | None = None
        #: the generator of the minibatch orders (``None``: torch's global one). A team learner
        #: that updates next to others is given its own, holding its random stream.
        self.generator: th.Generator | None = None
        #: Mean loss of the last fit's final epoch (``nan`` before the first fit).
        self.last_loss = float("nan")

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        buffer = cast(MaskableDictRolloutBuffer, self.model.rollout_buffer)  # type: ignore[attr-defined]
        pairs = transition_pairs(
            buffer.observations["nodes"],  # type: ignore[index, call-overload]
            buffer.episode_starts,
            np.asarray(self.model._last_obs["nodes"]),  # type: ignore[index, call-overload]
            np.asarray(self.model._last_episode_starts),
        )
        self._pending = pairs  # boolean indexing copied them: the next rollout cannot overwrite them

    def _on_rollout_start(self) -> None:
        self._fit_pending()

    def _on_training_end(self) -> None:
        self._fit_pending()

    def _fit_pending(self) -> None:
        if self._pending is not None:
            pairs, self._pending = self._pending, None
            self.fit(*pairs)

    def fit(self, previous: np.ndarray, current: np.ndarray) -> float:
        """Fit the estimator on pairs of maps ``(P, N, F)``; returns the last epoch's mean loss."""
        policy = cast("DCBFActorCriticPolicy", self.model.policy)
        estimator, optimizer = policy.estimator, policy.estimator_optimizer
        if estimator is None or optimizer is None or len(previous) == 0:
            return self.last_loss
        device = policy.device
        prev_t = th.as_tensor(previous, dtype=th.float32, device=device)
        curr_t = th.as_tensor(current, dtype=th.float32, device=device)
        batch_size = max(1, int(policy.estimator_batch_size))
        losses: list[float] = []
        for _ in range(int(policy.estimator_epochs)):
            losses = []
            if self.generator is None:
                order = th.randperm(len(prev_t), device=device)
            else:  # a learner's own (CPU) generator, in an update next to others
                order = th.randperm(len(prev_t), generator=self.generator).to(device)
            for start in range(0, len(order), batch_size):
                idx = order[start : start + batch_size]
                loss = estimator.loss(prev_t[idx], curr_t[idx])
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                losses.append(loss.item())
        # Leave no gradient behind: PPO clips the norm over all policy parameters.
        optimizer.zero_grad(set_to_none=True)
        self.last_loss = float(np.mean(losses))
        self.logger.record("estimator/loss", self.last_loss)
        self.logger.record("estimator/pairs", len(prev_t))
        return self.last_loss
