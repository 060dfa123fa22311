"""``sb3-pm convert-team OLD NEW``: convert a team saved in the old format to the current one.

Teams saved before the current format (``sb3_pm.team/1``, ``sb3_pm.centralized/1``) could only be
loaded by unpickling their SB3 zips, which runs whatever a crafted file holds, so sb3_pm refuses to
load them. This command loads one that way **once, on your word that you trust it** (you trained
it, or got it from a source you would run code from), and saves it in the current format, which
loads without unpickling (:mod:`sb3_pm.agents.training.legacy_teams`). The new folder is checked:
loaded the safe way, it has the same parameters, bit for bit.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "convert-team",
        help="convert a team saved in the old format (trusted files only: loading it runs its pickles)",
        description=(
            "Load OLD, a team saved in the old format, the old way (SB3's load, which unpickles the "
            "zips and can run code stored in them: only for files you trust), and save it to NEW in "
            "the current format, which loads without unpickling."
        ),
    )
    parser.add_argument("old", type=Path, metavar="OLD", help="the old team's folder (or its run folder)")
    parser.add_argument("new", type=Path, metavar="NEW", help="the folder to save the converted team to")
    parser.add_argument("--overwrite", action="store_true", help="replace a team already in NEW")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sb3_pm.agents.training.legacy_teams import convert_team

    folder = convert_team(args.old, args.new, overwrite=args.overwrite)
    print(f"converted {args.old} to {folder}")
    return 0
