"""The callbacks every team learner carries: episode metrics in TensorBoard, and their order."""

from __future__ import annotations

import copy
import os
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from sb3_pm.agents.multiplexing.agent_vec_env import RolloutBarrier
from sb3_pm.errors import InputError


class EpisodeMetricsCallback(BaseCallback):
    """Logs the env's episode metrics (``avg_uncertainty``, ``max_neglect`` ...) as ``metrics/<name>``.

    The mean is over this learner's last ``window`` episodes, recorded at each rollout's end, next
    to SB3's ``rollout/ep_rew_mean``.
    """

    def __init__(self, window: int = 100, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.window = window
        self.history: dict[str, deque[float]] = {}

    def _on_step(self) -> bool:
        for info, done in zip(self.locals.get("infos", ()), self.locals.get("dones", ())):
            if done and "metrics" in info:
                for key, value in info["metrics"].items():
                    self.history.setdefault(key, deque(maxlen=self.window)).append(float(value))
        return True

    def _on_rollout_end(self) -> None:
        for key, values in self.history.items():
            if values:
                self.logger.record(f"metrics/{key}", float(np.mean(values)))


def learner_callbacks(model: BaseAlgorithm, callback: BaseCallback | None) -> CallbackList:
    """A team learner's callbacks, in order: an :class:`EpisodeMetricsCallback`, the caller's, the
    estimator fit (for a DCBF-PPO learner with an estimator, which would otherwise attach it
    itself, after everything else), and a :class:`RolloutBarrier` last, so the barrier sees each
    learner with its ``train()`` and estimator fit done."""
    callbacks = list(with_episode_metrics(callback).callbacks)
    estimator = None
    if getattr(model.policy, "estimator", None) is not None:
        from sb3_pm.callbacks import EstimatorCallback
        from sb3_pm.ppo_dcbf.ppo_dcbf import DCBFPPO, find_estimator_callback

        if isinstance(model, DCBFPPO):
            estimator = find_estimator_callback(callbacks)
            if estimator is None:
                estimator = EstimatorCallback()
                callbacks.append(estimator)
    callbacks.append(RolloutBarrier(estimator))
    return CallbackList(callbacks)


def with_episode_metrics(callback: BaseCallback | list[BaseCallback] | None) -> CallbackList:
    """A learner's callbacks: an :class:`EpisodeMetricsCallback` first, then the caller's (one, a
    list, or none)."""
    callbacks: list[BaseCallback] = [EpisodeMetricsCallback()]
    if isinstance(callback, list):
        callbacks += callback
    elif callback is not None:
        callbacks.append(callback)
    return CallbackList(callbacks)


#: The attributes by which SB3's callbacks name where they write (``CheckpointCallback.save_path``,
#: ``EvalCallback.best_model_save_path`` and ``log_path``).
PATH_ATTRIBUTES = ("save_path", "best_model_save_path", "log_path")

#: What ``IndependentPPO.learn(callback=...)`` takes: one callback per agent, in any of these forms.
CallbackArg = (
    BaseCallback
    | Sequence[BaseCallback | None]
    | Mapping[str, BaseCallback]
    | Callable[[str], BaseCallback]
    | None
)


def per_agent_callbacks(callback: CallbackArg, agents: Sequence[str]) -> list[BaseCallback | None]:
    """One callback (or None) per agent, in ``agents`` order, from a list, an ``{agent: callback}``
    dict, a factory ``agent_name -> callback``, or one callback object: the first agent gets it
    and every other agent a deep copy of it, as SB3 binds a callback to one model (each copy keeps
    its own counters, and an ``EvalCallback`` copy its own evaluations). Where SB3's callbacks name
    a folder they write to (:data:`PATH_ATTRIBUTES`), each agent's callback writes to its own
    subfolder, named after the agent: the learners run side by side, and would overwrite each
    other's files.

    :raises InputError: for a list of the wrong length.
    """
    if callback is None:
        return [None] * len(agents)
    if isinstance(callback, BaseCallback):
        callbacks = [callback] + [copy.deepcopy(callback) for _ in agents[1:]]
        for agent, each in zip(agents, callbacks):
            for name in PATH_ATTRIBUTES:
                value = getattr(each, name, None)
                if isinstance(value, (str, os.PathLike)):
                    setattr(each, name, os.path.join(value, agent))
        return callbacks
    if isinstance(callback, Mapping):
        return [callback.get(agent) for agent in agents]
    if callable(callback):
        return [callback(agent) for agent in agents]
    callbacks = list(callback)
    if len(callbacks) != len(agents):
        raise InputError(f"got {len(callbacks)} callbacks for {len(agents)} agents")
    return callbacks


def close_loggers(models: Iterable[BaseAlgorithm]) -> None:
    """Close each model's SB3 logger, if it was configured (``learn()`` configures it)."""
    for model in models:
        logger = getattr(model, "_logger", None)
        if logger is not None:
            logger.close()


__all__ = [
    "CallbackArg",
    "EpisodeMetricsCallback",
    "close_loggers",
    "learner_callbacks",
    "per_agent_callbacks",
    "with_episode_metrics",
]
