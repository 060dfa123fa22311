"""The monitoring env with one flat vector per agent: the view that generic MARL libraries train on.

Libraries such as BenchMARL (through TorchRL's PettingZoo wrapper) feed each agent's observation
to an MLP and read the action mask from a fixed place. :class:`FlatMonitoringEnv` wraps
:func:`sb3_pm.envs.persistent_monitoring_v0.parallel_env` (``observation="map"``) so that

- each agent's observation is one ``float32`` vector in ``[0, 1]`` (:class:`Flattener`): the
  mental map's node features divided by their largest values (``u / u_max``,
  ``age / max_cycles``, the 0/1 flags), the position one-hot, ``dwell / max_cycles`` and, unless
  left out, the known adjacency;
- the reachable-set mask moves from the observation to ``infos[agent]["action_mask"]``, where
  TorchRL's wrapper finds it and BenchMARL's masked categorical policies use it;
- every possible agent reports every step. A failed agent (the env's ``failures`` and
  ``failure_rate``) leaves :attr:`FlatMonitoringEnv.agents`, which is what TorchRL's alive mask
  (``use_mask=True``) reads, and from then on reports a zero observation, reward 0 and
  ``terminated``; an action given for it is dropped.

The wrapped env's own infos (``metrics`` at the end of an episode, ``illegal_action``,
``failed``) pass through beside the mask.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo.utils.env import ParallelEnv

from sb3_pm.envs import persistent_monitoring_v0
from sb3_pm.errors import InputError


class Flattener:
    """Turns one agent's mental-map ``Dict`` observation into the flat vector of
    :class:`FlatMonitoringEnv` (see the module docstring for its layout).

    :param observation_space: the wrapped env's per-agent ``Dict`` space (``observation="map"``).
    :param adjacency: include the known adjacency (``N * N`` entries).
    """

    def __init__(self, observation_space: spaces.Dict, adjacency: bool) -> None:
        if not isinstance(observation_space, spaces.Dict) or "nodes" not in observation_space.spaces:
            raise InputError("the flat view needs the mental-map observation (observation='map')")
        nodes = observation_space["nodes"]
        self.n_nodes = int(nodes.shape[0])
        self.scale = np.asarray(nodes.high, dtype=np.float32)  # (N, F), every entry >= 1
        self.max_dwell = float(observation_space["dwell"].high[0])
        self.adjacency = bool(adjacency)
        if self.adjacency and "adjacency" not in observation_space.spaces:
            raise InputError("the flat view's adjacency entries need the env's layout='dense'")
        self.size = self.scale.size + self.n_nodes + 1 + (self.n_nodes**2 if self.adjacency else 0)

    @property
    def space(self) -> spaces.Box:
        """The flat observation space: ``Box(0, 1, (size,), float32)``."""
        return spaces.Box(0.0, 1.0, shape=(self.size,), dtype=np.float32)

    def __call__(self, observation: dict[str, Any]) -> np.ndarray:
        """The flat ``(size,)`` float32 vector of one agent's ``Dict`` observation."""
        out = np.zeros(self.size, dtype=np.float32)
        end = self.scale.size
        out[:end] = (np.asarray(observation["nodes"], dtype=np.float32) / self.scale).ravel()
        out[end + int(observation["position"])] = 1.0
        end += self.n_nodes
        out[end] = float(np.asarray(observation["dwell"]).reshape(-1)[0]) / self.max_dwell
        if self.adjacency:
            out[end + 1 :] = np.asarray(observation["adjacency"], dtype=np.float32).ravel()
        return out


class FlatMonitoringEnv(ParallelEnv):
    """A PettingZoo ``ParallelEnv``: the monitoring env with flat observations and the action mask
    in the infos (see the module docstring).

    :param env: a :func:`~sb3_pm.envs.persistent_monitoring_v0.parallel_env` with
        ``observation="map"``.
    :param adjacency: include the known adjacency in the vector; ``None`` (default): only when the
        env's ``graph_knowledge`` is ``"discovered"`` (with ``"known"`` it is the same whole
        graph every step and tells the agent nothing).
    """

    metadata = {"name": "sb3_pm_flat_monitoring_v0", "render_modes": ["rgb_array", "ansi"]}

    def __init__(self, env: Any, adjacency: bool | None = None) -> None:
        self.env = env
        base = env.unwrapped
        if adjacency is None:
            adjacency = getattr(base, "graph_knowledge", "discovered") != "known"
        self.possible_agents = list(env.possible_agents)
        self.flattener = Flattener(env.observation_space(self.possible_agents[0]), adjacency)
        self._observation_space = self.flattener.space
        self._zero = np.zeros(self.flattener.size, dtype=np.float32)
        self._free_mask = np.ones(self.flattener.n_nodes, dtype=np.int8)
        self.render_mode = getattr(env, "render_mode", None)

    @property
    def agents(self) -> list[str]:  # type: ignore[override]
        """The agents alive and acting (the wrapped env's ``agents``)."""
        return list(self.env.agents)

    @property
    def unwrapped(self) -> Any:  # type: ignore[override]
        """The monitoring env itself."""
        return self.env.unwrapped

    def observation_space(self, agent: str) -> spaces.Box:  # type: ignore[override]
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Discrete:  # type: ignore[override]
        return self.env.action_space(agent)

    def _flat(
        self, observations: dict[str, Any], infos: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        flat: dict[str, np.ndarray] = {}
        flat_infos: dict[str, dict[str, Any]] = {}
        for agent in self.possible_agents:
            observation = observations.get(agent)
            info = dict(infos.get(agent, {}))
            if observation is None:  # failed earlier: no node, no view, any action is dropped
                flat[agent] = self._zero.copy()
                info["action_mask"] = self._free_mask.copy()
            else:
                flat[agent] = self.flattener(observation)
                info["action_mask"] = np.asarray(observation["action_mask"], dtype=np.int8)
            flat_infos[agent] = info
        return flat, flat_infos

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        observations, infos = self.env.reset(seed=seed, options=options)
        return self._flat(observations, infos)

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        acting = set(self.env.agents)
        chosen = {agent: int(np.asarray(action).reshape(-1)[0]) for agent, action in actions.items()}
        observations, rewards, terminations, truncations, infos = self.env.step(
            {agent: action for agent, action in chosen.items() if agent in acting}
        )
        flat, flat_infos = self._flat(observations, infos)
        last = not self.env.agents and bool(truncations) and all(truncations.values())
        full_rewards = {agent: float(rewards.get(agent, 0.0)) for agent in self.possible_agents}
        full_terminations = {agent: bool(terminations.get(agent, True)) for agent in self.possible_agents}
        full_truncations = {agent: bool(truncations.get(agent, last)) for agent in self.possible_agents}
        if last:  # the episode's end: every agent's info carries the metrics, failed ones too
            metrics = next(iter(infos.values())).get("metrics")
            if metrics is not None:
                for info in flat_infos.values():
                    info.setdefault("metrics", dict(metrics))
        return flat, full_rewards, full_terminations, full_truncations, flat_infos

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()


def flat_parallel_env(
    graph: Any = "paper-50",
    n_agents: int = 4,
    max_cycles: int = 500,
    adjacency: bool | None = None,
    **env_kwargs: Any,
) -> FlatMonitoringEnv:
    """:class:`FlatMonitoringEnv` around ``persistent_monitoring_v0.parallel_env(graph=graph,
    n_agents=n_agents, max_cycles=max_cycles, **env_kwargs)``.

    :raises InputError: ``observation`` other than ``"map"``, or a bad environment argument.
    """
    if env_kwargs.get("observation", "map") != "map":
        raise InputError(f"the flat view needs observation='map', got {env_kwargs['observation']!r}")
    env = persistent_monitoring_v0.parallel_env(
        graph=graph, n_agents=n_agents, max_cycles=max_cycles, **env_kwargs
    )
    return FlatMonitoringEnv(env, adjacency=adjacency)


__all__ = ["FlatMonitoringEnv", "Flattener", "flat_parallel_env"]
