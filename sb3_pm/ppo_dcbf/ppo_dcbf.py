"""PPO whose action masks come from the policy's DCBF filter (docs/METHOD.md "DCBF safety filter").

:class:`DCBFPPO` is sb3-contrib's :class:`~sb3_contrib.MaskablePPO` with two changes:

* ``collect_rollouts`` takes each action's mask from the policy
  (:meth:`~sb3_pm.policies.DCBFActorCriticPolicy.rollout_heads`, or the same from
  :attr:`DCBFPPO.rollout_heads_source`, then the draw of
  :meth:`~sb3_pm.policies.DCBFActorCriticPolicy.sample_masked`), not from the env's
  ``action_masks()``, and stores exactly that mask in the :class:`MaskableDictRolloutBuffer`.
  MaskablePPO's ``train()`` then feeds the stored masks to ``evaluate_actions`` unchanged, so the
  ratio compares the same distribution support that was sampled from, even after the estimator
  (which drives the filter) has changed. The env therefore needs no ``action_masks()`` method: the
  reachable set is read from the observation's ``action_mask`` entry.
* its rollout buffer is an :class:`~sb3_pm.ppo_dcbf.buffers.OrderedRolloutBuffer`, which can draw
  its minibatch orders before the update phase (so team learners can update side by side);
* with ``update_device``, ``train()`` runs on another device than the rollouts
  (:mod:`sb3_pm.ppo_dcbf.update_device`: rollouts on the CPU, updates on a GPU);
* with ``advice_imitation``, ``train()`` ends with a pass that teaches the actor the env's advice
  (:mod:`sb3_pm.ppo_dcbf.imitation`);
* ``learn`` attaches :class:`~sb3_pm.callbacks.EstimatorCallback` when the policy has an
  estimator, and ``_get_torch_save_params`` adds the estimator's optimizer so that save/load
  round-trips it (the estimator's weights are part of the policy's state dict).

Usage::

    from sb3_pm.ppo_dcbf import DCBFPPO
    model = DCBFPPO("DCBFPolicy", env, policy_kwargs=dict(avoid_collisions=True), seed=0)
    model.learn(10_000)
    action, _ = model.predict(obs, deterministic=True)  # DCBF-filtered
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import MaskablePPO
from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv

from sb3_pm.callbacks import EstimatorCallback
from sb3_pm.errors import InputError
from sb3_pm.machine import release_freed_memory
from sb3_pm.policies.policy import DCBFActorCriticPolicy
from sb3_pm.policies.settings import check_advice_weight
from sb3_pm.ppo_dcbf.buffers import OrderedRolloutBuffer
from sb3_pm.ppo_dcbf.imitation import imitation_pass
from sb3_pm.ppo_dcbf.policies import DCBFPolicy
from sb3_pm.ppo_dcbf.update_device import check_update_device, on_update_device

SelfDCBFPPO = TypeVar("SelfDCBFPPO", bound="DCBFPPO")


def find_estimator_callback(callback: MaybeCallback) -> EstimatorCallback | None:
    """The :class:`~sb3_pm.callbacks.EstimatorCallback` in ``callback`` (a callback, a list or a
    ``CallbackList``, nested), or None."""
    if isinstance(callback, EstimatorCallback):
        return callback
    children = callback.callbacks if isinstance(callback, CallbackList) else callback
    if isinstance(children, list):
        return next((found for c in children if (found := find_estimator_callback(c)) is not None), None)
    return None


class DCBFPPO(MaskablePPO):
    """PPO (clip) with DCBF-filtered masked actions and a self-trained state estimator.

    Takes every :class:`~sb3_contrib.MaskablePPO` argument, plus:

    :param update_device: torch device of the update phase (``train()``) alone, e.g. ``"cuda"``
        for a learner whose ``device`` is the CPU; ``None`` (default) updates on ``device``. Not
        saved with the model (like ``device``): set it again after loading.
    :param advice_imitation: the weight of the advice-imitation pass after each update
        (:mod:`sb3_pm.ppo_dcbf.imitation`; it needs the env's ``advice_input``); ``0`` (default):
        no pass.

    Policy options (ablation flags and the filter's settings) are policy kwargs, see
    :class:`~sb3_pm.policies.DCBFActorCriticPolicy`.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"DCBFPolicy": DCBFPolicy}
    policy: DCBFActorCriticPolicy  # type: ignore[assignment]

    def __init__(
        self,
        *args: Any,
        update_device: str | th.device | None = None,
        advice_imitation: float = 0.0,
        **kwargs: Any,
    ) -> None:
        self.update_device = check_update_device(update_device)
        self.advice_imitation = check_advice_weight("advice_imitation", advice_imitation)
        #: where a rollout step's logits, values and masks come from instead of this learner's own
        #: forward pass (:meth:`collect_rollouts`): a callable given the learner's last observation
        #: that returns ``(logits, values, masks)`` equal to ``policy.rollout_heads`` on it (and
        #: counts rule 8's decisions in the policy's ``filter_counts`` as that call does), or
        #: ``None`` to compute them here. A team sets it to batch its learners' passes; never saved.
        self.rollout_heads_source: Callable[[Any], tuple[th.Tensor, th.Tensor, th.Tensor] | None] | None = (
            None
        )
        super().__init__(*args, **kwargs)

    def train(self) -> None:
        """PPO's update, on :attr:`update_device` when one is set; what it freed goes back to the
        system (:func:`~sb3_pm.machine.release_freed_memory`), since each learner updates in a
        thread of its own and glibc would keep every thread's freed activations."""
        try:
            with on_update_device(self, self.update_device):
                super().train()
                if self.advice_imitation > 0:
                    loss, probability = imitation_pass(self)
                    self.logger.record("train/imitation_loss", loss)
                    self.logger.record("train/advice_probability", probability)
        finally:
            release_freed_memory()

    def _setup_model(self) -> None:
        if self.rollout_buffer_class in (None, MaskableDictRolloutBuffer):  # also a zip saved before
            self.rollout_buffer_class = OrderedRolloutBuffer
        super()._setup_model()
        if not isinstance(self.policy, DCBFActorCriticPolicy):
            raise InputError(f"DCBFPPO needs a DCBFActorCriticPolicy, got {type(self.policy).__name__}")
        space = self.observation_space  # a Dict of mental-map entries (DCBFActorCriticPolicy checked it)
        check_advice_weight("advice_imitation", self.advice_imitation, space, use="teaches")  # type: ignore[arg-type]

    def _excluded_save_params(self) -> list[str]:
        # update_device is this machine's, as device is: a model saved beside a GPU loads without one
        return [*super()._excluded_save_params(), "rollout_heads_source", "update_device"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        if getattr(self.policy, "estimator_optimizer", None) is not None:
            state_dicts = [*state_dicts, "policy.estimator_optimizer"]
        return state_dicts, variables

    def collect_rollouts(  # type: ignore[override]
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
        use_masking: bool = True,
    ) -> bool:
        """Fill ``rollout_buffer`` with ``n_rollout_steps`` steps per env, each stored with its DCBF mask.

        ``use_masking`` is accepted for MaskablePPO compatibility and ignored: the DCBF mask is
        part of the policy and is always applied.
        """
        if not isinstance(rollout_buffer, MaskableDictRolloutBuffer):
            raise TypeError("DCBFPPO needs a MaskableDictRolloutBuffer (mental-map observations are a Dict)")
        assert self._last_obs is not None, "No previous observation was provided"
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        discrete = isinstance(self.action_space, spaces.Discrete)
        new_obs: Any = self._last_obs
        dones = self._last_episode_starts

        for _ in range(n_rollout_steps):
            # inference_mode, not no_grad: nothing computed here is ever differentiated (the buffer
            # stores NumPy copies), and it skips autograd's version counting on every op.
            with th.inference_mode():
                source = self.rollout_heads_source
                heads = None if source is None else source(self._last_obs)
                if heads is None:
                    heads = self.policy.rollout_heads(obs_as_tensor(self._last_obs, self.device))  # type: ignore[arg-type]
                logits, values, masks_t = heads
                # the draw from torch's generator, in this learner's turn, as forward_with_masks makes it
                actions_t, log_probs = self.policy.sample_masked(logits, masks_t)
            actions = actions_t.cpu().numpy()
            masks = masks_t.cpu().numpy()
            new_obs, rewards, dones, infos = env.step(actions)
            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)

            # A time-limit end is not a real end: bootstrap with the value of the final state.
            for idx in np.flatnonzero(dones):
                terminal = infos[idx].get("terminal_observation")
                if terminal is not None and infos[idx].get("TimeLimit.truncated", False):
                    terminal_obs = self.policy.obs_to_tensor(terminal)[0]
                    with th.inference_mode():
                        rewards[idx] += self.gamma * self.policy.predict_values(terminal_obs)[0].item()

            rollout_buffer.add(
                self._last_obs,  # type: ignore[arg-type]
                actions.reshape(-1, 1) if discrete else actions,
                rewards,
                self._last_episode_starts,  # type: ignore[arg-type]
                values,
                log_probs,
                action_masks=masks,  # the very mask sampled from; train() reuses it unchanged
            )
            self._last_obs = new_obs
            self._last_episode_starts = dones

        assert dones is not None
        with th.inference_mode():
            last_values = self.policy.predict_values(obs_as_tensor(new_obs, self.device))  # type: ignore[arg-type]
        rollout_buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)
        callback.on_rollout_end()
        return True

    def learn(  # type: ignore[override]
        self: SelfDCBFPPO,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "DCBFPPO",
        reset_num_timesteps: bool = True,
        use_masking: bool = True,
        progress_bar: bool = False,
    ) -> SelfDCBFPPO:
        """MaskablePPO's ``learn``, with the estimator callback attached when the policy has an estimator."""
        if self.policy.estimator is not None and find_estimator_callback(callback) is None:
            estimator_callback = EstimatorCallback()
            if callback is None:
                callback = estimator_callback
            elif isinstance(callback, list):
                callback = [*callback, estimator_callback]
            elif isinstance(callback, BaseCallback):
                callback = CallbackList([callback, estimator_callback])
            else:  # a plain function, as SB3 accepts
                callback = CallbackList([ConvertCallback(callback), estimator_callback])
        return super().learn(
            total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            use_masking=use_masking,
            progress_bar=progress_bar,
        )
