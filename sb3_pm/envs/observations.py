"""What each agent observes: the observation space and the per-step observations.

:class:`EnvObservations` is a part of :class:`~sb3_pm.envs.persistent_monitoring.PersistentMonitoringEnv`
(its base class): it folds each step's local views into the mental maps and hands every agent
its map (``observation="map"``) or its raw neighbourhood (``observation="local"``). It reads the
env's state: ``core`` (positions, uncertainty), ``maps``, ``graph``, the precomputed reachability
and sensing tables (``_reachable_i8``, ``_observes``, ``_edge_nodes``), the team's ``_active``
flags and ``_dwell`` counters, and the optional input columns (``_territory_column``,
``_advice``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_pm.envs.mental_map import AGE, FEATURES, U


class EnvObservations:
    """The observation half of the environment (see the module docstring)."""

    # Set by the environment's constructor and reset.
    observation_mode: str
    space_nodes: int
    n_agents: int
    u_max: float
    max_cycles: int
    territory_input: bool
    advice_input: bool
    shared_map: bool
    layout: str
    possible_agents: list[str]
    core: Any
    maps: Any
    graph: Any

    def _build_observation_space(self) -> spaces.Dict:
        n = self.space_nodes
        mask = spaces.Box(0, 1, shape=(n,), dtype=np.int8)
        if self.observation_mode == "map":
            # territory_input, then advice_input, each append one 0/1 column after FEATURES
            extra = int(self.territory_input) + int(self.advice_input)
            high = np.ones((n, len(FEATURES) + extra), dtype=np.float32)
            high[:, FEATURES.index("u")] = self.u_max
            high[:, FEATURES.index("age")] = self.max_cycles
            return spaces.Dict(
                {
                    "nodes": spaces.Box(0.0, high, dtype=np.float32),
                    **self._graph_spaces(n),
                    "position": spaces.Discrete(n),
                    "dwell": spaces.Box(0.0, float(self.max_cycles), shape=(1,), dtype=np.float32),
                    "action_mask": mask,
                }
            )
        return spaces.Dict(
            {
                "position": spaces.Discrete(n),
                "observed": mask,
                "uncertainty": spaces.Box(0.0, float(self.u_max), shape=(n,), dtype=np.float32),
                "target": mask,
                "occupied": mask,
                "edges": spaces.Box(0, 1, shape=(n, n), dtype=np.int8),
                "action_mask": mask,
            }
        )

    def _graph_spaces(self, n: int) -> dict[str, spaces.Box]:
        """The known graph's entries of a map observation: ``adjacency`` ``(N, N)`` int8
        (``layout="dense"``), or ``edge_index`` ``(2, E)`` int64 and ``edge_mask`` ``(E,)`` int8
        (``layout="edges"``, E the graph's directed edges: O(N + E) per observation)."""
        if self.layout == "dense":
            return {"adjacency": spaces.Box(0, 1, shape=(n, n), dtype=np.int8)}
        edges = self.maps.known_edges.n_edges
        return {
            "edge_index": spaces.Box(0, max(n - 1, 0), shape=(2, edges), dtype=np.int64),
            "edge_mask": spaces.Box(0, 1, shape=(edges,), dtype=np.int8),
        }

    def _observe(self, counts: np.ndarray, presence: np.ndarray, advance_age: bool) -> None:
        """Fold this step's local views into the maps: ``counts`` ``(N,)`` agents per node and
        ``presence`` ``(N,)`` bool, ``counts > 0``."""
        positions = self.core.positions
        self._observed = self._observes[positions]  # (n_agents, N) bool
        self._last_outcome_counts = counts
        edge_nodes = self._edge_nodes[positions]
        # Each map's edge row is its own node's unless an agent failed or the map is shared.
        edge_positions: list[int] | None = None
        # A failed agent senses nothing (nor feeds a shared map).
        if np.count_nonzero(self._active) < self.n_agents:
            self._observed = self._observed & self._active[:, None]
            edge_nodes = edge_nodes & self._active[:, None]
        elif not self.shared_map:
            edge_positions = positions.tolist()
        map_observed = self._observed
        if self.shared_map:
            # Centralized setting: every map receives the union of the team's observations.
            map_observed = np.broadcast_to(self._observed.any(axis=0), self._observed.shape)
            edge_nodes = np.broadcast_to(edge_nodes.any(axis=0), edge_nodes.shape)
        self.maps.update(
            positions,
            map_observed,
            self.core.uncertainty,
            self._targets,
            counts,
            edge_nodes,
            advance_age=advance_age,
            edge_positions=edge_positions,
            presence=presence,
        )

    def _observations(self) -> dict[str, dict[str, Any]]:
        positions = self.core.positions
        masks = self._reachable_i8[positions]  # fresh (n_agents, N); rows handed out as views
        if self.observation_mode == "map":
            nodes = self.maps.features  # a fresh array; rows handed out as views
            extra = [self._territory_column] if self._territory_column is not None else []
            if self._advice is not None:
                extra.append(self._advice_column(positions))
            if extra:  # one copy for every appended column
                nodes = np.concatenate((nodes, *extra), axis=-1)
            dwell = self._dwell.astype(np.float32)[:, None]
            if self.layout == "edges":
                return self._edge_observations(nodes, masks, dwell, positions)
            adjacency: Sequence[np.ndarray] | np.ndarray
            if self.space_nodes > self.core.n_nodes:
                nodes, adjacency, masks = self._padded(nodes, masks)
            else:
                adjacency = self.maps.adjacency_observations()
            return {
                agent: {
                    "nodes": nodes[i],
                    "adjacency": adjacency[i],
                    "position": position,
                    "dwell": dwell[i],
                    "action_mask": masks[i],
                }
                for i, (agent, position) in enumerate(zip(self.possible_agents, positions.tolist()))
            }
        return {agent: self._local_observation(i, masks[i]) for i, agent in enumerate(self.possible_agents)}

    def _edge_observations(
        self, nodes: np.ndarray, masks: np.ndarray, dwell: np.ndarray, positions: np.ndarray
    ) -> dict[str, dict[str, Any]]:
        """Map observations in the edges layout: ``nodes`` ``(n_agents, N, F)``, ``masks``
        ``(n_agents, N)``, ``dwell`` ``(n_agents, 1)``, the maps' edge masks ``(E,)`` each and the
        graph's one read-only edge list ``(2, E)``, shared by every observation."""
        known = self.maps.known_edges
        edge_masks = known.mask_observations()
        return {
            agent: {
                "nodes": nodes[i],
                "edge_index": known.edge_index,
                "edge_mask": edge_masks[i],
                "position": position,
                "dwell": dwell[i],
                "action_mask": masks[i],
            }
            for i, (agent, position) in enumerate(zip(self.possible_agents, positions.tolist()))
        }

    def _advice_column(self, positions: np.ndarray) -> np.ndarray:
        """``(n_agents, N, 1)`` float32: 1 on each agent's next move by the territory rule."""
        assert self._advice is not None
        channels = self.maps.channels
        moves = self._advice.moves(positions, channels[U], channels[AGE], self._active)
        column = np.zeros((self.n_agents, self.core.n_nodes, 1), dtype=np.float32)
        advised = moves >= 0
        column[advised.nonzero()[0], moves[advised], 0] = 1.0
        return column

    def _padded(self, nodes: np.ndarray, masks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Map observations padded from the graph's N nodes to the space's M.

        A padding node has zero features, no edge and is never reachable: to the agent it looks
        like a node it has not discovered, and since it has no edge the GAT passes nothing from it
        to a real node. With ``laplacian: none`` the actor's logits on real nodes therefore do not
        depend on the padding.

        Shapes: nodes ``(n_agents, N, F)`` -> ``(n_agents, M, F)`` (F = 5, plus one column
        each for ``territory_input`` and ``advice_input``); the maps' known adjacency
        ``(n_agents, N, N)`` -> ``(n_agents, M, M)``; masks ``(n_agents, N)`` -> ``(n_agents, M)``.
        """
        n, m = self.graph.n_nodes, self.space_nodes
        padded_nodes = np.zeros((self.n_agents, m, nodes.shape[-1]), dtype=nodes.dtype)
        padded_nodes[:, :n] = nodes
        padded_adjacency = np.zeros((self.n_agents, m, m), dtype=np.int8)
        padded_adjacency[:, :n, :n] = self.maps.adjacency
        padded_masks = np.zeros((self.n_agents, m), dtype=np.int8)
        padded_masks[:, :n] = masks
        return padded_nodes, padded_adjacency, padded_masks

    def _local_observation(self, i: int, mask: np.ndarray) -> dict[str, Any]:
        """The raw observation of agent ``i`` (no memory): its ball of radius ``obs_radius``."""
        observed = self._observed[i]
        position = int(self.core.positions[i])
        others = self._last_outcome_counts.copy()
        others[position] -= 1
        edge_nodes = self._edge_nodes[position]
        edges = self.graph.adjacency & (edge_nodes[:, None] | edge_nodes[None, :])
        return {
            "position": position,
            "observed": observed.astype(np.int8),
            "uncertainty": np.where(observed, self.core.uncertainty, 0).astype(np.float32),
            "target": (observed & self._targets).astype(np.int8),
            "occupied": (observed & (others > 0)).astype(np.int8),
            "edges": edges.astype(np.int8),
            "action_mask": mask,
        }


__all__ = ["EnvObservations"]
