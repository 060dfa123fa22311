"""Team checkpoints: everything needed to continue a training run bit for bit.

A checkpoint is taken at a rollout barrier
(:class:`~sb3_pm.agents.multiplexing.agent_vec_env.RolloutBarrier`), where every learner has finished
``train()`` and its estimator fit and none has started the next
rollout. What the run still depends on at that point is saved:

* the learners, as a saved team (SB3 zips: parameters, optimizer states, step counts; a manifest
  with their settings);
* the env copies (node uncertainties, positions, mental maps, their generators), the multiplexer's
  running episode returns, lengths and last observations, and every learner's random stream
  (:mod:`sb3_pm.agents.multiplexing.streams`) and rollout state (last observation, episode buffers):
  :mod:`sb3_pm.agents.training.checkpoint_state`.

Layout, inside a run folder::

    checkpoints/
      rollout_000010/       the barrier after 10 rollouts (counted from the run's start)
        manifest.json ...   a saved team (see :mod:`sb3_pm.agents.deployment.saved_teams`)
        state.json          env copies, counters, random streams, learner rollout state (JSON) ...
        state.npz           ... and their arrays
        checkpoint.json     written last: step counts and the SHA-256 of every file

Nothing in a checkpoint is code: the team is rebuilt from its manifest and given the zips' tensors
(``torch.load(..., weights_only=True)``), the state is JSON and arrays read with
``allow_pickle=False``. The checksums catch damage (a truncated or edited file), not a forger, who
can rewrite them too; resuming from a crafted checkpoint fails or trains from other numbers, and
runs nothing.

A checkpoint is written to a hidden temporary folder and renamed into place, so a crash leaves the
previous checkpoints intact; the ``keep`` newest are kept. On resume, a checkpoint whose files no
longer match their checksums is skipped with a warning, and the one before it is used. A
checkpoint is resumed only by the sb3_pm version that wrote it (``checkpoint.json`` records it).
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_pm.agents.training.checkpoint_state import read_team_state, write_team_state
from sb3_pm.errors import InputError
from sb3_pm.files import checksum_problem, move_aside, sha256_file, write_atomic
from sb3_pm.version import __version__

if TYPE_CHECKING:
    from sb3_pm.agents.training.team import IndependentPPO

logger = logging.getLogger(__name__)

#: The checkpoints folder of a run folder.
CHECKPOINTS = "checkpoints"
#: The file a checkpoint writes last.
RECORD = "checkpoint.json"
RECORD_FORMAT = "sb3_pm.checkpoint/2"
#: Checkpoints whose state was a pickle: refused (resume them with the version that wrote them).
OLD_RECORD_FORMATS = ("sb3_pm.checkpoint/1",)


class CheckpointError(InputError):
    """No usable checkpoint: none written yet, all damaged, or from another sb3_pm version."""


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on Ctrl-C after writing a checkpoint; ``checkpoint`` is its folder."""

    def __init__(self, checkpoint: Path) -> None:
        super().__init__(f"interrupted; checkpoint saved to {checkpoint}")
        self.checkpoint = Path(checkpoint)


@dataclass
class CheckpointSchedule:
    """When and where a team writes checkpoints during ``learn()``.

    :param folder: the checkpoints folder (created when the first checkpoint is written).
    :param every: write one at every ``every``-th rollout barrier (counted from step 0), and always
        when a stop was requested (Ctrl-C).
    :param keep: how many of the newest checkpoints to keep (at least 1).
    :param every_seconds: also write one at the first barrier this many seconds after the last
        checkpoint (or the schedule's start), so a long rollout interval cannot cost a cut session
        hours of training; ``None``: by rollouts only. Writing a checkpoint never changes training.
    """

    folder: Path
    every: int = 10
    keep: int = 2
    every_seconds: float | None = None

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        if self.every < 1:
            raise InputError(f"checkpoint every must be at least 1 rollout, got {self.every}")
        if self.keep < 1:
            raise InputError(f"checkpoints to keep must be at least 1, got {self.keep}")
        if self.every_seconds is not None and not self.every_seconds > 0:
            raise InputError(f"checkpoint every_seconds must be positive, got {self.every_seconds}")
        #: the last checkpoint written or resumed from
        self.last: Path | None = None
        #: when the last checkpoint was due (time.monotonic()), for ``every_seconds``
        self.since = time.monotonic()

    def due(self, rollouts: int, stop_requested: bool) -> bool:
        """Whether the barrier after ``rollouts`` rollouts writes a checkpoint (the clock of
        ``every_seconds`` restarts when it does)."""
        late = self.every_seconds is not None and time.monotonic() - self.since >= self.every_seconds
        if rollouts > 0 and (stop_requested or rollouts % self.every == 0 or late):
            self.since = time.monotonic()
            return True
        return False


def checkpoint_name(rollouts: int) -> str:
    return f"rollout_{rollouts:06d}"


def write_checkpoint(team: IndependentPPO, schedule: CheckpointSchedule, rollouts: int) -> Path:
    """Save ``team`` (stopped at a rollout barrier) as checkpoint ``rollouts``; returns its folder.

    An existing checkpoint of that name is kept as it is: it holds this very state (a resumed run
    meets its own starting checkpoint again at its first barrier).
    """
    final = schedule.folder / checkpoint_name(rollouts)
    if final.is_dir() and (final / RECORD).is_file():
        try:
            read_record(final)
        except CheckpointError as error:  # damaged: kept aside, written again
            logger.warning("checkpoint %s kept as %s and written again: %s", final, move_aside(final), error)
        else:
            schedule.last = final
            return final
    schedule.folder.mkdir(parents=True, exist_ok=True)
    temporary = schedule.folder / f".{final.name}.tmp"
    if temporary.exists():
        shutil.rmtree(temporary)  # a checkpoint a crash left half written
    team.save(temporary)
    write_team_state(team, temporary)
    model = team.models[team.agents[0]]
    record = {
        "format": RECORD_FORMAT,
        "sb3_pm": __version__,
        "rollouts": rollouts,
        "num_timesteps": int(model.num_timesteps),
        "total_timesteps": int(model._total_timesteps),
        "sha256": {path.name: sha256_file(path) for path in sorted(temporary.iterdir()) if path.is_file()},
    }
    write_atomic(temporary / RECORD, json.dumps(record, indent=1, sort_keys=True) + "\n")
    if final.exists():
        shutil.rmtree(final)  # an incomplete folder of that name (no record): never a finished one
    temporary.rename(final)
    schedule.last = final
    _prune(schedule)
    return final


def checkpoint_at_barrier(team: IndependentPPO, schedule: CheckpointSchedule | None) -> str | None:
    """A team's rollout-barrier hook (the multiplexer's ``on_sync``): write a checkpoint when one
    is due; after an interrupt, write one and return the reason to stop the team."""
    if schedule is None:
        return None
    rollouts = team.num_timesteps // team.rollout_size
    if not schedule.due(rollouts, team.hub.stop_requested):
        return None
    folder = write_checkpoint(team, schedule, rollouts)
    logger.info("checkpoint %s written", folder)
    return f"interrupted; checkpoint {folder} saved" if team.hub.stop_requested else None


def _prune(schedule: CheckpointSchedule) -> None:
    """Remove all but the ``keep`` newest finished checkpoints."""
    finished = sorted(p for p in schedule.folder.glob("rollout_*") if (p / RECORD).is_file())
    for old in finished[: -schedule.keep]:
        shutil.rmtree(old)


def read_record(folder: Path) -> dict[str, Any]:
    """A checkpoint's ``checkpoint.json``, checked against its files.

    :raises CheckpointError: if it is missing, malformed, from another sb3_pm version, or a file
        does not match its checksum (naming the file).
    """
    path = folder / RECORD
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{folder} is not a finished checkpoint ({RECORD} is missing)") from None
    except ValueError as error:
        raise CheckpointError(f"{path} is not valid JSON ({error})") from None
    if isinstance(record, dict) and record.get("format") in OLD_RECORD_FORMATS:
        raise CheckpointError(
            f"{folder} is a checkpoint in the old format {record['format']!r}, whose state is a pickle "
            "(loading it can run code); resume it with the sb3_pm version that wrote it"
        )
    if not isinstance(record, dict) or record.get("format") != RECORD_FORMAT:
        raise CheckpointError(f"{path} is not an sb3_pm checkpoint record")
    if record.get("sb3_pm") != __version__:
        raise CheckpointError(
            f"{folder} was written by sb3_pm {record.get('sb3_pm')}, this is {__version__}; "
            "resume it with that version"
        )
    problem = checksum_problem(folder, record["sha256"])
    if problem is not None:
        file, reason = problem
        raise CheckpointError(f"{file} is damaged ({reason})")
    return dict(record)


def latest_checkpoint(folder: Path) -> tuple[Path, dict[str, Any]]:
    """The newest intact checkpoint in the checkpoints ``folder`` and its record.

    Damaged newer ones are skipped with a warning (and left where they are).

    :raises CheckpointError: if there is none.
    """
    candidates = sorted(Path(folder).glob("rollout_*"), reverse=True) if Path(folder).is_dir() else []
    problems = []
    for candidate in candidates:
        try:
            return candidate, read_record(candidate)
        except CheckpointError as error:
            logger.warning("skipping checkpoint %s: %s", candidate, error)
            problems.append(str(error))
    if problems:
        raise CheckpointError(f"no intact checkpoint in {folder}: {problems[0]}")
    raise CheckpointError(f"no checkpoint in {folder}")


def find_checkpoint(path: str | Path) -> Path:
    """The checkpoint at ``path``: a checkpoint folder (its files checked against their checksums),
    or the newest intact one in a ``checkpoints/`` folder or a run folder holding one.

    :raises CheckpointError: if there is no intact checkpoint there.
    """
    folder = Path(path)
    if (folder / RECORD).is_file():
        read_record(folder)  # checks every file against its checksum
        return folder
    parent = folder / CHECKPOINTS if (folder / CHECKPOINTS).is_dir() else folder
    return latest_checkpoint(parent)[0]


def restore_state(team: IndependentPPO, checkpoint: Path) -> None:
    """Put a checkpoint's env copies, counters, random streams and learner rollout state into a
    team loaded from it (nothing in the files is unpickled).

    :raises CheckpointError: if the state files are malformed or do not match the team.
    """
    try:
        read_team_state(team, checkpoint)
    except InputError as error:
        raise CheckpointError(f"{checkpoint}: {error}") from None


__all__ = [
    "CHECKPOINTS",
    "CheckpointError",
    "CheckpointSchedule",
    "TrainingInterrupted",
    "checkpoint_at_barrier",
    "latest_checkpoint",
    "read_record",
    "restore_state",
    "write_checkpoint",
]
