"""A SuperSuit vector env over our PettingZoo env, fixed up for SB3 and sb3-contrib."""

from __future__ import annotations

from typing import Any

import numpy as np
import supersuit
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper

from sb3_pm.envs import persistent_monitoring_v0

TRUNCATED_KEY = "TimeLimit.truncated"


class MaskedVecEnv(SB3VecEnvWrapper):
    """SuperSuit's SB3 vector env with three fixes.

    - **Truncation.** SuperSuit folds terminations and truncations into one ``done`` and drops the
      difference. SB3 bootstraps a timed-out step only when its info says
      ``TimeLimit.truncated``; without it every timeout of this (never-terminating) task would be
      learned as a true end. We set the flag from SuperSuit's own truncation array.
    - **Seeding.** SB3 calls ``env.seed(seed)`` when a model has a seed, which SuperSuit's
      concatenated env cannot take; the seed is kept and passed to the next ``reset``.
    - **Masks.** sb3-contrib's ``MaskablePPO`` asks ``env_method("action_masks")``; the answer is
      the latest observations' ``action_mask``.
    """

    def __init__(self, venv: Any) -> None:
        super().__init__(venv)
        self._pending_seed: int | None = None
        self._masks = np.ones((self.num_envs, self.action_space.n), dtype=bool)

    def seed(self, seed: int | None = None) -> list[int | None]:
        self._pending_seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def reset(self, seed: int | None = None, options: dict | None = None) -> Any:
        seed = self._pending_seed if seed is None else seed
        self._pending_seed = None
        observations, self.reset_infos = self.venv.reset(seed=seed, options=options)
        self._masks = observations["action_mask"].astype(bool)
        return observations

    def step_wait(self) -> Any:
        observations, rewards, terminations, truncations, infos = self.venv.step_wait()
        dones = np.logical_or(terminations, truncations)
        for i in np.flatnonzero(np.logical_and(truncations, np.logical_not(terminations))):
            infos[i][TRUNCATED_KEY] = True
        self._masks = observations["action_mask"].astype(bool)  # after auto-reset: the next step's masks
        return observations, rewards, dones, infos

    def has_attr(self, attr_name: str) -> bool:
        # SuperSuit's concatenated env has no has_attr; masks are the one capability we add.
        return attr_name == "action_masks" or hasattr(self.venv, attr_name)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any) -> list[Any]:
        if method_name == "action_masks":
            rows = range(self.num_envs) if indices is None else np.atleast_1d(indices)
            return [self._masks[i] for i in rows]
        return self.venv.env_method(method_name, *args, indices=indices, **kwargs)


def make_parameter_sharing_vec_env(
    graph: Any = "paper-50",
    n_envs: int = 1,
    n_agents: int = 4,
    env_kwargs: dict[str, Any] | None = None,
) -> VecEnv:
    """One SB3 ``VecEnv`` with ``n_envs * n_agents`` entries, for a single shared model.

    Layers: SuperSuit's ``pettingzoo_env_to_vec_env_v1`` and ``concat_vec_envs_v1`` (Gymnasium
    flavour), :class:`MaskedVecEnv` (the SB3 adapter, with the fixes above) and ``VecMonitor``
    (episode statistics for the logger). Seed it through the model's ``seed=`` or ``env.seed()``.
    """
    env = persistent_monitoring_v0.parallel_env(graph=graph, n_agents=n_agents, **(env_kwargs or {}))
    venv = supersuit.pettingzoo_env_to_vec_env_v1(env)
    venv = supersuit.concat_vec_envs_v1(venv, n_envs, num_cpus=0, base_class="gymnasium")
    return VecMonitor(MaskedVecEnv(venv))
