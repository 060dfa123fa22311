"""The team evaluation callback: SB3's ``EvalCallback`` for a whole team.

:class:`TeamEvalCallback` is a :class:`~sb3_pm.agents.training.team_callbacks.TeamCallback`: at
every ``eval_freq``-th rollout barrier of a team's ``learn()``, where every learner has finished
its update, it evaluates the whole team on held episodes (:func:`~sb3_pm.evaluation.evaluate`),
logs the team's metrics through the team's logger, and saves the best team so far (lowest mean
``avg_uncertainty``), as ``EvalCallback`` keeps ``best_model``. It restores the process-wide random
generators it drew from, so a seeded run trains the same parameters with or without it.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

from sb3_pm.agents.multiplexing.streams import capture_stream, load_stream
from sb3_pm.agents.training.team_callbacks import TeamCallback
from sb3_pm.errors import InputError
from sb3_pm.evaluation.harness import evaluate
from sb3_pm.files import write_atomic

#: The best team's score, beside it in ``best_model_save_path``.
BEST_RECORD = "best.json"


class TeamEvalCallback(TeamCallback):
    """Evaluates the team every ``eval_freq`` rollouts and keeps the best one.

    :param eval_freq: rollouts between evaluations (each learner's ``n_steps * n_envs`` steps make
        one rollout).
    :param n_eval_episodes: held episodes per evaluation.
    :param eval_seed: the first held episode's env seed (episode ``i`` uses ``eval_seed + i``);
        keep it apart from the training seeds.
    :param max_cycles: steps per held episode (default: the team's ``max_cycles``).
    :param best_model_save_path: folder where the best team is saved (as ``team/``, with its score
        in ``best.json``; a team already there is replaced only by a better one), or ``None``.
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
                self._save_best(record)
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

    def _init_callback(self) -> None:
        # A resumed run (or another run into the same folder) keeps the best team saved there
        # unless it does better.
        if self.best_model_save_path is not None and (self.best_model_save_path / BEST_RECORD).is_file():
            saved = json.loads((self.best_model_save_path / BEST_RECORD).read_text())
            self.best_mean = min(self.best_mean, float(saved["avg_uncertainty"]))

    def _save_best(self, record: dict[str, Any]) -> None:
        """Save the team as ``best_model_save_path/team``, staged and renamed into place, so a
        crash leaves the previous best team whole; then its score, in :data:`BEST_RECORD`."""
        assert self.best_model_save_path is not None
        folder = self.best_model_save_path
        folder.mkdir(parents=True, exist_ok=True)
        staging, previous, target = folder / ".team.tmp", folder / ".team.old", folder / "team"
        for leftover in (staging, previous):
            shutil.rmtree(leftover, ignore_errors=True)
        self.team.save(staging)
        if target.exists():
            target.rename(previous)
        staging.rename(target)
        shutil.rmtree(previous, ignore_errors=True)
        best = {"avg_uncertainty": record["avg_uncertainty"], "timesteps": record["timesteps"]}
        write_atomic(folder / BEST_RECORD, json.dumps(best, indent=1))

    def _write_log(self) -> None:
        assert self.log_path is not None
        self.log_path.mkdir(parents=True, exist_ok=True)
        write_atomic(self.log_path / "evaluations.json", json.dumps(self.evaluations, indent=1))


__all__ = ["TeamEvalCallback"]
