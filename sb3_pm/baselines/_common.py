"""Small helpers shared by the baselines (not part of the public API)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sb3_pm.envs.territory_rule import nearest_first
from sb3_pm.graphs import GraphSpec
from sb3_pm.graphs.routes import Routes

__all__ = [
    "agent_positions",
    "env_graph",
    "nearest_first",
    "nearest_target",
    "own_uncertainty",
    "step_towards",
]


def agent_positions(observations: Mapping[str, Mapping[str, Any]]) -> tuple[list[str], np.ndarray]:
    """The agents of ``observations`` (in the order given) and each one's own ``position``."""
    agents = list(observations)
    positions = np.fromiter(
        (int(observations[a]["position"]) for a in agents), dtype=np.int64, count=len(agents)
    )
    return agents, positions


def env_graph(env: Any) -> GraphSpec:
    """The graph of ``env`` (the topology is static problem data, not hidden state)."""
    return env.unwrapped.graph


def step_towards(
    next_hop: np.ndarray, positions: np.ndarray, goals: Sequence[int] | np.ndarray
) -> np.ndarray:
    """One move along a shortest path for every agent (``next_hop[i, i] == i``, so goal reached = stay)."""
    return next_hop[positions, np.asarray(goals, dtype=np.int64)]


def nearest_target(
    routes: Routes, position: int, candidates: np.ndarray, keys: np.ndarray | None = None
) -> int:
    """:func:`nearest_first`'s first candidate (highest ``keys`` ``(N,)`` if given, then nearest,
    then lowest index) among the targets ``candidates``, from the site's routes (``graph.routes``:
    no all-pairs table on a large site)."""
    order_keys: list[np.ndarray] = [candidates, routes.distances(position, candidates)]
    if keys is not None:
        order_keys.append(-keys[candidates])
    return int(candidates[np.lexsort(order_keys)[0]])


def own_uncertainty(observation: Any, node: int) -> float:
    """The ``u`` an agent observes on ``node`` in its own observation (``map`` or ``local`` mode)."""
    if "nodes" in observation:
        return float(observation["nodes"][node, 0])  # column 0 is ``u`` (mental_map.FEATURES)
    return float(observation["uncertainty"][node])
