"""A single-agent Gymnasium view of persistent monitoring: one learner, fixed teammates.

:class:`SingleAgentMonitoringEnv` wraps :class:`~sb3_pm.envs.PersistentMonitoringEnv` with mental-map
observations. One agent (default ``agent_0``) is controlled through the Gymnasium API; the others
are driven by a fixed :class:`~sb3_pm.team_interface.Team`, or, with ``teammates=None``, move
uniformly at random within their own reachable sets. It is the test bed of the DCBF policy and the
basis of a Gymnasium registration; training a whole team of learners goes through the multiplexer
in :mod:`sb3_pm.agents` instead.

Spaces are the learner's own (:mod:`sb3_pm.envs.persistent_monitoring`): a ``Dict`` mental map
and ``Discrete(N)`` actions. ``action_masks()`` returns the learner's reachable set as bool (for
sb3-contrib's MaskablePPO). Episodes end by truncation after ``max_cycles`` steps; the last
step's ``info`` holds the env's ``"metrics"``.

Seeding: ``reset(seed=s)`` reseeds the env and the teammates' randomness (derived from ``s``) and
starts a new agent lifetime: the known adjacency (``graph_knowledge="discovered"``) and the
``change`` reward's history of past episodes are cleared, so that the same seed always gives the
same episode. ``reset()`` without a seed continues the lifetime: edges discovered and episode
totals from earlier episodes are kept, as docs/METHOD.md prescribes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from sb3_pm.envs.persistent_monitoring import PersistentMonitoringEnv
from sb3_pm.errors import InputError


class Teammates(Protocol):
    """The two methods of :class:`~sb3_pm.team_interface.Team` this env calls on its teammates.

    Every ``Team`` has them. The env names this protocol instead of importing ``Team`` because the
    team interface is the layer above the environments.
    """

    def reset(self, env: Any, seed: int | None = None) -> None: ...

    def predict_dict(
        self, observations: dict[str, dict[str, Any]], deterministic: bool = True
    ) -> Mapping[str, Any]: ...


class SingleAgentMonitoringEnv(gym.Env):
    """One learning agent among fixed teammates.

    :param graph: a preset name, a GraphML path or a :class:`~sb3_pm.graphs.GraphSpec`.
    :param agent: the learner's name, ``agent_i``.
    :param teammates: the team driving every other agent (``None``: uniform random moves).
    :param env_kwargs: further :class:`~sb3_pm.envs.PersistentMonitoringEnv` arguments
        (``n_agents``, ``max_cycles``, ``reward``, ...); ``observation`` must stay ``"map"``.
        ``illegal_action`` defaults to ``"stay"`` here (not ``"raise"``): a Gymnasium env must accept
        any element of its action space (``action_space.sample()``, SB3's ``check_env``); the
        illegal request is still reported in ``info["illegal_action"]``, and masked learners
        never make one.
    """

    metadata = {"render_modes": ["human", "rgb_array", "ansi"], "render_fps": 4}

    def __init__(
        self,
        graph: Any = "paper-50",
        agent: str = "agent_0",
        teammates: Teammates | None = None,
        **env_kwargs: Any,
    ) -> None:
        super().__init__()
        if env_kwargs.get("observation", "map") != "map":
            raise InputError("SingleAgentMonitoringEnv needs observation='map'")
        env_kwargs.setdefault("illegal_action", "stay")
        self.env = PersistentMonitoringEnv(graph=graph, **env_kwargs)
        if agent not in self.env.possible_agents:
            raise InputError(f"agent must be one of {self.env.possible_agents}, got {agent!r}")
        self.agent = agent
        self.teammate_names = [a for a in self.env.possible_agents if a != agent]
        self.teammates = teammates
        self.observation_space = self.env.observation_space(agent)
        self.action_space = self.env.action_space(agent)
        self.render_mode = self.env.render_mode
        self._observations: dict[str, dict[str, Any]] = {}
        self._teammate_rng = np.random.default_rng()

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict]:
        super().reset(seed=seed)
        if seed is not None:
            # A seeded reset must give the same episode whatever ran before: start a new lifetime
            # (the wrapped env otherwise keeps discovered edges and reward history across resets).
            options = {**(options or {}), "new_lifetime": True}
        # Teammates' randomness comes from gymnasium's np_random, itself seeded by ``seed``.
        team_seed = int(self.np_random.integers(2**31 - 1))
        self._teammate_rng = np.random.default_rng(team_seed)
        self._observations, infos = self.env.reset(seed=seed, options=options)
        if self.teammates is not None:
            self.teammates.reset(self.env, seed=team_seed)
        return self._learner_observation(), infos[self.agent]

    def _teammate_actions(self) -> dict[str, int]:
        observations = {a: self._observations[a] for a in self.teammate_names}
        if self.teammates is not None:
            # Fixed teammates are part of this env's dynamics: their most likely actions, whatever a
            # learned team's deploy_temperature says, so the env depends on its seed alone.
            actions = self.teammates.predict_dict(observations, deterministic=True)
            return {a: int(v) for a, v in actions.items()}
        return {
            a: int(self._teammate_rng.choice(np.flatnonzero(obs["action_mask"])))
            for a, obs in observations.items()
        }

    def step(self, action: Any) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        actions = self._teammate_actions()
        actions[self.agent] = int(action)
        self._observations, rewards, terminations, truncations, infos = self.env.step(actions)
        info = dict(infos[self.agent])
        return (
            self._learner_observation(),
            rewards[self.agent],
            terminations[self.agent],
            truncations[self.agent],
            info,
        )

    def _learner_observation(self) -> dict[str, Any]:
        """The learner's observation with its own copy of the known adjacency.

        The parallel env hands out one read-only adjacency array until the map gains an edge (a
        zero-copy fast path for the team). A Gymnasium env should return new data on every call,
        so this single-agent view copies it (in the edges layout, the edge mask; the edge list is the
        graph's, fixed and read-only).
        """
        observation = dict(self._observations[self.agent])
        key = "adjacency" if "adjacency" in observation else "edge_mask"
        observation[key] = np.array(observation[key], copy=True)
        return observation

    def action_masks(self) -> np.ndarray:
        """The learner's reachable set, ``(N,)`` bool."""
        return np.asarray(self._observations[self.agent]["action_mask"], dtype=bool)

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()
