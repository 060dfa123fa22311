"""Run folders that lose nothing: a lock held for the life of a run, and atomic file writes.

A second ``sb3-pm train --out R --overwrite`` while a first run still trains into ``R`` used to
delete the folder under it; the first run then saved into a folder holding another run's records.
Now every run holds ``R/.lock`` (its process id) from before it touches the folder until it ends, and
``--overwrite`` refuses a folder whose lock belongs to a live process. A lock left by a process
that died (a SIGKILL, a power cut) is recognised as stale and taken over.
"""

from __future__ import annotations

import os
import shutil
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: The lock file inside a run folder.
LOCK = ".lock"
#: Files that mark a folder as a run folder (only such a folder is replaced by --overwrite).
RUN_MARKERS = ("args.yml", "config.yml", "command.txt", "team")


class RunFolderError(Exception):
    """A run folder that cannot be used: in use by another process, or not a run folder."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def lock_owner(folder: Path) -> int | None:
    """The process id holding ``folder``'s lock if that process is alive on this host, else None."""
    path = folder / LOCK
    try:
        pid_text, _, host = path.read_text().partition("@")
        pid = int(pid_text)
    except (OSError, ValueError):
        return None
    if host.strip() and host.strip() != socket.gethostname():
        return pid  # another machine's process: cannot tell, so assume it is alive
    return pid if pid != os.getpid() and _alive(pid) else None


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, then rename it over ``path``: a reader
    (or a crash) sees the old file or the new one, never half of one."""
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


@contextmanager
def locked_run_folder(folder: Path, overwrite: bool) -> Iterator[Path]:
    """Create (or, with ``overwrite``, empty) ``folder`` and hold its lock until the block ends.

    :raises RunFolderError: if another live process holds the lock, the folder exists and is not
        empty without ``overwrite``, or it is not a run folder.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise RunFolderError(f"{folder} exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    owner = lock_owner(folder)
    if owner is not None:
        raise RunFolderError(
            f"run folder {folder} is in use by process {owner}; wait for it to end or choose another --out"
        )
    existing = [entry for entry in folder.iterdir() if entry.name != LOCK]
    if existing and not overwrite:
        raise RunFolderError(f"run folder {folder} already exists; pass --overwrite to replace it")
    if existing and not any((folder / marker).exists() for marker in RUN_MARKERS):
        raise RunFolderError(
            f"{folder} is not empty and does not look like a run folder; refusing to replace it"
        )
    lock = folder / LOCK
    lock.unlink(missing_ok=True)  # stale: its process is gone
    try:
        descriptor = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:  # another process took it between the check and here
        raise RunFolderError(f"run folder {folder} is in use by process {lock_owner(folder)}") from None
    with os.fdopen(descriptor, "w") as handle:
        handle.write(f"{os.getpid()}@{socket.gethostname()}")
    try:
        for entry in existing:  # --overwrite: the old run goes only once the lock is ours
            shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
        yield folder
    finally:
        lock.unlink(missing_ok=True)
