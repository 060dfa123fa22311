"""Trained teams that ship with the package: ``--policy pretrained:<name>``.

Each is a saved team folder (the safe format: a manifest and one SB3 zip per agent, read without
unpickling) under ``sb3_pm/pretrained/<name>/``, as ``sb3-pm train`` saved it (optimizer states
included, so it can train on), with ``provenance.json`` saying which command, code version and
seed made it and what it scored.

=============== ==============================================================================
name             team
=============== ==============================================================================
paper-50         the default configuration (``zoo/ippo.yml``: planned territories) trained on the
                 paper's 50-node graph at the paper's budget, seed 0
transfer         the transfer configuration (``zoo/ippo_transfer.yml``: planned territories, the
                 rule's move with a prior of 4 and taught after each update, the filter's rule
                 10 at deployment) trained on random graphs of 20 to 60 nodes, seed 0: deploy it
                 on any graph (``--graph``; on large sites with ``--territories planned_tours``)
transfer_prior4  the transfer configuration before it (``zoo/ippo_transfer_prior4.yml``: the same
                 without the teaching and rule 10), seed 0
transfer_split   the one before that (``zoo/ippo_transfer_split.yml``: split territories, a prior
                 of 2, a neglect bound calibrated on each site), seed 0
=============== ==============================================================================
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sb3_pm.errors import InputError

#: What names a pretrained team in ``--policy``.
PREFIX = "pretrained:"
_FOLDER = Path(__file__).resolve().parent


def pretrained_names() -> list[str]:
    """The names of the shipped pretrained teams."""
    return sorted(p.name for p in _FOLDER.iterdir() if (p / "manifest.json").is_file())


def pretrained_path(name: str) -> Path:
    """The folder of the pretrained team ``name`` (with or without the ``pretrained:`` prefix).

    :raises InputError: for a name that ships no team.
    """
    name = name.removeprefix(PREFIX)
    folder = _FOLDER / name
    if "/" in name or "\\" in name or not (folder / "manifest.json").is_file():
        raise InputError(f"no pretrained team {name!r}: use one of {', '.join(pretrained_names()) or 'none'}")
    return folder


def provenance(name: str) -> dict[str, Any]:
    """How the pretrained team ``name`` was made and what it scored (its ``provenance.json``)."""
    return dict(json.loads((pretrained_path(name) / "provenance.json").read_text()))


__all__ = ["PREFIX", "pretrained_names", "pretrained_path", "provenance"]
