"""Episode metrics (docs/METHOD.md "Metrics"), streamed one step at a time.

Step ``k`` (``k = 0..K-1``) is measured after its move and uncertainty update:

``avg_uncertainty``
    (1/K) sum_k sum_{targets} u_{m,k}
``max_neglect``
    over targets, the longest run of consecutive steps with no agent on the
    target (K for a target never visited during the episode)
``collisions``
    agent-steps on which an agent shared its node with another
``peak_uncertainty``
    the largest target u seen
``saturated_fraction``
    fraction of steps on which some target sat at the cap u_max
``idle_fraction``
    fraction of agent-steps spent alone on a target that was already at u = 0
    (guarding a cleared target instead of clearing another one)

With agent failures configured (the env's ``failures`` / ``failure_rate``), four more:

``failed_agents``
    agents that failed during the episode
``first_failure_step``
    the step after which the first one failed (K if none did)
``avg_uncertainty_before_failure``
    the mean of the summed target uncertainty over steps
    ``0..f-1`` (``f`` = first_failure_step)
``avg_uncertainty_after_failure``
    the same over steps ``f..K-1``; NaN when no agent failed (there
    is no "after"; a random failure rate may spare an episode)
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

METRIC_NAMES = (
    "avg_uncertainty",
    "max_neglect",
    "collisions",
    "peak_uncertainty",
    "saturated_fraction",
    "idle_fraction",
)


class EpisodeMetrics:
    """Accumulates one episode's metrics; vectorized over targets.

    :param target_indices: ``(T,)`` target node indices.
    :param u_max: the cap, for ``saturated_fraction``.
    :param max_steps: episode length K, to preallocate the uncertainty trace.
    :param n_agents: team size, for ``idle_fraction``.
    """

    def __init__(self, target_indices: np.ndarray, u_max: int, max_steps: int, n_agents: int) -> None:
        self.target_indices = np.asarray(target_indices)
        self.u_max = u_max
        self.n_agents = n_agents
        #: ``(K,)`` summed target uncertainty after each step (only the first ``steps`` are valid).
        self.trace = np.zeros(max_steps, dtype=np.float64)
        self.reset()

    #: Report the failure metrics (set by the env when failures are configured).
    track_failures = False

    def reset(self) -> None:
        n_targets = len(self.target_indices)
        self.steps = 0
        self.failure_steps: list[int] = []
        self.collisions = 0
        self.peak = 0
        self.saturated_steps = 0
        self.idle_agent_steps = 0
        self.live_agent_steps = 0
        self._run = np.zeros(n_targets, dtype=np.int64)
        self._longest = np.zeros(n_targets, dtype=np.int64)

    def update(
        self,
        target_uncertainty: np.ndarray,
        target_presence: np.ndarray,
        n_collided: int,
        n_idle: int,
        n_live: int | None = None,
    ) -> None:
        """Record step ``k``: the targets' ``(T,)`` uncertainties and ``(T,)`` bool presence after
        the move (in ``target_indices`` order), ``n_collided`` agents sharing a node, ``n_idle``
        agents alone on a target at u = 0 and ``n_live`` agents that acted (all of them unless some
        failed)."""
        self.live_agent_steps += self.n_agents if n_live is None else int(n_live)
        u = target_uncertainty
        self._run += 1
        self._run[target_presence] = 0
        np.maximum(self._longest, self._run, out=self._longest)
        # The ufuncs' own reductions: ndarray.sum()/max() add a Python wrapper that costs more
        # than the arithmetic on a few dozen targets. Integer sums, so the order does not matter.
        if self.steps < len(self.trace):
            self.trace[self.steps] = np.add.reduce(u)
        self.steps += 1
        self.collisions += int(n_collided)
        self.idle_agent_steps += int(n_idle)
        highest = int(np.maximum.reduce(u))  # a graph has at least one target (GraphSpec)
        self.peak = max(self.peak, highest)
        self.saturated_steps += highest >= self.u_max

    #: What :meth:`state_dict` keeps: everything :meth:`reset` and :meth:`update` change.
    _STATE = (
        "steps",
        "failure_steps",
        "collisions",
        "peak",
        "saturated_steps",
        "idle_agent_steps",
        "live_agent_steps",
        "_run",
        "_longest",
        "trace",
    )

    def state_dict(self) -> dict[str, Any]:
        """The episode so far, as plain values (a checkpoint's)."""
        return {name: copy.copy(getattr(self, name)) for name in self._STATE}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Put back a :meth:`state_dict` of metrics of the same problem."""
        for name in self._STATE:
            setattr(self, name, copy.copy(state[name]))

    def record_failure(self, n_failed: int) -> None:
        """``n_failed`` agents failed after the step just recorded."""
        self.failure_steps.extend([self.steps] * int(n_failed))

    def summary(self) -> dict[str, float]:
        """The metrics so far (``{}``-like zeros before the first step)."""
        steps = max(self.steps, 1)
        metrics = {
            "avg_uncertainty": float(self.trace[: self.steps].sum() / steps),
            "max_neglect": float(self._longest.max()) if len(self._longest) else 0.0,
            "collisions": float(self.collisions),
            "peak_uncertainty": float(self.peak),
            "saturated_fraction": float(self.saturated_steps / steps),
            "idle_fraction": float(self.idle_agent_steps / max(self.live_agent_steps, 1)),
            "steps": float(self.steps),
        }
        if self.track_failures:
            first = self.failure_steps[0] if self.failure_steps else self.steps
            trace = self.trace[: self.steps]
            metrics["failed_agents"] = float(len(self.failure_steps))
            metrics["first_failure_step"] = float(first)
            metrics["avg_uncertainty_before_failure"] = float(trace[:first].mean()) if first else float("nan")
            after = trace[first:]
            metrics["avg_uncertainty_after_failure"] = float(after.mean()) if len(after) else float("nan")
        return metrics

    def uncertainty_trace(self) -> np.ndarray:
        """``(steps,)`` summed target uncertainty after each step so far (a copy)."""
        return self.trace[: self.steps].copy()
