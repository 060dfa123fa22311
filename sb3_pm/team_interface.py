"""The one team interface shared by baselines and learned teams.

It sits just above :mod:`sb3_pm.envs` and below everything that builds or drives a team
(baselines, learners, evaluation), so that each of them can depend on it without depending on the
others. It imports nothing from ``sb3_pm`` at module level (``make_env`` imports the env lazily).

The evaluation harness drives every team the same way::

    env = team.make_env(graph, n_agents=..., max_cycles=...)   # the env the team acts in
    team.reset(env, seed=...)            # once per episode, after env.reset()
    actions = team.predict_dict(observations, deterministic=True)   # {agent: destination node}

``deterministic`` is the harness's choice; when the caller leaves it open, a team's
``deploy_temperature`` decides (``None``: deterministic; a learned team may sample instead).

:meth:`Team.predict_dict` is the method every team implements. :meth:`Team.predict` is SB3's
shape around it, for code written against an SB3 model: ``actions, state = team.predict(obs)``
returns the same ``{agent: action}`` dict and hands ``state`` back unchanged (no team is
recurrent).

``observations`` maps agent names to that agent's own observation (a mental map by default).
A *decentralized* team must compute each agent's action from that agent's observation alone;
an *omniscient* team (``omniscient = True``) may also read the true state through
``env.unwrapped`` (``uncertainty``, ``positions``, ``graph``).

Everything the harness and the commands ask of a team is declared here with the answer of a team
that has no trained policies (a baseline); trained teams override it
(:class:`sb3_pm.agents.deployment.rule.DeploymentRule`), so nothing probes a team with
``getattr``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, final

import numpy as np

#: One agent's observation: the env's per-agent ``Dict`` (a mental map by default).
Observation = dict[str, Any]

#: Env arguments that are the caller's choice for every team, never a team's own setting.
CALLER_ENV_KEYS = ("graph", "n_agents", "max_cycles", "render_mode")


class Team(ABC):
    """A policy for a whole team of agents.

    :cvar name: the name used in reports and on the command line.
    :cvar omniscient: True if the team reads the true state through the env.
    :cvar learned: True for a trained team (it has policies, a DCBF filter and an acting rule).
    :cvar resizable: True if the team can act with another number of agents than it was built for.
    """

    name: str = "team"
    omniscient: bool = False
    learned: bool = False
    resizable: bool = True
    #: The team size it was trained for, or ``None``: any size (a baseline).
    n_agents: int | None = None
    #: How the team acts when the caller does not say (``evaluate(..., deterministic=None)``):
    #: ``None`` deterministically; a learned team may set a sampling temperature instead.
    deploy_temperature: float | None = None
    #: ``True`` while the team waits for a neglect bound calibrated on the graph it acts on
    #: (a trained team whose ``deploy_filter`` is ``auto``); the harness calibrates it first.
    site_bound_pending: bool = False

    def acts_deterministically(self, deterministic: bool | None) -> bool:
        """``deterministic`` as given, or, for ``None``, the team's rule: deterministically unless
        it has a ``deploy_temperature``."""
        return self.deploy_temperature is None if deterministic is None else bool(deterministic)

    def env_settings(self) -> dict[str, Any]:
        """The environment settings the team acts in (observation radius, map mode, ...): a trained
        team's training settings without :data:`CALLER_ENV_KEYS`; ``{}`` for a baseline."""
        return {}

    def default_graph(self) -> Any:
        """The graph the team acts on when the caller names none, or ``None`` (a baseline)."""
        return None

    def make_env(
        self, graph: Any = None, n_agents: int | None = None, max_cycles: int = 500, **env_kwargs: Any
    ) -> Any:
        """The PettingZoo parallel env this team acts in: ``graph`` (default: the team's own), the
        team's size (default: its own, else 4) and its :meth:`env_settings`, overridden by
        ``env_kwargs`` (``render_mode``, failures, ...).

        :raises InputError: no graph given for a team that has none of its own.
        """
        from sb3_pm.envs import persistent_monitoring_v0
        from sb3_pm.errors import InputError
        from sb3_pm.graphs import resolve_graph

        graph = self.default_graph() if graph is None else graph
        if graph is None:
            raise InputError(f"{self.name!r} has no graph of its own: pass one to make_env(graph)")
        return persistent_monitoring_v0.parallel_env(
            graph=resolve_graph(graph),
            n_agents=(self.n_agents or 4) if n_agents is None else n_agents,
            max_cycles=max_cycles,
            **{**self.env_settings(), **env_kwargs},
        )

    def acting_record(self, deterministic: bool) -> dict[str, Any]:
        """What the team acted under, for an evaluation's record (``temperature``,
        ``neglect_bound``, ``neglect_scope``, ``leave_cleared``, ``pass_held``); ``{}`` for a
        baseline."""
        return {}

    def acting_filter(self) -> dict[str, Any] | None:
        """The DCBF neglect bound the team acts under now, or ``None`` (a baseline has no filter)."""
        return None

    def filter_activity(self) -> dict[str, int] | None:
        """Masks computed and forced by the neglect bound so far, or ``None`` without a filter."""
        return None

    def reset(self, env: Any, seed: int | None = None) -> None:
        """Start an episode on ``env`` (already reset). Seeds the team's own randomness."""
        self.env = env
        self.rng = np.random.default_rng(seed)

    @abstractmethod
    def predict_dict(
        self, observations: dict[str, Observation], deterministic: bool = True
    ) -> dict[str, int]:
        """One destination node per agent in ``observations``: the method every team implements."""

    @final
    def predict(
        self,
        observation: dict[str, Observation],
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool | None = None,
    ) -> tuple[dict[str, int], Any]:
        """SB3's ``predict``: ``(actions, state)``, where ``actions`` is :meth:`predict_dict`'s
        ``{agent: destination node}`` for the team's ``{agent: observation}``.

        :param observation: ``{agent: observation}``, PettingZoo's shape.
        :param state: handed back unchanged (no team keeps a recurrent state).
        :param episode_start: accepted for SB3's signature and not read.
        :param deterministic: ``None`` (the default) follows the team's rule
            (:meth:`acts_deterministically`: argmax unless it has a ``deploy_temperature``).
        """
        actions = self.predict_dict(observation, deterministic=self.acts_deterministically(deterministic))
        return actions, state

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"


def without_caller_keys(env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` less :data:`CALLER_ENV_KEYS`."""
    return {key: value for key, value in env_kwargs.items() if key not in CALLER_ENV_KEYS}


__all__ = ["CALLER_ENV_KEYS", "Observation", "Team", "without_caller_keys"]
