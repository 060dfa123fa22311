"""Team-level callbacks: what SB3's ``EvalCallback`` and logger do for one model, for a whole team.

An SB3 callback sees one learner. A :class:`TeamCallback` sees the team, at each rollout barrier,
where every learner has finished its update and none has started the next rollout (the place
checkpoints are taken, :mod:`sb3_pm.agents.training.checkpoints`). Pass one to
:meth:`IndependentPPO.learn <sb3_pm.agents.training.team.IndependentPPO.learn>` as its
``callback``, alone or in a list with learner callbacks.

* :class:`~sb3_pm.evaluation.team_eval_callback.TeamEvalCallback` evaluates the whole team every
  ``eval_freq`` rollouts on held episodes, logs the team's metrics, and keeps the best team so far
  (lowest mean ``avg_uncertainty``), as ``EvalCallback`` keeps ``best_model``.
* :class:`TeamScalars` logs, at every barrier, the team's scalars next to the per-agent runs:
  the mean over the learners of each one's last ``train/*`` values (the episode metrics are
  written out before the update, so the team's own come from the evaluation callback).

Both write through the team's logger (:meth:`IndependentPPO.set_logger
<sb3_pm.agents.training.team.IndependentPPO.set_logger>`, by default a TensorBoard run
``<tb_log_name>team`` beside the agents' runs when the team has a ``tensorboard_log``).

**Training is unchanged by them.** A callback runs between rollouts, and the evaluation callback
acts with the team's policies under the process-wide random generators of that moment, which it
restores afterwards; so a seeded run ends with the same parameters with or without them
(``tests/test_team_callbacks.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class TeamCallback:
    """Called at every rollout barrier of a team's ``learn()``; see the module docstring."""

    def __init__(self, verbose: int = 0) -> None:
        self.verbose = verbose
        self.team: Any = None
        self.logger: Any = None
        #: rollouts done by every learner, at the last barrier
        self.n_rollouts = 0

    def init_callback(self, team: Any, logger: Any) -> None:
        """Bind the team and its logger, at the start of ``learn()``."""
        self.team, self.logger = team, logger
        self._init_callback()

    def _init_callback(self) -> None:
        """Subclasses' set-up, once the team is bound."""

    def on_barrier(self) -> None:
        """Every learner has finished its update: act on the team."""
        self.n_rollouts = int(self.team.num_timesteps // self.team.rollout_size)
        self._on_barrier()

    def _on_barrier(self) -> None:
        raise NotImplementedError

    def on_training_end(self) -> None:
        """``learn()`` is returning."""


class TeamScalars(TeamCallback):
    """Logs the mean over the learners of their last ``train/*`` values."""

    PREFIXES = ("train/",)

    def _on_barrier(self) -> None:
        sums: dict[str, list[float]] = {}
        for model in self.team.models.values():
            values = getattr(getattr(model, "_logger", None), "name_to_value", {})
            for key, value in values.items():
                if key.startswith(self.PREFIXES) and isinstance(value, (int, float)) and math.isfinite(value):
                    sums.setdefault(key, []).append(float(value))
        for key, values in sums.items():
            self.logger.record(f"team/{key}", float(np.mean(values)))
        if sums:
            self.logger.dump(self.team.num_timesteps)


def split_team_callbacks(callback: Any) -> tuple[Any, list[TeamCallback]]:
    """``callback`` (what ``learn()`` was given) without its :class:`TeamCallback` objects, and
    those objects: one, or the ones in a list. What is left of a list is none, its one learner
    callback, or the per-agent list."""
    if isinstance(callback, TeamCallback):
        return None, [callback]
    if not isinstance(callback, list) or not any(isinstance(c, TeamCallback) for c in callback):
        return callback, []
    team = [c for c in callback if isinstance(c, TeamCallback)]
    rest = [c for c in callback if not isinstance(c, TeamCallback)]
    return (None if not rest else rest[0] if len(rest) == 1 else rest), team


__all__ = ["TeamCallback", "TeamScalars", "split_team_callbacks"]
