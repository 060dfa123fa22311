""":class:`PersistentMonitoringEnv`, the PettingZoo adapter around the simulation core.

Its arguments, spaces, rewards and metrics are documented in the versioned front file,
:mod:`sb3_pm.envs.persistent_monitoring_v0`, as PettingZoo documents its environments. The
dynamics are :mod:`sb3_pm.envs.core` (pure NumPy), the mental maps :mod:`sb3_pm.envs.mental_map`
and the observations built from them :mod:`sb3_pm.envs.observations`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec

from sb3_pm.envs.core import DEFAULT_U_MAX, MonitoringCore
from sb3_pm.envs.env_state import EnvState
from sb3_pm.envs.env_territories import EnvTerritories
from sb3_pm.envs.known_edges import check_layout, sensing_tables
from sb3_pm.envs.mental_map import MentalMaps
from sb3_pm.envs.metrics import EpisodeMetrics
from sb3_pm.envs.observations import EnvObservations
from sb3_pm.envs.rewards import RewardComputer, resolve_reward
from sb3_pm.envs.territory_rule import TerritoryAdvice
from sb3_pm.errors import InputError
from sb3_pm.graphs import GraphFamily, GraphLike, GraphSpec, resolve_graph_or_family
from sb3_pm.planning.conventions import check_convention, is_planned

OBSERVATION_MODES = ("map", "local")
INITIAL_UNCERTAINTY = ("zero", "random")
ILLEGAL_ACTION_MODES = ("raise", "stay")
_FAMILY_POSITIONS = "initial_positions cannot be given with a graph family (each episode's graph differs)"


class PersistentMonitoringEnv(EnvState, EnvObservations, EnvTerritories, ParallelEnv):
    """Agents patrol a graph to keep the uncertainty of its target nodes low.

    Its running state is saved and restored with ``state_dict()`` / ``load_state_dict()``
    (:class:`~sb3_pm.envs.env_state.EnvState`).
    """

    metadata = {
        "name": "persistent_monitoring_v0",
        "render_modes": ["human", "rgb_array", "ansi"],
        "is_parallelizable": True,
        "render_fps": 4,
    }

    def __init__(
        self,
        graph: GraphLike | GraphFamily = "paper-50",
        n_agents: int = 4,
        max_cycles: int = 500,
        u_max: int = DEFAULT_U_MAX,
        obs_radius: int = 1,
        initial_positions: Sequence[int] | None = None,
        initial_uncertainty: str = "zero",
        reward: str | Mapping[str, float] = "paper",
        observation: str = "map",
        graph_knowledge: str = "discovered",
        target_knowledge: str = "discovered",
        territory_input: bool = False,
        advice_input: bool = False,
        territories: str = "split",
        illegal_action: str = "raise",
        shared_map: bool = False,
        failures: Mapping[str, int] | None = None,
        failure_rate: float = 0.0,
        render_mode: str | None = None,
        layout: str = "dense",
    ) -> None:
        super().__init__()
        for flag, setting in (("territory_input", territory_input), ("advice_input", advice_input)):
            if setting is not False and setting is not True:
                raise InputError(f"{flag} must be true or false, got {setting!r}")
        problem = resolve_graph_or_family(graph)
        #: The family each reset draws a graph from (``None``: one fixed graph).
        self.family: GraphFamily | None = problem if isinstance(problem, GraphFamily) else None
        #: ``"dense"`` (an ``(N, N)`` adjacency per map observation) or ``"edges"`` (an edge list and mask).
        self.layout = check_layout(layout, observation, self.family is not None)
        if self.family is not None:
            # A placeholder until the first reset draws the episode's graph from the seeded generator.
            problem = self.family.draw(np.random.default_rng(0))
            if initial_positions is not None:
                raise InputError(_FAMILY_POSITIONS)
            if observation != "map":
                raise InputError("a graph family needs observation='map' (padded mental maps)")
            if not isinstance(reward, str) and "territory" in dict(reward) and territory_input is not True:
                # Told its territory each episode (territory_input), a learner need not settle in one.
                raise InputError(
                    "the territory reward needs one graph or territory_input: a graph family's "
                    "territories change every episode, so no learner could settle in one unless told it"
                )
            if n_agents > self.family.min_nodes:
                raise InputError(
                    f"{n_agents} agents do not fit the graph family {self.family.name!r}: "
                    f"its smallest graph has {self.family.min_nodes} nodes"
                )
        for flag, setting in (("territory_input", territory_input), ("advice_input", advice_input)):
            if not setting:
                continue
            if observation != "map":
                raise InputError(f"{flag} is a node feature of map observations: it needs observation='map'")
            if graph_knowledge != "known" or target_knowledge != "known":
                raise InputError(
                    f"{flag} needs graph_knowledge and target_knowledge 'known': an agent computes "
                    f"its territory from the site plan (got {graph_knowledge!r} and {target_knowledge!r})"
                )
        self.territory_input = bool(territory_input)
        self.advice_input = bool(advice_input)
        self.territories = check_convention(territories)
        assert isinstance(problem, GraphSpec)
        self.graph: GraphSpec = problem
        if max_cycles < 1:
            raise InputError(f"max_cycles must be at least 1, got {max_cycles}")
        if obs_radius < 0:
            raise InputError(f"obs_radius must be >= 0, got {obs_radius}")
        for value, allowed, label in (
            (observation, OBSERVATION_MODES, "observation"),
            (initial_uncertainty, INITIAL_UNCERTAINTY, "initial_uncertainty"),
            (illegal_action, ILLEGAL_ACTION_MODES, "illegal_action"),
        ):
            if value not in allowed:
                raise InputError(f"{label} must be one of {allowed}, got {value!r}")
        render_modes = list(self.metadata["render_modes"])  # type: ignore[call-overload]
        if render_mode is not None and render_mode not in render_modes:
            raise InputError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        n_nodes = self.graph.n_nodes
        if initial_positions is not None:
            initial_positions = [int(p) for p in initial_positions]
            if len(initial_positions) != n_agents or not all(0 <= p < n_nodes for p in initial_positions):
                raise InputError(
                    f"initial_positions must list {n_agents} nodes in 0..{n_nodes - 1}, "
                    f"got {initial_positions}"
                )
        self.n_agents = n_agents
        self.max_cycles = int(max_cycles)
        self.u_max = int(u_max)
        self.obs_radius = int(obs_radius)
        self.initial_positions = initial_positions
        self.initial_uncertainty = initial_uncertainty
        self.reward_weights = resolve_reward(reward)
        if is_planned(self.territories):
            if not self._uses_territory():
                raise InputError(
                    f"territories: {self.territories} sets what the territory reward, territory_input "
                    "and advice_input read, and none of them is on"
                )
            if "territory" in self.reward_weights and not self.territory_input:
                # The same reason as for a family: the planned groups change with the starts.
                raise InputError(
                    f"the territory reward with territories: {self.territories} needs territory_input: the "
                    "groups change every episode, so no learner could settle in one unless told it"
                )
        self.observation_mode = observation
        self.graph_knowledge = graph_knowledge
        self.target_knowledge = target_knowledge
        self.illegal_action = illegal_action
        self.shared_map = bool(shared_map)
        self.render_mode = render_mode
        self._advice: TerritoryAdvice | None = None

        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.agents: list[str] = []
        self.failures, self.failure_rate = self._check_failures(failures, failure_rate)
        #: ``(n_agents,)`` the step after which each agent fails (``max_cycles + 1``: never).
        self._fail_at = np.full(n_agents, self.max_cycles + 1, dtype=np.int64)
        for agent, step in self.failures.items():
            self._fail_at[self.possible_agents.index(agent)] = step
        self._active = np.ones(n_agents, dtype=bool)
        self.agent_name_mapping = {name: i for i, name in enumerate(self.possible_agents)}

        self.rewards_computer = RewardComputer(self.reward_weights, n_agents, self.u_max)
        self._renderer: Any = None
        #: ``(n_agents,)`` row index of each agent, for per-agent gathers such as the territory's.
        self._rows = np.arange(self.n_agents)
        self._use_graph(self.graph)
        self._rng = np.random.default_rng()
        self._step_count = 0
        self._dwell = np.zeros(n_agents, dtype=np.int64)

        #: Nodes of the observation and action spaces: the graph's, or a family's largest graph.
        self.space_nodes = self.family.max_nodes if self.family is not None else n_nodes
        self._observation_space = self._build_observation_space()
        self._action_space = spaces.Discrete(self.space_nodes)

    def _use_graph(self, graph: GraphSpec) -> None:
        """Build everything that depends on the graph: the dynamics, fresh mental maps (a new graph
        is unknown to every agent) and the metrics."""
        self.graph = graph
        self.core = MonitoringCore(graph, self.n_agents, self.u_max)
        # (N, N) or sparse rows: node j is seen from node i, edges of j are seen, j is a move
        tables = sensing_tables(graph, self.obs_radius, self.layout)
        self._observes, self._edge_nodes, self._reachable_i8 = tables
        self._targets = graph.targets
        self.maps = MentalMaps(
            self.n_agents, graph.adjacency, self.graph_knowledge, self.target_knowledge, graph.targets,
            self.layout,
        )
        self.maps.track_uncertainty_sum = "change" in self.reward_weights
        self._territories_for_graph()
        self.metrics = EpisodeMetrics(graph.target_indices, self.u_max, self.max_cycles, self.n_agents)
        self.metrics.track_failures = bool(self.failures) or self.failure_rate > 0
        self._last_outcome_counts = np.zeros(graph.n_nodes, dtype=np.int64)
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def _check_failures(
        self, failures: Mapping[str, int] | None, rate: float
    ) -> tuple[dict[str, int], float]:
        """Validated ``failures`` and ``failure_rate`` (one-line errors naming the bad entry)."""
        schedule: dict[str, int] = {}
        for agent, step in dict(failures or {}).items():
            if agent not in self.possible_agents:
                raise InputError(f"failures names {agent!r}, not an agent of {self.possible_agents}")
            if isinstance(step, bool) or not isinstance(step, (int, np.integer)):
                raise InputError(f"failures[{agent!r}] must be an integer step, got {step!r}")
            if not 1 <= int(step) < self.max_cycles:
                raise InputError(f"failures[{agent!r}] = {step} is outside 1..{self.max_cycles - 1}")
            schedule[agent] = int(step)
        if len(schedule) >= len(self.possible_agents):
            raise InputError("failures would remove every agent; at least one must stay")
        rate = float(rate)
        if not 0.0 <= rate < 1.0:
            raise InputError(f"failure_rate must be in [0, 1), got {rate}")
        return schedule, rate

    def observation_space(self, agent: str) -> spaces.Dict:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    # ------------------------------------------------------------ true state
    @property
    def uncertainty(self) -> np.ndarray:
        """``(N,)`` int true uncertainties (a copy), for tests and omniscient baselines."""
        return self.core.uncertainty.copy()

    @property
    def positions(self) -> np.ndarray:
        """``(n_agents,)`` int node of each agent, in ``possible_agents`` order (a copy)."""
        return self.core.positions.copy()

    @property
    def active(self) -> np.ndarray:
        """``(n_agents,)`` bool, the agents that have not failed (a copy), in ``possible_agents`` order."""
        return self._active.copy()

    @property
    def step_count(self) -> int:
        return self._step_count

    # ------------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = options or {}
        # Other keys are ignored, as PettingZoo expects (its API test passes arbitrary options).
        if self.family is not None:
            if "initial_positions" in options:
                raise InputError(_FAMILY_POSITIONS)
            # Every episode on a new graph, drawn first so the sequence of graphs flows from the seed.
            self._use_graph(self.family.draw(self._rng))
            self.rewards_computer.forget_history()
        elif options.get("new_lifetime"):
            # Agents that have never lived: no discovered edges, no past episodes for `change`.
            self.maps.forget_edges()
            self.rewards_computer.forget_history()
        n_nodes = self.graph.n_nodes
        positions = options.get("initial_positions", self.initial_positions)
        if positions is None:
            positions = self._rng.choice(n_nodes, size=self.n_agents, replace=False)
        initial_u = None
        if self.initial_uncertainty == "random":
            initial_u = self._rng.integers(0, self.u_max, size=n_nodes, endpoint=True)
        self.core.reset(np.asarray(positions), initial_u)
        self._territories_for_episode()
        self.agents = list(self.possible_agents)
        self._active[:] = True
        self._step_count = 0
        self._dwell[:] = 0
        self.maps.reset_features()
        if self._advice is not None:
            self._advice.reset()
        self.rewards_computer.reset()
        self.metrics.reset()
        counts = np.bincount(self.core.positions, minlength=n_nodes)
        self._observe(counts, counts > 0, advance_age=False)
        infos: dict[str, dict] = {agent: {} for agent in self.agents}
        return self._observations(), infos

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step() called on a finished episode; call reset() first")
        failures_on = self.metrics.track_failures
        acting = list(self.agents)
        missing = [agent for agent in acting if agent not in actions]
        if missing:
            raise InputError(f"no action given for {missing}")
        if failures_on:  # a failed agent gives no action (-1 here); the core keeps it where it is
            requested = [actions[agent] if agent in actions else -1 for agent in self.possible_agents]
        else:
            requested = [actions[agent] for agent in self.possible_agents]
        destinations = np.array(requested, dtype=np.int64)
        if destinations.shape != (self.n_agents,):
            raise InputError(f"every action must be one node index; got {requested}")
        previous = self.core.positions
        outcome = self.core.step(
            destinations, self.illegal_action, self.possible_agents, self._active if failures_on else None
        )
        self._step_count += 1
        positions = self.core.positions
        self._dwell += 1
        self._dwell[positions != previous] = 0
        self._observe(outcome.counts, outcome.presence, advance_age=True)
        alone_on_target = self._targets[positions] & ~outcome.collided
        if failures_on:
            alone_on_target &= self._active  # a failed agent is on no node
        idle = alone_on_target & (outcome.u_before == 0)  # guarding a target that is already clean
        self.metrics.update(
            outcome.target_uncertainty,
            outcome.target_presence,
            int(np.count_nonzero(outcome.collided)),
            int(np.count_nonzero(idle)),
            int(np.count_nonzero(self._active)) if failures_on else self.n_agents,
        )
        last = self._step_count >= self.max_cycles
        reward_values, _ = self.rewards_computer.step(
            outcome,
            alone_on_target,
            last,
            self.maps.episode_uncertainty_sum,
            self._territory[self._rows, positions] if self._territory is not None else None,
        )

        failed = self._draw_failures(last) if failures_on else []
        observations = self._observations()
        rewards = dict(zip(self.possible_agents, reward_values.tolist()))
        terminations = {agent: agent in failed for agent in self.possible_agents}
        truncations = dict.fromkeys(self.possible_agents, last)
        infos: dict[str, dict] = {agent: {} for agent in self.possible_agents}
        if outcome.any_illegal:
            for i in np.flatnonzero(outcome.illegal):
                infos[self.possible_agents[i]]["illegal_action"] = int(destinations[i])
        for agent in failed:
            infos[agent]["failed"] = self._step_count
        if last:
            summary = self.metrics.summary()
            for agent in self.possible_agents:
                infos[agent]["metrics"] = dict(summary)
            self.agents = []
        elif failed:
            self.agents = [agent for agent in self.agents if agent not in failed]
        if len(acting) < len(self.possible_agents):  # only the agents that acted this step report
            observations = {agent: observations[agent] for agent in acting}
            rewards = {agent: rewards[agent] for agent in acting}
            terminations = {agent: terminations[agent] for agent in acting}
            truncations = {agent: truncations[agent] for agent in acting}
            infos = {agent: infos[agent] for agent in acting}
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def _draw_failures(self, last: bool) -> list[str]:
        """The agents that fail after this step (scheduled, then drawn at ``failure_rate``)."""
        if last:
            return []
        failing = self._active & (self._fail_at == self._step_count)
        if self.failure_rate > 0:
            draws = self._rng.random(self.n_agents)  # one draw per agent and step: a fixed stream
            failing |= self._active & (draws < self.failure_rate)
        if failing.sum() >= self._active.sum():  # the last live agent never fails
            keep = np.flatnonzero(self._active)[0]
            failing[keep] = False
        if not failing.any():
            return []
        self._active &= ~failing
        self.metrics.record_failure(int(failing.sum()))
        return [self.possible_agents[i] for i in np.flatnonzero(failing)]

    def episode_metrics(self) -> dict[str, float]:
        """The metrics of the episode so far (complete once it has been truncated)."""
        return self.metrics.summary()

    def uncertainty_trace(self) -> np.ndarray:
        """``(steps,)`` summed target uncertainty after each step of the current episode."""
        return self.metrics.uncertainty_trace()

    # ------------------------------------------------------------ rendering
    def render(self) -> Any:
        if self.render_mode is None:
            raise InputError("render() needs a render_mode: pass render_mode='rgb_array', 'human' or 'ansi'")
        from sb3_pm.envs import rendering

        if self.render_mode == "ansi":
            return rendering.render_ansi(self)
        if self._renderer is None:
            self._renderer = rendering.GraphRenderer(self.graph, self.u_max, blit=self.render_mode != "human")
        frame = self._renderer.draw(self.core.uncertainty, self.core.positions, self._step_count)
        if self.render_mode == "human":
            self._renderer.show()
            return None
        return frame

    def __deepcopy__(self, memo: dict[int, Any]) -> PersistentMonitoringEnv:
        """A copy of the episode's whole state without the renderer, whose drawing buffers cannot
        be copied; the copy draws afresh if asked to render."""
        import copy

        duplicate = type(self).__new__(type(self))
        memo[id(self)] = duplicate
        for name, value in self.__dict__.items():
            setattr(duplicate, name, None if name == "_renderer" else copy.deepcopy(value, memo))
        return duplicate

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    @property
    def unwrapped(self) -> PersistentMonitoringEnv:
        return self


#: The environment class itself (PettingZoo's name for the unwrapped parallel env).
raw_env = PersistentMonitoringEnv


def parallel_env(**kwargs: Any) -> PersistentMonitoringEnv:
    """The environment with the parallel API (every agent acts each step)."""
    return PersistentMonitoringEnv(**kwargs)


def env(**kwargs: Any) -> Any:
    """The environment with the AEC API (agents act in turn), order-enforced."""
    return wrappers.OrderEnforcingWrapper(parallel_to_aec(PersistentMonitoringEnv(**kwargs)))
