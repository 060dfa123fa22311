"""Progress off a terminal: plain lines at an interval, a last line on close, nothing when disabled."""

from __future__ import annotations

import io

import pytest

from sb3_pm.progress import PlainProgress, progress_bar


def test_plain_lines_when_the_stream_is_not_a_terminal() -> None:
    stream = io.StringIO()
    bar = progress_bar(100, "grazing on paper-50", unit="step", stream=stream)
    assert isinstance(bar, PlainProgress)
    bar.interval = 0.0  # a line on every update
    bar.update(25)
    bar.update(25)
    bar.close()
    bar.close()  # closing twice prints once
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("grazing on paper-50: 25/100 step (25%)") and "left" in lines[0]
    assert lines[-1].startswith("grazing on paper-50: 50/100 step (50%)")
    assert len(lines) == 3


def test_the_interval_limits_the_lines(monkeypatch) -> None:
    monkeypatch.setenv("SB3_PM_PROGRESS_SECONDS", "3600")
    stream = io.StringIO()
    bar = progress_bar(10, "sweep", unit="cell", stream=stream)
    for _ in range(10):
        bar.update(1)
    assert stream.getvalue() == ""  # an hour has not passed
    bar.close()
    assert stream.getvalue().strip() == "sweep: 10/10 cell (100%), 0:00:00 elapsed"


def test_disabled_means_nothing() -> None:
    assert progress_bar(10, "x", enabled=False) is None


@pytest.mark.parametrize("text", ["soon", "-1", "nan"])
def test_a_bad_interval_is_a_clear_error(monkeypatch, text) -> None:
    monkeypatch.setenv("SB3_PM_PROGRESS_SECONDS", text)
    with pytest.raises(ValueError, match="SB3_PM_PROGRESS_SECONDS"):
        progress_bar(10, "x", stream=io.StringIO())


def test_evaluate_reports_progress_off_a_terminal(capsys, monkeypatch) -> None:
    """What `sb3-pm evaluate` does in a log file: lines on stderr, with the policy and graph."""
    from sb3_pm.baselines import make_team
    from sb3_pm.evaluation import evaluate

    monkeypatch.setenv("SB3_PM_PROGRESS_SECONDS", "0")
    evaluate(make_team("grazing"), "paper-50", episodes=2, max_cycles=60, progress=None)
    err = capsys.readouterr().err
    assert "grazing on paper-50: 120/120 step (100%)" in err
