"""File writes that lose nothing: atomic replacement, and keeping a damaged file or folder aside.

Every layer writes records (run folders, saved teams, sweep cells), so this module depends on
nothing else in the package.
"""

from __future__ import annotations

import hashlib
import os
import time
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


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, then rename it over ``path``: a reader
    (or a crash) sees the old file or the new one, never half of one."""
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


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
