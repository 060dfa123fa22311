"""The team's wait deadline counts only the time the process ran (a suspended sweep resumes)."""

from __future__ import annotations

import pytest

from sb3_pm.agents.multiplexing.awake_deadline import SUSPENSION_GAP, AwakeDeadline


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_deadline_passes_after_its_seconds_of_polling() -> None:
    clock = FakeClock()
    deadline = AwakeDeadline(10.0, slice_seconds=0.5, clock=clock)
    for _ in range(19):
        clock.now += 0.5
        remaining = deadline.remaining()
        assert remaining is not None and remaining > 0
    clock.now += 0.5
    assert deadline.remaining() == pytest.approx(0.0)
    assert deadline.suspended == 0.0


def test_a_suspension_does_not_count() -> None:
    """A process stopped for an hour between two poll slices wakes with its time still left."""
    clock = FakeClock()
    deadline = AwakeDeadline(10.0, slice_seconds=0.5, clock=clock)
    clock.now += 2.0
    assert deadline.remaining() == pytest.approx(8.0)
    clock.now += 3600.0  # SIGSTOP ... SIGCONT
    assert deadline.remaining() == pytest.approx(8.0 - 0.5)  # only the slice it asked for counts
    assert deadline.suspended == pytest.approx(3600.0 - 0.5)
    for _ in range(15):  # and it still times out once the remaining time has been waited
        clock.now += 0.5
        deadline.remaining()
    remaining = deadline.remaining()
    assert remaining is not None and remaining <= 0


def test_a_slow_slice_below_the_gap_still_counts() -> None:
    """A loaded machine that reschedules a waiter late is waiting, not suspended."""
    clock = FakeClock()
    deadline = AwakeDeadline(60.0, slice_seconds=0.5, clock=clock)
    clock.now += SUSPENSION_GAP  # overran by less than the gap
    assert deadline.remaining() == pytest.approx(60.0 - SUSPENSION_GAP)
    assert deadline.suspended == 0.0


def test_no_deadline() -> None:
    clock = FakeClock()
    deadline = AwakeDeadline(None, slice_seconds=0.5, clock=clock)
    clock.now += 1e6
    assert deadline.remaining() is None
