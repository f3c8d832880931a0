"""Plot functions in the paper's style. Each takes ``ax=None`` (a new figure when None), draws on
it and returns it; none saves, shows or touches pyplot's global state (only replay writes files).
:func:`render` turns a finished figure into file bytes (replay writes them).

Inputs are already-summarised series (see :mod:`lagrseq.analysis.stats`), so a plot is a pure
function of its numbers.
"""

from __future__ import annotations

import math
import re
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from lagrseq.analysis.stats import CurveStats, Interval

FIGSIZE = (6.4, 4.4)
# The matplotlib default cycle, fixed here so a figure does not depend on the user's rcParams.
COLORS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)
STYLE: dict[str, Any] = {
    "font.family": "DejaVu Sans",
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "legend.fontsize": 9,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "figure.dpi": 100,
}
"""rcParams replay draws with (it applies them with ``matplotlib.rc_context``)."""


def ready() -> list[bytes]:
    """Nothing: run in a new worker process, it imports this module (and so matplotlib) before
    the first figure arrives there."""
    return []


def render(
    figure: Figure, formats: Sequence[str], dpi: int, metadata: dict[str, dict[str, None]], rc: dict[str, Any] | None
) -> list[bytes]:
    """``figure`` drawn in each format (the file bytes, in order), under the rcParams ``rc`` when
    given. Replay runs this in its worker processes too (the figure arrives pickled): the bytes do
    not depend on the process that draws them (same rcParams, fonts and backend)."""
    import contextlib
    import io

    import matplotlib

    out = []
    with matplotlib.rc_context(rc) if rc is not None else contextlib.nullcontext():  # type: ignore[arg-type]
        for fmt in formats:
            buffer = io.BytesIO()
            figure.savefig(buffer, format=fmt, dpi=dpi, metadata=metadata[fmt])
            out.append(buffer.getvalue())
    return out


def new_axes(figsize: tuple[float, float] = FIGSIZE) -> Axes:
    """Axes on a new, pyplot-free figure."""
    figure = Figure(figsize=figsize, layout="constrained")
    return figure.add_subplot()


@dataclass(frozen=True)
class Series:
    """One learning curve: its label and its statistics over trials."""

    label: str
    stats: CurveStats
    trials: int


def returns(
    series: Sequence[Series],
    ax: Axes | None = None,
    *,
    band: str = "std",
    xlabel: str = "Episodes",
    ylabel: str = "Average return",
    title: str | None = None,
) -> Axes:
    """Mean return curves with a shaded band of one standard deviation (``band="std"``, the
    paper's appendix captions) or one standard error (``"se"``) over trials."""
    if band not in ("std", "se"):
        raise ValueError(f"band must be 'std' or 'se', not {band!r}")
    ax = new_axes() if ax is None else ax
    for i, s in enumerate(series):
        color = COLORS[i % len(COLORS)]
        spread = s.stats.std if band == "std" else s.stats.se
        ax.plot(
            s.stats.x, s.stats.mean, color=color, linewidth=1.6, label=f"{s.label} (n={s.trials})"
        )
        finite = np.isfinite(spread)
        if finite.any():
            ax.fill_between(
                s.stats.x,
                s.stats.mean - spread,
                s.stats.mean + spread,
                where=finite,
                color=color,
                alpha=0.18,
                linewidth=0,
            )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.set_xlim(left=0)
    _zero_in_view(ax)
    band_text = "±1 std" if band == "std" else "±1 s.e."
    _legend_below(ax, len(series), title=f"mean, shaded {band_text} over trials")
    return ax


def _zero_in_view(ax: Axes) -> None:
    """Returns that are all positive get a y axis from 0 (matplotlib's autoscale started it
    near the lowest curve, which made a gap of 0.2 against 1.3 look like a factor of ten)."""
    low, high = ax.get_ylim()
    if low > 0:
        ax.set_ylim(0, high)


def _legend_below(ax: Axes, entries: int, title: str | None = None) -> None:
    """A legend under the axes, so that it never hides a curve; as many columns as fit the
    figure's width (long labels stack), so the axes keep their size."""
    handles, labels = ax.get_legend_handles_labels()
    labels = [textwrap.fill(label, 72) for label in labels]  # a longer one would leave the figure
    longest = max((len(line) for label in labels for line in label.splitlines()), default=0)
    columns = entries if entries <= 3 else -(-entries // 2)
    while columns > 1 and columns * (longest + 6) > 90:
        columns -= 1
    from matplotlib.transforms import offset_copy

    # a fixed distance under the axes, past the tick labels and the x label, whatever the axes'
    # height (a fraction of it put a tall legend on top of the x label)
    below = offset_copy(ax.transAxes, fig=ax.figure, y=-40, units="points")  # type: ignore[arg-type]
    ax.legend(
        handles,
        labels,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        bbox_transform=below,
        ncols=columns,
        frameon=False,
        title=title,
        title_fontsize=8,
    )


@dataclass(frozen=True)
class Bar:
    """One bar: a label and a per-trial quantity's summary."""

    label: str
    summary: Interval


def bars(
    items: Sequence[Bar],
    ax: Axes | None = None,
    *,
    ylabel: str = "LLM queries per trial\n(mean, 95% t interval, log scale)",
    title: str | None = None,
) -> Axes:
    """Bars of the mean with error bars that are the tables' intervals (each summary's
    ``ci_low``/``ci_high``: for queries, the 95% t interval on the log scale, which never reaches
    below 0), each bar labelled with its mean."""
    ax = new_axes() if ax is None else ax
    positions = np.arange(len(items))
    means = np.array([b.summary.mean for b in items])
    below = np.array([0.0 if math.isnan(b.summary.ci_low) else b.summary.mean - b.summary.ci_low for b in items])
    above = np.array([0.0 if math.isnan(b.summary.ci_high) else b.summary.ci_high - b.summary.mean for b in items])
    ax.bar(
        positions,
        means,
        yerr=np.vstack([below, above]) if len(items) else None,
        width=0.6,
        color=[COLORS[i % len(COLORS)] for i in range(len(items))],
        capsize=6,
        error_kw={"elinewidth": 1.2},
    )
    top = float(np.nanmax(means + above)) if len(items) else 1.0
    for x, b, err in zip(positions.tolist(), items, above.tolist(), strict=True):
        text = (
            f"{b.summary.mean:.1f}"
            if math.isnan(b.summary.ci_low)
            else f"{b.summary.mean:.1f} [{b.summary.ci_low:.1f}, {b.summary.ci_high:.1f}]"
        )
        ax.text(x, b.summary.mean + err + 0.02 * top, text, ha="center", va="bottom", fontsize=9)
    ax.set_xticks(positions, [f"{b.label}\n(n={b.summary.n})" for b in items])
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, top * 1.15 if top > 0 else 1.0)
    ax.grid(axis="x", visible=False)
    if title:
        ax.set_title(title)
    return ax


def _without_repeated_tags(label: str) -> str:
    """``label`` without a bracketed tag whose words the label already says ("open model
    (Qwen2.5-Coder-1.5B, recorded), τ=0 [open model]" said "open model" twice)."""
    out = label
    for tag in re.findall(r" \[([^\[\]]+)\]", label):
        head = out.split(" [", 1)[0].lower()
        if tag.lower() in head:
            out = out.replace(f" [{tag}]", "", 1)
    return out


@dataclass(frozen=True)
class AccuracyLine:
    """Answer accuracy (percent) at each fraction of the sequence shown."""

    label: str
    fraction: np.ndarray
    accuracy: np.ndarray
    samples: int


def accuracy(
    lines: Sequence[AccuracyLine],
    ax: Axes | None = None,
    *,
    title: str | None = None,
) -> Axes:
    """Fig. 4: percentage of answers equal to the target vs the fraction of the target sequence
    given in the prompt, one line per provider and temperature. On a figure of its own, the
    figure grows with the legend under the axes, so the axes keep their height (eight long labels
    squeezed them to a quarter of the picture)."""
    if ax is None:
        labels = [_without_repeated_tags(f"{line.label} ({line.samples} per point)") for line in lines]
        rows = sum(len(textwrap.wrap(label, 72)) for label in labels)
        # a whole number of tenths of an inch: a whole number of pixels at the report's DPI
        ax = new_axes((FIGSIZE[0] + 1.6, round(FIGSIZE[1] + 0.19 * rows, 1)))
    markers = "osD^vP*X"
    styles = ("-", "--", "-.", ":")
    for i, line in enumerate(lines):
        # Lines often coincide (0% or 100% at the same fractions): each later line is drawn
        # narrower, dashed and with a smaller hollow marker on top of the earlier ones, so the
        # first line still shows as a wide band under the others instead of vanishing.
        ax.plot(
            line.fraction,
            line.accuracy,
            color=COLORS[i % len(COLORS)],
            marker=markers[i % len(markers)],
            markersize=max(4.0, 10.0 - 1.5 * i),
            markerfacecolor="none",
            markeredgewidth=1.4,
            linestyle=styles[i % len(styles)],
            linewidth=max(1.2, 4.0 - 0.7 * i),
            label=_without_repeated_tags(f"{line.label} ({line.samples} per point)"),
        )
    ax.set_xlabel("Fraction of the sequence in the prompt")
    ax.set_ylabel("Accuracy (%)")
    ax.set_ylim(-3, 103)
    ax.set_xlim(0, 1.05)
    if title:
        ax.set_title(title)
    _legend_below(ax, len(lines))
    return ax
