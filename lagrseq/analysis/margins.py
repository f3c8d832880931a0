"""The scoreboard's margins and the paper's sample sizes: one table, fixed from the paper's own
numbers before any of lagrseq's were looked at (docs/verdicts.md lists every entry and why).

Each quantity the scoreboard judges has an entry: the scale it is judged on, the margin (or, for a
trend, the threshold) and why. The rules behind them:

* **A count in a table** (queries per run): half the smallest step between this cell and its
  neighbouring cell of the same table, the effect the table reports (Table 2: the step between
  adjacent tau rows of a column; Table 3: SEQ's reduction in the same row, its smallest contrast).
  The bands of neighbouring cells then never overlap: data equivalent to one row cannot also be
  equivalent to the next.
* **A ratio** (performance ratio LaGR / Q-learning): on the advantage, ratio - 1: 25% of the
  paper's advantage (1.05 -> ±0.0125), not 10% of the ratio (which accepted 0.95, LaGR worse).
* **A query reduction** (1 - LaGR-SEQ / LaGR, in points): 25% of the paper's reduction (SEQ's
  advantage, the same rule as a ratio's).
* **A trend** (a slope over tau or stack size): a directional claim. ``rises``: the slope's lower
  bound must clear 25% of the paper's slope (a rise worth the name); ``holds``: the slope's lower
  bound must lie above minus 25% of the paper's mean level (the reduction does not fall by more
  than a quarter over the range); a measure with no paper value must rise at all (threshold 0).

:data:`PAPER_SAMPLES` says what each item's ± is (a standard error: every table's caption says so)
and over how many runs (10: stated by Tables 2 and 3, assumed for the appendix table, which
states none).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

QUERIES = "queries per run"
RATIO = "ratio (on the advantage, ratio - 1)"
POINTS = "percentage points"
SLOPE_TAU = "queries per unit τ"
POINTS_PER_TAU = "points per unit τ"
RATIO_PER_CUBE = "ratio per cube"

REDUCTION = "reduction"
"""The column key of a query reduction row (``"ROW|reduction"``)."""
SLOPE = "slope"
"""The row key of a trend row (``"slope|COLUMN"``)."""
EARLY_AREA = "early-area"
"""The stack-size table's added measure: the return over the first :data:`EARLY_EPISODES`."""
EARLY_EPISODES = 10
"""Episodes of the early return area: Q-learning's return levels off within about 10 episodes,
after which a 100-episode total mostly measures the run's length, not LaGR."""


@dataclass(frozen=True)
class Margin:
    """How one quantity is judged: ``value`` is a TOST margin (± around the paper's value) or,
    with ``trend`` set, the threshold the slope's bound must clear (``rises``: above it;
    ``holds``: above it, a negative number)."""

    scale: str
    value: float
    why: str
    trend: str = ""


@dataclass(frozen=True)
class PaperSample:
    """What a paper value's ± is (``se``: standard error; ``sd``: standard deviation) and over
    how many runs (``n``), with the source of both."""

    n: int
    spread: str
    why: str


PAPER_SAMPLES: dict[str, PaperSample] = {
    "table2": PaperSample(10, "se", "Table 2's caption: mean ± std error over 10 runs"),
    "table3": PaperSample(10, "se", "Table 3's caption: mean ± std error over 10 runs"),
    "appendix-stack-size": PaperSample(
        10, "se", "the appendix table's caption: average ± standard error; it states no n, assumed 10 (every cube figure's trials)"
    ),
}

ALIASES = {"appendix-stack-size-paper-preset": "appendix-stack-size"}
"""Items that judge the same paper numbers as another (same margins, same paper sample)."""

MARGINS: dict[tuple[str, str], Margin] = {
    # Table 2: counts, half the step between adjacent tau rows of the column
    ("table2", "0|LaGR-SEQ"): Margin(QUERIES, 3.5, "half the step to τ = 0.5 (126 -> 133)"),
    ("table2", "0.5|LaGR-SEQ"): Margin(QUERIES, 2.665, "half the step to τ = 1 (133 -> 138.33), the smaller of its two"),
    ("table2", "1|LaGR-SEQ"): Margin(QUERIES, 2.665, "half the step from τ = 0.5 (133 -> 138.33)"),
    ("table2", "0|LaGR (without SEQ)"): Margin(QUERIES, 5.15, "half the step to τ = 0.5 (284 -> 294.3)"),
    ("table2", "0.5|LaGR (without SEQ)"): Margin(QUERIES, 5.15, "half the step from τ = 0 (284 -> 294.3), the smaller of its two"),
    ("table2", "1|LaGR (without SEQ)"): Margin(QUERIES, 18.68, "half the step from τ = 0.5 (294.3 -> 331.66)"),
    ("table2", "0|reduction"): Margin(POINTS, 13.91, "25% of the paper's reduction (55.63%)"),
    ("table2", "0.5|reduction"): Margin(POINTS, 13.70, "25% of the paper's reduction (54.81%)"),
    ("table2", "1|reduction"): Margin(POINTS, 14.57, "25% of the paper's reduction (58.29%)"),
    ("table2", "slope|LaGR-SEQ"): Margin(SLOPE_TAU, 3.083, "queries rise with τ: at least 25% of the paper's slope (12.33 per unit τ)", "rises"),
    ("table2", "slope|LaGR (without SEQ)"): Margin(SLOPE_TAU, 11.92, "queries rise with τ: at least 25% of the paper's slope (47.66 per unit τ)", "rises"),
    ("table2", "slope|reduction"): Margin(
        POINTS_PER_TAU, -14.06, "SEQ's reduction holds across τ: it falls by less than 25% of the paper's mean reduction (56.24 points) from τ = 0 to 1", "holds"
    ),
    # Table 3: counts, half the SEQ contrast of the row (the table's smallest)
    ("table3", "GPT4|LaGR-SEQ"): Margin(QUERIES, 16.4, "half SEQ's reduction in the row (59.5 -> 92.3), the table's smallest contrast"),
    ("table3", "GPT4|LaGR (without SEQ)"): Margin(QUERIES, 16.4, "half SEQ's reduction in the row (59.5 -> 92.3), the table's smallest contrast"),
    ("table3", "GPT3|LaGR-SEQ"): Margin(QUERIES, 76.75, "half SEQ's reduction in the row (236.4 -> 389.9), smaller than the step to GPT4"),
    ("table3", "GPT3|LaGR (without SEQ)"): Margin(QUERIES, 76.75, "half SEQ's reduction in the row (236.4 -> 389.9), smaller than the step to GPT4"),
    ("table3", "GPT4|reduction"): Margin(POINTS, 8.884, "25% of the paper's reduction (35.54%)"),
    ("table3", "GPT3|reduction"): Margin(POINTS, 9.842, "25% of the paper's reduction (39.37%)"),
    # the appendix's stack-size table: ratios on the advantage, and its trend
    ("appendix-stack-size", "5"): Margin(RATIO, 0.0125, "25% of the paper's advantage (1.05 - 1 = 0.05)"),
    ("appendix-stack-size", "8"): Margin(RATIO, 0.07, "25% of the paper's advantage (1.28 - 1 = 0.28)"),
    ("appendix-stack-size", "11"): Margin(RATIO, 0.0825, "25% of the paper's advantage (1.33 - 1 = 0.33)"),
    ("appendix-stack-size", "slope|ratio"): Margin(
        RATIO_PER_CUBE, 0.01167, "LaGR's advantage grows with stack size: at least 25% of the paper's slope ((1.33 - 1.05) / 6 = 0.0467 per cube)", "rises"
    ),
    ("appendix-stack-size", f"slope|{EARLY_AREA}"): Margin(
        RATIO_PER_CUBE, 0.0, "LaGR's early advantage grows with stack size: the paper gives no value of this measure, so any rise (threshold 0)", "rises"
    ),
}


def family(item_id: str) -> str:
    """The item whose paper numbers ``item_id`` judges (itself unless it is an alias)."""
    return ALIASES.get(item_id, item_id)


def margin(item_id: str, key: str) -> Margin | None:
    """The margin of ``key`` (a reference key, ``ROW|reduction`` or ``slope|COLUMN``) in
    ``item_id``'s table; None where the table states none (then no verdict is given)."""
    return MARGINS.get((family(item_id), key))


def paper_sample(item_id: str) -> PaperSample | None:
    return PAPER_SAMPLES.get(family(item_id))


TREND_SHARE = 0.25
"""A trend's size margin: a quarter of the paper's slope (as a ratio's margin is a quarter of
its advantage), computed from the same cells as the slope it judges."""


def slope_margin(paper_slope: float, unit: str) -> Margin:
    """The margin of a trend's size: ± :data:`TREND_SHARE` of the paper's slope over the same cells."""
    value = TREND_SHARE * abs(paper_slope)
    return Margin(unit, value, f"a quarter of the paper's slope over the same cells ({paper_slope:+.4g} {unit})")


def holds_threshold(levels: Sequence[float], xs: Sequence[float]) -> Margin:
    """The "holds" threshold of a reduction's slope over ``xs``: it falls by less than
    :data:`TREND_SHARE` of the paper's mean level over the range, from the same cells."""
    mean = sum(levels) / len(levels)
    span = max(xs) - min(xs)
    value = -TREND_SHARE * mean / span
    return Margin(POINTS_PER_TAU, value, f"SEQ's reduction holds: it falls by less than 25% of the paper's mean reduction ({mean:.4g} points) over the range", "holds")
