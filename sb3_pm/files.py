"""File writes that lose nothing: atomic replacement, and keeping a damaged file or folder aside.

Every layer writes records (run folders, saved teams, sweep cells), so this module depends on
nothing else in the package.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def sha256_file(path: Path) -> str:
    """The SHA-256 of a file's bytes, as hex (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def checksum_problem(folder: Path, sha256: dict[str, str]) -> tuple[Path, str] | None:
    """The first file of ``folder`` that is missing or no longer matches its recorded SHA-256
    (``{relative name: hex digest}``), with the reason; None when all match."""
    for name, expected in sha256.items():
        path = Path(folder) / name
        if not path.is_file():
            return path, "missing"
        if sha256_file(path) != expected:
            return path, "changed since it was written"
    return None


def temporary_beside(path: Path) -> Path:
    """The temporary name :func:`atomic_path` writes ``path`` under: hidden, in the same folder (so
    that the rename stays on one file system), ending in ``.tmp`` (what run folders ignore)."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def located(error: OSError, path: Path, temporary: Path | None = None) -> OSError:
    """``error`` naming ``path`` where it names no file, or only ``temporary``: a full disk raised
    while writing a temporary file said just "No space left on device", and the command line prints
    the file an error names."""
    names_nothing = error.filename is None or (temporary is not None and error.filename == str(temporary))
    if names_nothing and error.strerror is not None:
        return type(error)(error.errno, error.strerror, str(path))
    return error


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for the block to write; when the block ends, flush
    it to disk and rename it over ``path``. A reader (or a crash, or a full disk) sees the old file
    or the new one, never half of one.

    If the block, the flush or the rename fails, the temporary file is removed (freeing the space
    a full disk needs) and ``path`` is left as it was; an ``OSError`` that names no file is raised
    again naming ``path``.
    """
    path = Path(path)
    temporary = temporary_beside(path)
    try:
        yield temporary
        descriptor = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(descriptor)  # the data on disk before the name points at it
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException as error:
        temporary.unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise located(error, path, temporary) from error
        raise


def write_atomic(path: str | Path, text: str | bytes) -> None:
    """Write ``text`` (or bytes) to ``path`` through :func:`atomic_path`: the old file or the new
    one, never half of one; a failure (a full disk) names ``path`` and leaves the old file intact."""
    with atomic_path(path) as temporary:
        if isinstance(text, bytes):
            temporary.write_bytes(text)
        else:
            temporary.write_text(text)


def append_atomic(path: str | Path, text: str) -> None:
    """Add ``text`` at the end of ``path`` (created if missing) by rewriting it atomically: a
    failed append leaves the file as it was, not with half a line."""
    path = Path(path)
    previous = path.read_text() if path.exists() else ""
    write_atomic(path, previous + text)


def move_aside(path: Path) -> Path:
    """Rename a damaged file or folder to ``<name>.damaged`` (or a timestamped name if that is
    taken) beside it, so that nothing is deleted; returns the new path."""
    aside = path.with_name(f"{path.name}.damaged")
    stamp = time.strftime("%Y%m%dT%H%M%S")
    count = 0
    while aside.exists():
        count += 1
        aside = path.with_name(f"{path.name}.damaged-{stamp}-{count}")
    path.rename(aside)
    return aside
