"""SIGTERM handled like Ctrl-C, so that a command stopped either way keeps what it finished.

A cluster's preemption or ``kill`` sends SIGTERM, whose default action ends the process at once:
no ``finally`` block runs, so nothing finished is written and temporary files stay. Inside
:func:`sigterm_as_interrupt`, SIGTERM raises :class:`Terminated` instead, a ``KeyboardInterrupt``:
the code that keeps finished work on Ctrl-C keeps it on SIGTERM too, and the command line exits
with the conventional status 128 + 15 = 143 (130 for Ctrl-C).
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

#: Exit status of a command stopped by Ctrl-C (128 + SIGINT).
INTERRUPTED = 128 + signal.SIGINT


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as an interrupt; ``exit_status`` is 143 (128 + SIGTERM)."""

    exit_status = 128 + signal.SIGTERM


def exit_status(interrupt: BaseException) -> int:
    """The exit status for an interrupt: its own ``exit_status`` if it has one, else 130."""
    return int(getattr(interrupt, "exit_status", INTERRUPTED))


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Raise :class:`Terminated` on SIGTERM while the block runs (outside the main thread, where
    signals cannot be handled, the block runs with signals left alone)."""

    def interrupt(signum: int, frame: Any) -> None:
        raise Terminated

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
