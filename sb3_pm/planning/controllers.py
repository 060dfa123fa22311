"""Per-agent controllers that carry out a plan, and the joint simulation that prices a whole plan.

A controller decides one agent's next node from the true state; :func:`simulate` runs a team of
them through eq. (1) exactly as :class:`sb3_pm.envs.core.MonitoringCore` does, so the planner can
compare whole plans before acting (and ``tests/test_planning.py`` checks the two agree).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from sb3_pm.planning.group_patrol import RULES
from sb3_pm.planning.pair_schedule import PairSchedule

__all__ = [
    "Controller",
    "GroupController",
    "OpeningController",
    "PairController",
    "ViaController",
    "simulate",
]


class Controller(Protocol):
    """One agent's rule: the next node from its position and the true uncertainties."""

    def move(self, position: int, uncertainty: np.ndarray, remaining: int) -> int:
        """:param uncertainty: ``(N,)`` true ``u``; :param remaining: steps left, this one included."""
        ...


class GroupController:
    """A group rule (:data:`~sb3_pm.planning.group_patrol.RULES`) on ``group``, the goal kept
    between steps (for ``tour``, ``group`` is in tour order)."""

    def __init__(
        self,
        group: Sequence[int],
        distances: list[list[int]],
        next_hop: list[list[int]],
        rule: str = "stalest",
    ) -> None:
        self.group = [int(t) for t in group]
        self.distances, self.next_hop = distances, next_hop
        self.rule = RULES[rule]
        self.goal: int | None = None

    def move(self, position: int, uncertainty: np.ndarray, remaining: int) -> int:
        node, self.goal = self.rule(
            position, self.goal, self.group, uncertainty, self.distances, self.next_hop
        )
        return int(node)


class PairController:
    """The exact schedule of a two-target group (:class:`~sb3_pm.planning.pair_schedule.PairSchedule`)."""

    def __init__(self, schedule: PairSchedule, entry_node: int) -> None:
        self.schedule, self.entry_node = schedule, int(entry_node)
        self.a, self.b = schedule.path[0], schedule.path[-1]

    def move(self, position: int, uncertainty: np.ndarray, remaining: int) -> int:
        return self.schedule.move(
            position, self.entry_node, int(uncertainty[self.a]), int(uncertainty[self.b]), remaining
        )


class ViaController:
    """Walk through ``waypoints`` by shortest paths first, then hand over to ``then``."""

    def __init__(self, waypoints: Sequence[int], then: Controller, next_hop: list[list[int]]) -> None:
        self.waypoints = [int(w) for w in waypoints]
        self.then, self.next_hop = then, next_hop

    def move(self, position: int, uncertainty: np.ndarray, remaining: int) -> int:
        while self.waypoints and self.waypoints[0] == position:
            self.waypoints.pop(0)
        if self.waypoints:
            return int(self.next_hop[position][self.waypoints[0]])
        return self.then.move(position, uncertainty, remaining)


class OpeningController:
    """Play the fixed first ``moves`` (nodes, one per step), then hand over to ``then``."""

    def __init__(self, moves: Sequence[int], then: Controller) -> None:
        self.moves = [int(m) for m in moves]
        self.then = then

    def move(self, position: int, uncertainty: np.ndarray, remaining: int) -> int:
        if self.moves:
            return self.moves.pop(0)
        return self.then.move(position, uncertainty, remaining)


def simulate(
    controllers: Sequence[Controller],
    starts: np.ndarray,
    target_indices: np.ndarray,
    initial_uncertainty: np.ndarray,
    max_cycles: int,
    u_max: int,
) -> float:
    """The team's ``avg_uncertainty`` over an episode (controllers are consumed: they keep state).

    :param starts: ``(n,)`` start nodes; :param initial_uncertainty: ``(N,)`` ``u`` at reset.
    """
    positions = [int(s) for s in starts]
    uncertainty = np.asarray(initial_uncertainty, dtype=np.int64).copy()
    targets = np.asarray(target_indices, dtype=np.int64)
    occupied = np.zeros(uncertainty.size, dtype=bool)
    total = 0
    for step in range(max_cycles):
        remaining = max_cycles - step
        positions = [c.move(p, uncertainty, remaining) for c, p in zip(controllers, positions)]
        occupied[:] = False
        occupied[positions] = True
        values = uncertainty[targets]
        here = occupied[targets]
        uncertainty[targets] = np.where(here, np.maximum(values - 1, 0), np.minimum(values + 1, u_max))
        total += int(uncertainty[targets].sum())
    return total / max_cycles
