"""The ``VecEnv`` each learner of a team sees, and the callback that makes the learners meet.

An :class:`AgentVecEnv` is a view onto a
:class:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer`: its ``step_wait`` submits the
agent's actions and blocks until every agent has submitted (see the
multiplexer's module docstring). :class:`RolloutBarrier` makes every learner wait at the start of
each rollout until all are there.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

if TYPE_CHECKING:
    from sb3_pm.agents.multiplexing.multiplexer import ParallelEnvMultiplexer


class AgentVecEnv(VecEnv):
    """The ``VecEnv`` seen by one agent's learner; a view onto a :class:`ParallelEnvMultiplexer`.

    ``env_method("action_masks")`` returns the agent's ``action_mask`` from its last observation
    (what sb3-contrib's ``MaskablePPO`` asks for). Other attributes and methods are forwarded to the
    env copies, which are shared by all agents.
    """

    def __init__(self, hub: ParallelEnvMultiplexer, index: int) -> None:
        self.hub = hub
        self.index = index
        self.agent = hub.agents[index]
        self._actions: np.ndarray | None = None
        super().__init__(hub.n_envs, hub.observation_spaces[self.agent], hub.action_spaces[self.agent])

    def reset(self) -> VecEnvObs:
        obs, infos = self.hub._submit(self.index, "reset", None)
        self.reset_infos = infos
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        actions, self._actions = self._actions, None
        return self.hub._submit(self.index, "step", actions)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Ask for the next joint reset to use ``seed`` (the lowest-indexed agent's request wins,
        unless the multiplexer was seeded directly with :meth:`ParallelEnvMultiplexer.seed`)."""
        with self.hub._cond:
            self.hub._agent_seeds[self.index] = seed
        return [None if seed is None else seed + k for k in range(self.num_envs)]

    def action_masks(self) -> np.ndarray:
        """``(n_envs, N)`` bool masks from the agent's last observation."""
        return np.stack(
            [np.asarray(obs["action_mask"], dtype=bool) for obs in self.hub._last_obs[self.index]]
        )

    def close(self) -> None:
        # The env copies are shared: closing one agent's view must not close them for the others.
        pass

    def has_attr(self, attr_name: str) -> bool:
        if attr_name == "action_masks":
            return True
        return super().has_attr(attr_name)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        if attr_name == "action_masks":
            masks = self.action_masks()
            return [lambda m=masks[k]: m for k in self._get_indices(indices)]
        return [getattr(self.hub.envs[k], attr_name) for k in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for k in self._get_indices(indices):
            setattr(self.hub.envs[k], attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        if method_name == "action_masks":
            masks = self.action_masks()
            return [masks[k] for k in self._get_indices(indices)]
        return [
            getattr(self.hub.envs[k], method_name)(*method_args, **method_kwargs)
            for k in self._get_indices(indices)
        ]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        # The copies are PettingZoo envs, never gymnasium wrappers (so SB3 sees no Monitor either).
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [env.render() if env.render_mode == "rgb_array" else None for env in self.hub.envs]


class RolloutBarrier(BaseCallback):
    """Makes a team learner wait at the start of each rollout until every learner is there.

    It must be the learner's last callback, so the barrier comes after everything the learner does
    between two rollouts (``train()``, the estimator fit). Its env must be an :class:`AgentVecEnv`.
    At each rollout's end it opens the learner's update phase
    (:meth:`~sb3_pm.agents.multiplexing.multiplexer.ParallelEnvMultiplexer.enter_update`); when the phase runs
    side by side with the others, it first waits for one of the team's update slots
    (:mod:`sb3_pm.agents.multiplexing.update_slots`), which it gives back at the barrier, and ``estimator``
    (the learner's estimator callback, if any) draws from the learner's own generator until the barrier.

    :param estimator: the learner's :class:`~sb3_pm.callbacks.EstimatorCallback`, or ``None``.
    """

    def __init__(self, estimator: Any = None, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.estimator = estimator

    def _on_step(self) -> bool:
        return True

    def _agent_env(self) -> AgentVecEnv:
        env = self.training_env
        if not isinstance(env, AgentVecEnv):
            raise TypeError(f"RolloutBarrier needs an AgentVecEnv, got {type(env).__name__}")
        return env

    def _on_rollout_end(self) -> None:
        env = self._agent_env()
        buffer: Any = getattr(self.model, "rollout_buffer", None)
        epochs = getattr(self.model, "n_epochs", None)
        draw = None
        # Side by side only where every draw of the update can be made now: the minibatch orders
        # (and no early stop on target_kl, which would leave some of them undrawn in a lone update).
        if (
            hasattr(buffer, "draw_orders")
            and epochs is not None
            and getattr(self.model, "target_kl", None) is None
        ):
            draw = lambda: buffer.draw_orders(int(epochs))  # noqa: E731
        generator = env.hub.enter_update(env.index, draw)
        if generator is not None:  # side by side: wait for an update slot (a free core)
            env.hub.take_update_slot(env.index)
        if self.estimator is not None:
            self.estimator.generator = generator

    def _on_rollout_start(self) -> None:
        env = self._agent_env()
        env.hub.give_back_update_slot(env.index)
        env.hub.sync(env.index)
        if self.estimator is not None:
            self.estimator.generator = None


__all__ = ["AgentVecEnv", "RolloutBarrier"]
