"""Run folders that lose nothing: a lock held for the life of a run, and atomic file writes.

A second ``sb3-pm train --out R --overwrite`` while a first run still trains into ``R`` used to
delete the folder under it; the first run then saved into a folder holding another run's records.
Now every run holds an exclusive ``flock`` on ``R/.lock`` from before it touches the folder until
it ends, and ``--overwrite`` refuses a folder whose lock another process holds. The kernel drops
the lock when its process dies, however it dies, so a lock is never stale. ``--overwrite`` removes
only what a run writes, and refuses a folder that holds anything else.

A sweep (``sb3-pm reproduce --out S``) holds the same lock on ``S/.lock`` for its whole life: a
second sweep on ``S`` is refused instead of training every cell a second time beside the first.
It refuses a folder holding files but no ``experiment.yml`` (the record a sweep writes first), so
that a user's own ``report.md`` or ``results.md`` there is never overwritten; a sweep's folder is
resumed, and files the sweep does not write are left alone in it.

A final team save that failed (a full disk) leaves ``team/`` without its manifest, which is
written last; ``sb3-pm train --resume`` finishes such a run and replaces that ``team/``.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sb3_pm.errors import Sb3PmError
from sb3_pm.machine import MACHINE_RECORD

#: The lock file inside a run folder.
LOCK = ".lock"
#: Files that mark a folder as a run folder.
RUN_MARKERS = ("args.yml", "config.yml", "command.txt", "team")
#: Everything a run writes into its folder: all that ``--overwrite`` may remove.
RUN_ENTRIES = frozenset({*RUN_MARKERS, MACHINE_RECORD, "tb", "checkpoints", "resumed.txt", LOCK})


class RunFolderError(Sb3PmError):
    """A run folder that cannot be used: in use by another process, or not a run folder."""


def _holder(path: Path) -> str:
    try:
        return path.read_text().strip() or "another process"
    except OSError:
        return "another process"


def lock_owner(folder: Path) -> str | None:
    """Who holds ``folder``'s lock (``pid@host``), or None if no other open lock holds it."""
    path = Path(folder) / LOCK
    if not path.exists():
        return None
    holder = _holder(path)
    if holder == f"{os.getpid()}@{socket.gethostname()}":
        return None  # our own lock does not block us
    try:
        descriptor = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return holder
    finally:
        os.close(descriptor)  # closing drops the probe's lock
    return None


def foreign_entries(folder: Path, own: frozenset[str] = RUN_ENTRIES) -> list[str]:
    """Entries of ``folder`` not named in ``own`` (by default: what a run writes); leftover
    temporary files (``.NAME.tmp``) are a run's own."""
    return sorted(
        entry.name
        for entry in folder.iterdir()
        if entry.name not in own and not (entry.name.startswith(".") and entry.name.endswith(".tmp"))
    )


def contents_problem(folder: Path, overwrite: bool) -> str | None:
    """Why the existing contents of ``folder`` may not be replaced, or None if they may."""
    if not folder.is_dir() or not any(entry.name != LOCK for entry in folder.iterdir()):
        return None
    if not overwrite:
        # a team/ without its manifest (written last) is a final save that failed: unfinished too
        if (folder / "checkpoints").is_dir() and not (folder / "team" / "manifest.json").exists():
            return (
                f"run folder {folder} holds an unfinished run; continue it with "
                f"sb3-pm train --resume {folder}, or pass --overwrite to start again"
            )
        return f"run folder {folder} already exists; pass --overwrite to replace it"
    foreign = foreign_entries(folder)
    if foreign:
        return f"{folder} holds files no run writes ({', '.join(foreign[:5])}); refusing to replace it"
    return None


#: The record that marks a folder as a sweep's (``sb3-pm reproduce``), written before anything else.
SWEEP_RECORD = "experiment.yml"


def sweep_folder_problem(folder: Path) -> str | None:
    """Why ``sb3-pm reproduce --out folder`` may not write into ``folder``, or None if it may: an
    existing folder that holds files but no :data:`SWEEP_RECORD` is not a sweep's, and the sweep
    would overwrite any ``report.md``, ``results.md`` or ``command.txt`` in it."""
    folder = Path(folder)
    if not folder.is_dir() or (folder / SWEEP_RECORD).is_file():
        return None
    entries = foreign_entries(folder, frozenset({LOCK}))
    if not entries:
        return None
    return (
        f"--out {folder} holds files no sweep wrote ({', '.join(entries[:5])}) and no {SWEEP_RECORD}; "
        "choose another --out"
    )


def in_use_message(folder: Path, owner: str) -> str:
    """One line: ``folder``'s lock is held by ``owner`` (``pid@host``, or a holder that wrote none)."""
    who = f"process {owner}" if "@" in owner else owner
    return f"run folder {folder} is in use by {who}; wait for it to end or choose another --out"


@contextmanager
def held_lock(folder: Path) -> Iterator[Path]:
    """Hold the exclusive lock of the existing ``folder`` until the block ends (the lock file is
    created if needed and kept afterwards: unlinking it would race).

    :raises RunFolderError: if another live process holds it.
    """
    descriptor = os.open(Path(folder) / LOCK, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunFolderError(in_use_message(folder, _holder(Path(folder) / LOCK))) from None
        os.ftruncate(descriptor, 0)
        os.write(descriptor, f"{os.getpid()}@{socket.gethostname()}".encode())
        yield Path(folder)
    finally:
        os.close(descriptor)  # releases the lock


@contextmanager
def locked_run_folder(folder: Path, overwrite: bool, resume: bool = False) -> Iterator[Path]:
    """Create (or, with ``overwrite``, empty) ``folder`` and hold its lock until the block ends.

    :param resume: lock an existing run folder as it is, to continue its run (nothing is removed).
    :raises RunFolderError: if another live process holds the lock, the folder exists and is not
        empty without ``overwrite``, or it holds files no run writes.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise RunFolderError(f"{folder} exists and is not a folder")
    if resume and not folder.is_dir():
        raise RunFolderError(f"no run folder at {folder}")
    folder.mkdir(parents=True, exist_ok=True)
    with held_lock(folder):
        if resume:
            yield folder
            return
        problem = contents_problem(folder, overwrite)
        if problem is not None:
            raise RunFolderError(problem)
        for entry in [
            entry for entry in folder.iterdir() if entry.name != LOCK
        ]:  # --overwrite: the old run goes only once the lock is ours
            shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
        yield folder


#: The staging folder of a run's final team save, renamed to ``team`` when whole.
STAGING = ".team.tmp"


def save_final_team(team: Any, out: Path) -> Path:
    """Save a trained team to ``out/team``: into :data:`STAGING` first, renamed when whole, so a
    run folder never holds half a team under the name ``team``.

    A ``team/`` already there without its manifest is an earlier final save of this run that
    failed; it is replaced (the caller holds the run's lock). When the save fails (a full disk),
    the staging folder is removed, which frees the space that a checkpoint of the finished
    training (:func:`keep_finished_training`) then needs, so that ``sb3-pm train --resume``
    finishes the save without training again.

    :raises RunFolderError: one line naming the folder, the reason and ``--resume``.
    """
    staging, final = out / STAGING, out / "team"
    try:
        if staging.exists():
            shutil.rmtree(staging)  # a staging folder a crash left
        team.save(staging)
        if final.exists():
            shutil.rmtree(final)
        staging.rename(final)
    except OSError as error:
        shutil.rmtree(staging, ignore_errors=True)
        reason = error.strerror or str(error)
        kept = keep_finished_training(team, out)
        raise RunFolderError(
            f"saving the team to {final} failed ({reason}); {kept}: free space and finish the run "
            f"with sb3-pm train --resume {out}"
        ) from None
    return final


def keep_finished_training(team: Any, out: Path) -> str:
    """Write a checkpoint of ``team`` as its training ended (``--resume`` then only saves it);
    returns what was kept, for the error message. If that fails too, the last periodic checkpoint
    is what ``--resume`` continues from (bit for bit: the same team, trained again from there)."""
    from sb3_pm.agents.training.checkpoints import CHECKPOINTS, CheckpointSchedule, write_checkpoint

    try:
        folder = write_checkpoint(
            team, CheckpointSchedule(out / CHECKPOINTS), team.num_timesteps // team.rollout_size
        )
    except OSError:  # the disk is still full: the error the caller raises says what is kept
        return f"the run resumes from its last checkpoint in {out / CHECKPOINTS}"
    return f"the finished training is kept as checkpoint {folder}"
