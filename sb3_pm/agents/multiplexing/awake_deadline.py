"""A wait deadline that counts only the time the process was running.

A learner waiting for its teammates gives up after the team's ``wait_timeout`` (a stuck learner
must not hang a sweep forever). Measured on the wall clock, that deadline also fires when nothing
is stuck but the whole process was suspended for longer than the timeout: a sweep paused with
``SIGSTOP`` (to free the cores for something else), a laptop asleep, a paused virtual machine. On
waking, every waiter saw its deadline long past and the team stopped. Waiters poll in short slices
(:data:`~sb3_pm.agents.multiplexing.multiplexer.POLL_INTERVAL`), so a slice that took far longer than it asked
for means the process was not running; :class:`AwakeDeadline` moves the deadline back by that gap.
"""

from __future__ import annotations

import time
from collections.abc import Callable

#: A poll slice that overran its request by more than this many seconds is taken as a suspension
#: of the whole process, not as waiting: a slice asks for at most half a second, and even a heavily
#: loaded machine schedules a waiting thread again within a few seconds.
SUSPENSION_GAP = 30.0


class AwakeDeadline:
    """``seconds`` from now, counted only while the process runs (``None``: never).

    Call :meth:`remaining` after every poll slice of at most ``slice_seconds``.

    :param seconds: the time allowed, or ``None`` for no deadline.
    :param slice_seconds: the longest wait the caller asks for between two calls.
    :param clock: a monotonic clock in seconds (injected by tests).
    """

    def __init__(
        self,
        seconds: float | None,
        slice_seconds: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._clock = clock
        self._slice = float(slice_seconds)
        self._last = clock()
        self._end = None if seconds is None else self._last + float(seconds)
        #: seconds the process was found suspended since the deadline was set
        self.suspended = 0.0

    def remaining(self) -> float | None:
        """Seconds left (``<= 0``: the deadline has passed), or ``None`` without a deadline."""
        now = self._clock()
        overrun = now - self._last - self._slice
        if overrun > SUSPENSION_GAP:  # the process was not running: that time does not count
            self.suspended += overrun
            if self._end is not None:
                self._end += overrun
        self._last = now
        return None if self._end is None else self._end - now


__all__ = ["SUSPENSION_GAP", "AwakeDeadline"]
