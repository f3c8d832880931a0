"""Plot functions draw on the axes they are given (or a new one), return it, and save nothing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from lagrseq.analysis import figures, stats
from tests.support.summaries import summarize


def _series(label: str, offset: float) -> figures.Series:
    x = np.arange(1, 6)
    matrix = np.vstack([x + offset, x + offset + 2.0])
    return figures.Series(label, stats.curve(x, matrix), 2)


@pytest.fixture(autouse=True)
def _in_empty_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)


@pytest.fixture(autouse=True)
def _nothing_saved(tmp_path: Path):  # type: ignore[no-untyped-def]
    yield
    assert list(tmp_path.iterdir()) == [], "plot functions must never write files"


def test_returns_draws_mean_lines_and_bands_on_the_given_axes() -> None:
    ax = Figure().add_subplot()
    out = figures.returns([_series("LaGR-SEQ", 0.0), _series("Q-learning", 10.0)], ax, title="t")
    assert out is ax
    lines = ax.get_lines()
    assert [line.get_label() for line in lines] == ["LaGR-SEQ (n=2)", "Q-learning (n=2)"]
    assert lines[0].get_ydata().tolist() == [2.0, 3.0, 4.0, 5.0, 6.0]
    assert len(ax.collections) == 2  # one shaded band per series
    assert ax.get_title() == "t" and ax.get_xlabel() == "Episodes"
    assert "std" in ax.get_legend().get_title().get_text()


def test_returns_band_choices() -> None:
    se = figures.returns([_series("a", 0.0)], band="se")
    assert "s.e." in se.get_legend().get_title().get_text()
    with pytest.raises(ValueError, match="band"):
        figures.returns([_series("a", 0.0)], band="iqr")


def test_returns_creates_axes_when_none_given() -> None:
    ax = figures.returns([_series("a", 0.0)])
    assert isinstance(ax.figure, Figure)


def test_bar_error_bars_are_the_tables_intervals_and_never_reach_below_zero() -> None:
    """The bars draw each summary's interval (the tables' 95% t interval on the log scale), not
    mean ± s.e.: asymmetric, and above 0 even for two very different trials."""
    a = stats.summarize_t([120.0, 130.0, 140.0], positive=True)
    b = stats.summarize_t([5.0, 290.0], positive=True)
    assert b.ci_low > 0 and stats.summarize_t([5.0, 290.0]).ci_low < 0  # the plain t interval would
    ax = figures.bars([figures.Bar("LaGR-SEQ", a), figures.Bar("LaGR", b)])
    heights = [p.get_height() for p in ax.patches]
    assert heights == [130.0, 147.5]
    texts = [t.get_text() for t in ax.texts]
    assert texts == [f"130.0 [{a.ci_low:.1f}, {a.ci_high:.1f}]", f"147.5 [{b.ci_low:.1f}, {b.ci_high:.1f}]"]
    (lines,) = [c for c in ax.get_children() if c.__class__.__name__ == "LineCollection"]
    ends = [(float(seg[:, 1].min()), float(seg[:, 1].max())) for seg in lines.get_segments()]
    assert ends == [(pytest.approx(a.ci_low), pytest.approx(a.ci_high)), (pytest.approx(b.ci_low), pytest.approx(b.ci_high))]
    assert "95% t interval" in ax.get_ylabel()
    ticks = [t.get_text() for t in ax.get_xticklabels()]
    assert ticks == ["LaGR-SEQ\n(n=3)", "LaGR\n(n=2)"]


def test_bars_with_a_single_trial_show_no_error() -> None:
    one = summarize([5.0], stats.generator("one"))
    assert math.isnan(one.se)
    ax = figures.bars([figures.Bar("x", one)])
    assert [t.get_text() for t in ax.texts] == ["5.0"]


def test_accuracy_plots_percent_against_fraction() -> None:
    line = figures.AccuracyLine(
        "mock, τ=0", np.array([0.125, 0.5, 1.0]), np.array([0.0, 50.0, 100.0]), 20
    )
    ax = figures.accuracy([line])
    (plotted,) = ax.get_lines()
    assert plotted.get_xdata().tolist() == [0.125, 0.5, 1.0]
    assert plotted.get_ydata().tolist() == [0.0, 50.0, 100.0]
    assert ax.get_ylabel() == "Accuracy (%)"
    assert plotted.get_label() == "mock, τ=0 (20 per point)"


def test_an_accuracy_label_says_a_tag_once_and_the_axes_keep_their_height() -> None:
    # "open model (Qwen...), τ=0 [open model]" said it twice, and eight two-line labels
    # squeezed Fig. 4's axes to a quarter of the picture
    import numpy as np

    from lagrseq.analysis import figures

    assert figures._without_repeated_tags("open model (Qwen), τ=0 [all 80 answers recorded] [open model] (10 per point)") == (
        "open model (Qwen), τ=0 [all 80 answers recorded] (10 per point)"
    )
    assert figures._without_repeated_tags("mock, τ=0 [rule-based mock]") == "mock, τ=0 [rule-based mock]"
    lines = [
        figures.AccuracyLine(f"open model number {i} with a long label, recorded, τ=0 [all 80 answers recorded] [open model]",
                             np.linspace(0.125, 1, 8), np.linspace(0, 100, 8), 10)
        for i in range(8)
    ]
    ax = figures.accuracy(lines)
    figure = ax.figure
    figure.canvas.draw()  # type: ignore[attr-defined]
    height = ax.get_position().height  # a share of the figure
    legend = ax.get_legend().get_window_extent()
    axes_box = ax.get_window_extent()
    assert axes_box.height >= 0.8 * legend.height and height > 0.3


def test_symlog_ticks_start_at_zero_and_never_sit_inside_the_linear_part() -> None:
    from lagrseq.analysis.frontier import symlog_ticks

    for threshold, largest in ((1.0, 444.0), (0.025, 2.2), (0.8, 50.0), (25.0, 1800.0), (1e-4, 0.5)):
        ticks = symlog_ticks(threshold, largest)
        assert ticks[0] == 0.0 and all(t >= threshold for t in ticks[1:])
        assert 3 <= len(ticks) <= 11 and ticks == sorted(ticks)
        assert max(ticks) >= largest / 5
    assert symlog_ticks(1.0, 100.0) == [0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
