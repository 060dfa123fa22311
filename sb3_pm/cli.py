"""The ``sb3-pm`` command line: ``sb3-pm <command> --help`` for each command.

Each command lives in its own module under :mod:`sb3_pm.commands` and provides
``register(subparsers)``; it sets ``func`` on its parser. Errors a user can fix (a bad graph, a
missing file, a malformed config: :class:`~sb3_pm.errors.Sb3PmError`, and ``OSError``) print one
line and exit with status 2, not a traceback; any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from sb3_pm.commands.interrupts import exit_status
from sb3_pm.errors import Sb3PmError, UsageError
from sb3_pm.version import __version__

__all__ = ["UsageError", "build_parser", "main"]

#: Command modules, in help order.
COMMAND_MODULES = ("evaluate", "compare", "effect", "bound", "train", "reproduce", "convert_team")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-pm",
        description="Decentralized, safety-aware multi-agent RL for persistent monitoring on graphs.",
    )
    parser.add_argument("--version", action="version", version=f"sb3-pm {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"sb3_pm.commands.{name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    # The command line as typed, for the records commands write (a run's command.txt); from the
    # arguments given rather than sys.argv, so that main([...]) called from Python records its own.
    args.command_line = ["sb3-pm", *(sys.argv[1:] if argv is None else argv)]
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except Sb3PmError as error:  # the project's own errors: problems the user can fix
        print(f"sb3-pm {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # an unwritable path, a missing file, a full disk: the file and the reason
        if error.strerror is None:  # raised with a message of ours, which names the file
            print(f"sb3-pm {args.command}: error: {error}", file=sys.stderr)
        else:
            where = f" {error.filename}:" if error.filename else ""
            print(f"sb3-pm {args.command}: error:{where} {error.strerror}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as interrupt:  # Ctrl-C: 130; SIGTERM where a command handles it: 143
        print(f"sb3-pm {args.command}: interrupted", file=sys.stderr)
        return exit_status(interrupt)


if __name__ == "__main__":
    sys.exit(main())
