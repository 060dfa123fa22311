"""Where each agent settles in an episode, and which targets nobody holds.

A learned team's agents stop roaming after the first part of an episode: each keeps to two or
three nodes, typically bouncing between two adjacent targets, which one agent can hold near 0
forever (docs/METHOD.md, "Why pairs of targets"). An episode is good when the agents' settling
places cover every target, and bad when two agents settle near the same targets and one is left.
This module reads that off the positions of one episode, for ``sb3-pm evaluate --settling``.

Pure NumPy on arrays the harness records (``SettlingRecorder``), so it runs for any team,
baselines included.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_pm.errors import InputError

#: A node is one of an agent's settling places if the agent stood on it for at least this share of
#: the steps looked at (with a 2-node oscillation each node has 0.5; 0.05 drops passing visits).
MIN_SHARE = 0.05


@dataclass
class Settling:
    """One episode's settling places.

    :ivar since: how many of the episode's first steps were skipped (the window is the steps
        after them, counting steps from 1 as ``--fail`` does).
    :ivar places: one list per agent, in ``possible_agents`` order: its settling nodes in
        increasing order (empty for an agent that failed before the window).
    :ivar targets_left: targets on no agent's list of places.
    :ivar target_u: ``{target node: mean uncertainty over the window}``, one entry per target.
    """

    since: int
    places: list[list[int]]
    targets_left: list[int]
    target_u: dict[int, float]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (target keys become strings in JSON; :meth:`from_dict` turns them back)."""
        return {
            "since": self.since,
            "places": self.places,
            "targets_left": self.targets_left,
            "target_u": self.target_u,
        }

    @classmethod
    def from_dict(cls, payload: dict[str, Any]) -> Settling:
        """The inverse of :meth:`to_dict` (after a JSON round trip)."""
        return cls(
            since=int(payload["since"]),
            places=[[int(n) for n in row] for row in payload["places"]],
            targets_left=[int(n) for n in payload["targets_left"]],
            target_u={int(k): float(v) for k, v in payload["target_u"].items()},
        )


def settling(
    positions: np.ndarray,
    target_u: np.ndarray,
    targets: np.ndarray,
    since: int,
    min_share: float = MIN_SHARE,
    active: np.ndarray | None = None,
) -> Settling:
    """The settling places of one episode.

    :param positions: ``(T, K)`` int, each agent's node after each step.
    :param target_u: ``(T, n_targets)`` the targets' uncertainty after each step.
    :param targets: ``(n_targets,)`` the targets' node indices, in ``target_u``'s column order.
    :param since: how many of the first steps to skip (``0 <= since < T``).
    :param min_share: a node counts if the agent stood on it for at least this share of the
        window's steps.
    :param active: ``(T, K)`` bool, whether each agent was live during each step (a failed agent
        stands nowhere); ``None``: all live.
    :return: the :class:`Settling` of the window.
    :raises InputError: for arrays of inconsistent shapes, a window outside the episode or a
        share outside ``(0, 1]``.
    """
    positions = np.asarray(positions)
    target_u = np.asarray(target_u, dtype=float)
    targets = np.asarray(targets)
    if positions.ndim != 2:
        raise InputError(f"settling: positions must be (steps, agents), got shape {positions.shape}")
    steps = positions.shape[0]
    if targets.ndim != 1 or target_u.shape != (steps, targets.size):
        raise InputError(
            f"settling: target_u must be (steps, targets) = {(steps, targets.size)}, got {target_u.shape}"
        )
    if active is not None and np.shape(active) != positions.shape:
        raise InputError(
            f"settling: active must have the positions' shape {positions.shape}, got {np.shape(active)}"
        )
    if not 0 <= since < steps:
        raise InputError(f"settling: since must be in [0, {steps}) for a {steps}-step episode, got {since}")
    if not 0 < min_share <= 1:
        raise InputError(f"settling: min_share must be in (0, 1], got {min_share}")
    window = positions[since:]
    live = np.ones(window.shape, dtype=bool) if active is None else np.asarray(active, dtype=bool)[since:]
    places: list[list[int]] = []
    for agent in range(window.shape[1]):
        nodes = window[live[:, agent], agent]
        if nodes.size == 0:  # failed before the window: it settles nowhere
            places.append([])
            continue
        values, counts = np.unique(nodes, return_counts=True)
        places.append(values[counts >= min_share * window.shape[0]].tolist())
    settled = {node for row in places for node in row}
    target_list = targets.tolist()
    mean_u = target_u[since:].mean(axis=0)
    return Settling(
        since=since,
        places=places,
        targets_left=[t for t in target_list if t not in settled],
        target_u={t: float(u) for t, u in zip(target_list, mean_u, strict=True)},
    )


class SettlingRecorder:
    """Collects positions and target uncertainties step by step (a :func:`run_episode` hook).

    :param since: how many of the first steps :meth:`result` skips.
    """

    def __init__(self, since: int) -> None:
        self.since = since
        self._positions: list[np.ndarray] = []
        self._u: list[np.ndarray] = []
        self._active: list[np.ndarray] = []
        self._targets: np.ndarray | None = None
        self._live: np.ndarray | None = None

    def __call__(self, env: Any) -> None:
        """Record the state after one step of ``env`` (the raw parallel env)."""
        if self._targets is None:
            self._targets = env.graph.target_indices
        positions = env.positions
        # An agent that fails "after step k" stood on its node during step k, and the env marks it
        # failed at the end of that step: so this step's live mask is the one before the step.
        self._active.append(np.ones(positions.shape, dtype=bool) if self._live is None else self._live)
        self._live = env.active
        self._positions.append(positions)
        self._u.append(env.uncertainty[self._targets])

    def result(self) -> Settling:
        """The episode's :class:`Settling` (after the last step)."""
        if self._targets is None:
            raise InputError("settling: no step was recorded")
        return settling(
            np.stack(self._positions),
            np.stack(self._u),
            self._targets,
            self.since,
            active=np.stack(self._active),
        )


def settling_table(records: list[Any]) -> str:
    """A plain-text table, one line per episode: avg_uncertainty, each agent's places, targets left.

    :param records: :class:`~sb3_pm.evaluation.harness.EpisodeRecord` objects with ``settling`` set.
    """
    lines = []
    for record in records:
        if record.settling is None:
            continue
        s = record.settling
        places = "  ".join(f"a{i}:{'-'.join(map(str, row)) or 'none'}" for i, row in enumerate(s.places))
        left = ", ".join(f"{t} (u {s.target_u[t]:.0f})" for t in s.targets_left) or "none"
        lines.append(
            f"episode {record.episode:>3}  avg_uncertainty {record.metrics['avg_uncertainty']:>7.1f}  "
            f"settles {places}  left: {left}"
        )
    return "\n".join(lines)
