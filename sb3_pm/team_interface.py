"""The one team interface shared by baselines and learned teams.

It sits just above :mod:`sb3_pm.envs` and below everything that builds or drives a team
(baselines, learners, evaluation), so that each of them can depend on it without depending on the
others. It imports nothing from ``sb3_pm``.

The evaluation harness drives every team the same way::

    team.reset(env, seed=...)            # once per episode, after env.reset()
    actions = team.predict(observations, deterministic=True)

``deterministic`` is the harness's choice; when the caller leaves it open, a team's
``deploy_temperature`` decides (``None``: deterministic; a learned team may sample instead).

``observations`` maps agent names to that agent's own observation (a mental map by default).
A *decentralized* team must compute each agent's action from that agent's observation alone;
an *omniscient* team (``omniscient = True``) may also read the true state through
``env.unwrapped`` (``uncertainty``, ``positions``, ``graph``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

#: One agent's observation: the env's per-agent ``Dict`` (a mental map by default).
Observation = dict[str, Any]


class Team(ABC):
    """A policy for a whole team of agents.

    :cvar name: the name used in reports and on the command line.
    :cvar omniscient: True if the team reads the true state through the env.
    """

    name: str = "team"
    omniscient: bool = False
    #: How the team acts when the caller does not say (``evaluate(..., deterministic=None)``):
    #: ``None`` deterministically; a learned team may set a sampling temperature instead.
    deploy_temperature: float | None = None

    def acts_deterministically(self, deterministic: bool | None) -> bool:
        """``deterministic`` as given, or, for ``None``, the team's rule: deterministically unless
        it has a ``deploy_temperature``."""
        return self.deploy_temperature is None if deterministic is None else bool(deterministic)

    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start an episode on ``env`` (already reset). Seeds the team's own randomness."""
        self.env = env
        self.rng = np.random.default_rng(seed)

    @abstractmethod
    def predict(self, observations: dict[str, Observation], deterministic: bool = True) -> dict[str, int]:
        """One destination node per agent in ``observations``."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"


__all__ = ["Observation", "Team"]
