"""Finished sweep cells that can be trusted: ``DONE`` records a checksum of what the cell wrote.

A resumed sweep reads finished cells back instead of re-running them. A truncated
``evaluation.json`` used to stop the whole sweep with a JSON message that named no file, and a
damaged team zip in a finished cell was never noticed. Now ``DONE`` holds the SHA-256 of
``evaluation.json`` and of every file of the saved team, and a cell whose files no longer match
is reported and run again.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from sb3_pm.files import checksum_problem, move_aside, sha256_file, write_atomic

#: The file a cell writes last.
DONE = "DONE"


def cell_files(folder: Path) -> list[Path]:
    """The files a finished cell vouches for: its evaluation and its saved team, if any."""
    team = (
        sorted(p for p in (folder / "team").rglob("*") if p.is_file()) if (folder / "team").is_dir() else []
    )
    return [folder / "evaluation.json", *team]


def write_done(folder: Path) -> None:
    """Mark ``folder`` finished, with the checksum of every file it vouches for."""
    record = {
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "sha256": {str(p.relative_to(folder)): sha256_file(p) for p in cell_files(folder)},
    }
    write_atomic(folder / DONE, json.dumps(record, indent=1) + "\n")


def check_done(folder: Path) -> tuple[Path, str] | None:
    """The first file of the finished cell in ``folder`` that cannot be trusted, with the reason,
    or None when all can.

    A ``DONE`` written before checksums existed (a plain timestamp) is trusted when its
    ``evaluation.json`` parses.
    """
    evaluation = folder / "evaluation.json"
    try:
        json.loads(evaluation.read_text())
    except (OSError, ValueError) as error:
        return evaluation, f"unreadable ({error})"
    try:
        record = json.loads((folder / DONE).read_text())
    except ValueError:
        return None  # the older plain-text DONE
    if not isinstance(record, dict) or not isinstance(record.get("sha256", {}), dict):
        return folder / DONE, "not a DONE record"
    problem = checksum_problem(folder, record.get("sha256", {}))
    if problem is not None and problem[1] != "missing":
        return problem[0], "changed since the cell finished"
    return problem


def reopen_damaged_cell(folder: Path) -> str | None:
    """If the finished cell in ``folder`` is damaged, make it unfinished so the sweep runs it again.

    A damaged team is moved aside to ``team.damaged`` (kept, not deleted), so the cell is trained
    again; a damaged evaluation alone only needs the evaluation run again.

    :return: a one-line description of the damage, or None if the cell is sound.
    """
    problem = check_done(folder)
    if problem is None:
        return None
    path, reason = problem
    (folder / DONE).unlink()
    team = folder / "team"
    if team in path.parents and team.is_dir():
        move_aside(team)
    return f"{path}: {reason}"
