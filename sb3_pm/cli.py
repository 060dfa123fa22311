"""The ``sb3-pm`` command line: ``sb3-pm <command> --help`` for each command.

Each command lives in its own module under :mod:`sb3_pm.commands` and provides
``register(subparsers)``; it sets ``func`` on its parser. Errors a user can fix (a bad graph, a
missing file, a malformed config) print one line and exit with status 2, not a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from sb3_pm.version import __version__

#: Command modules, in help order.
COMMAND_MODULES = ("evaluate", "compare", "train", "reproduce")


class UsageError(Exception):
    """A problem with the user's input; the CLI prints its message and exits with status 2."""


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
    from sb3_pm.graphs import GraphError

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
    except (UsageError, GraphError, FileNotFoundError, FileExistsError, ValueError) as error:
        print(f"sb3-pm {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # an unwritable path, a full disk: the file and the reason, in one line
        where = f" {error.filename}" if getattr(error, "filename", None) else ""
        print(f"sb3-pm {args.command}: error:{where}: {error.strerror or error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sb3-pm {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
