"""Team-level callbacks: what SB3's ``EvalCallback`` and logger do for one model, for a whole team.

An SB3 callback sees one learner. A :class:`TeamCallback` sees the team, at each rollout barrier,
where every learner has finished its update and none has started the next rollout (the place
checkpoints are taken, :mod:`sb3_pm.agents.training.checkpoints`). Pass one to
:meth:`IndependentPPO.learn <sb3_pm.agents.training.team.IndependentPPO.learn>` as its
``callback``, alone or in a list with learner callbacks.

* :class:`TeamEvalCallback` evaluates the whole team every ``eval_freq`` rollouts on held
  episodes, logs the team's metrics, and keeps the best team so far (lowest mean
  ``avg_uncertainty``), as ``EvalCallback`` keeps ``best_model``.
* :class:`TeamScalars` logs, at every barrier, the team's scalars next to the per-agent runs:
  the mean over the learners of each one's last ``train/*`` values (the episode metrics are
  written out before the update, so the team's own come from :class:`TeamEvalCallback`).

Both write through the team's logger (:meth:`IndependentPPO.set_logger
<sb3_pm.agents.training.team.IndependentPPO.set_logger>`, by default a TensorBoard run
``<tb_log_name>team`` beside the agents' runs when the team has a ``tensorboard_log``).

**Training is unchanged by them.** A callback runs between rollouts, and an evaluation acts with
the team's policies under the process-wide random generators of that moment, which it restores
afterwards; so a seeded run ends with the same parameters with or without them
(``tests/test_team_callbacks.py``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sb3_pm.agents.multiplexing.streams import capture_stream, load_stream
from sb3_pm.errors import InputError


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


class TeamEvalCallback(TeamCallback):
    """Evaluates the team every ``eval_freq`` rollouts and keeps the best one.

    :param eval_freq: rollouts between evaluations (each learner's ``n_steps * n_envs`` steps make
        one rollout).
    :param n_eval_episodes: held episodes per evaluation.
    :param eval_seed: the first held episode's env seed (episode ``i`` uses ``eval_seed + i``);
        keep it apart from the training seeds.
    :param max_cycles: steps per held episode (default: the team's ``max_cycles``).
    :param best_model_save_path: folder where the best team is saved (as ``team/``), or ``None``.
    :param log_path: folder of ``evaluations.json`` (every evaluation's metrics), or ``None``.
    :param deterministic: most likely actions (default) or sampled ones.
    """

    def __init__(
        self,
        eval_freq: int = 10,
        n_eval_episodes: int = 5,
        eval_seed: int = 10_000_000,
        max_cycles: int | None = None,
        best_model_save_path: str | Path | None = None,
        log_path: str | Path | None = None,
        deterministic: bool = True,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        if eval_freq < 1 or n_eval_episodes < 1:
            raise InputError(
                f"eval_freq and n_eval_episodes must be at least 1, got {eval_freq} and {n_eval_episodes}"
            )
        if eval_seed < 0:
            raise InputError(f"eval_seed must be non-negative, got {eval_seed}")
        self.eval_freq, self.n_eval_episodes, self.eval_seed = eval_freq, n_eval_episodes, eval_seed
        self.max_cycles = max_cycles
        self.best_model_save_path = None if best_model_save_path is None else Path(best_model_save_path)
        self.log_path = None if log_path is None else Path(log_path)
        self.deterministic = deterministic
        self.best_mean = math.inf
        #: every evaluation: ``{"timesteps", "avg_uncertainty", "max_neglect", "episodes"}``
        self.evaluations: list[dict[str, Any]] = []

    def _on_barrier(self) -> None:
        # A barrier comes before each rollout: the first, before any training, is skipped.
        if self.n_rollouts and not self.n_rollouts % self.eval_freq:
            self._evaluate()

    def on_training_end(self) -> None:
        """Evaluate the trained team, unless the last barrier did (there is none after the last
        update)."""
        rollouts = int(self.team.num_timesteps // self.team.rollout_size)
        if rollouts != self.n_rollouts and not rollouts % self.eval_freq:
            self.n_rollouts = rollouts
            self._evaluate()

    def _evaluate(self) -> None:
        from sb3_pm.evaluation.harness import evaluate

        state = capture_stream()  # the learners' draws go on as if nothing had run here
        try:
            run = evaluate(
                self.team,
                episodes=self.n_eval_episodes,
                max_cycles=self.max_cycles or int(self.team.env_kwargs.get("max_cycles", 500)),
                seed=self.eval_seed,
                deterministic=self.deterministic,
                progress=False,
                threads=None,  # the training's thread count stands
            )
        finally:
            load_stream(state)
        means = run.mean
        record = {
            "timesteps": int(self.team.num_timesteps),
            "avg_uncertainty": float(means["avg_uncertainty"]),
            "max_neglect": float(means["max_neglect"]),
            "episodes": [float(v) for v in run.values("avg_uncertainty")],
        }
        self.evaluations.append(record)
        for key in ("avg_uncertainty", "max_neglect"):
            self.logger.record(f"eval/{key}", record[key])
        improved = record["avg_uncertainty"] < self.best_mean
        if improved:
            self.best_mean = record["avg_uncertainty"]
            if self.best_model_save_path is not None:
                self.team.save(self.best_model_save_path / "team", overwrite=True)
        self.logger.record("eval/best_avg_uncertainty", self.best_mean)
        self.logger.dump(self.team.num_timesteps)
        if self.log_path is not None:
            self._write_log()
        if self.verbose:
            best = " (new best)" if improved else ""
            print(
                f"team evaluation at {record['timesteps']} steps per learner: avg_uncertainty "
                f"{record['avg_uncertainty']:.1f}, max_neglect {record['max_neglect']:.1f}{best}"
            )

    def _write_log(self) -> None:
        from sb3_pm.files import write_atomic

        assert self.log_path is not None
        self.log_path.mkdir(parents=True, exist_ok=True)
        write_atomic(self.log_path / "evaluations.json", json.dumps(self.evaluations, indent=1))


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


__all__ = ["TeamCallback", "TeamEvalCallback", "TeamScalars", "split_team_callbacks"]
