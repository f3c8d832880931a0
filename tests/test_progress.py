"""progress.py: the Reporter that a long command hands down its phases, and durations as people read them."""

from __future__ import annotations

import pytest

from lagrseq import progress
from lagrseq.progress import Reporter, duration, ignore


def test_warnings_go_to_their_own_channel_with_the_lines_or_nowhere() -> None:
    lines: list[str] = []
    warnings: list[str] = []
    both = Reporter(lines.append, warnings.append)
    both.say("planned")
    both.warn("failed: fig6a")
    assert lines == ["planned"] and warnings == ["failed: fig6a"]
    alone = Reporter(lines.append)
    alone.warn("failed: table2")
    assert lines == ["planned", "failed: table2"]
    lines_only = Reporter(lines.append, ignore)
    lines_only.say("resuming")
    lines_only.warn("failed: fig7")
    assert lines == ["planned", "failed: table2", "resuming"] and warnings == ["failed: fig6a"]


def test_runs_and_calibrations_move_the_bar_it_shows(capsys: pytest.CaptureFixture[str]) -> None:
    reporter = Reporter(lambda _line: None)
    reporter.on_run("cube-stacking lagr-seq")  # no bar yet: nothing to move, nothing raised
    reporter.on_calibrated()
    with progress.bar(3, "experiment", "calibration") as reporter.bar:
        reporter.on_calibrated()
        reporter.on_calibrated()
        reporter.on_run("cube-stacking lagr-seq")
        assert reporter.bar.n == 2 and reporter.bar.desc.startswith("cube-stacking lagr-seq")
    assert "cube-stacking lagr-seq" in capsys.readouterr().err


def test_a_silent_reporter_says_nothing_and_shows_no_bar(capsys: pytest.CaptureFixture[str]) -> None:
    silent = Reporter.silent()
    silent.say("a line")
    silent.warn("a warning")
    assert silent.quiet and silent.bar is None
    assert capsys.readouterr() == ("", "")


def test_durations_read_in_seconds_minutes_or_hours() -> None:
    assert [duration(s) for s in (12.4, 89.6, 90, 5399, 5400, 7200)] == ["12 s", "90 s", "1.5 min", "90.0 min", "1.5 h", "2.0 h"]
