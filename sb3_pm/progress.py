"""Progress of long runs: a tqdm bar on a terminal, periodic plain lines anywhere else.

A run whose output goes to a file or a CI log would otherwise show nothing for minutes (a tqdm
bar disables itself there, and a redrawn bar in a log is unreadable). This module has no
dependency on the rest of the package, so every layer may use it.
"""

from __future__ import annotations

import os
import sys
import time
from typing import IO, Any

from sb3_pm.errors import InputError

#: Seconds between two plain progress lines; ``SB3_PM_PROGRESS_SECONDS`` overrides it.
DEFAULT_INTERVAL = 30.0


def _interval() -> float:
    text = os.environ.get("SB3_PM_PROGRESS_SECONDS")
    if text is None:
        return DEFAULT_INTERVAL
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"SB3_PM_PROGRESS_SECONDS must be a number of seconds, got {text!r}") from None
    if not value >= 0:  # also refuses nan, which would silence every line
        raise InputError(f"SB3_PM_PROGRESS_SECONDS must be at least 0, got {text!r}")
    return value


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


class PlainProgress:
    """Prints ``desc: done/total unit (p%), elapsed, ~left`` at most every ``interval`` seconds,
    and once more when closed. Same ``update``/``close`` interface as a tqdm bar.

    :param total: the amount of work, in ``unit``.
    :param interval: seconds between lines (0 prints on every update).
    """

    def __init__(
        self,
        total: int,
        desc: str,
        unit: str = "it",
        interval: float | None = None,
        stream: IO[str] | None = None,
    ) -> None:
        self.total, self.desc, self.unit = int(total), desc, unit
        self.interval = _interval() if interval is None else float(interval)
        self.stream = stream if stream is not None else sys.stderr
        self.n = 0
        self._start = self._last = time.monotonic()
        self._closed = False

    def update(self, n: int = 1) -> None:
        self.n += int(n)
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            self._print(now)

    def set_description(self, desc: str) -> None:
        self.desc = desc

    def _print(self, now: float) -> None:
        elapsed = now - self._start
        share = self.n / self.total if self.total else 1.0
        left = f", ~{_clock(elapsed * (1 - share) / share)} left" if 0 < share < 1 else ""
        print(
            f"{self.desc}: {self.n}/{self.total} {self.unit} ({100 * share:.0f}%), "
            f"{_clock(elapsed)} elapsed{left}",
            file=self.stream,
            flush=True,
        )

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._print(time.monotonic())


def progress_bar(
    total: int, desc: str, unit: str = "it", enabled: bool | None = True, stream: IO[str] | None = None
) -> Any:
    """A progress reporter with ``update(n)`` and ``close()``, or None when ``enabled`` is False.

    On a terminal it is a tqdm bar; otherwise a :class:`PlainProgress` that prints a line every
    ``SB3_PM_PROGRESS_SECONDS`` (default 30) seconds. ``enabled=None`` means the same as True: the
    caller has no opinion, and progress is always worth seeing on a long run.
    """
    if enabled is False:
        return None
    stream = stream if stream is not None else sys.stderr
    if hasattr(stream, "isatty") and stream.isatty():
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit, file=stream, leave=False)
    return PlainProgress(total, desc, unit, stream=stream)
