"""The scoreboard: every number the paper states beside lagrseq's value from every source.

For each reference value of a table item (Table 2, Table 3, the stack-size ratios), the query
reductions those tables imply (1 - LaGR-SEQ / LaGR) and the trends the paper claims over a table's
rows (Table 2: queries rise with tau, SEQ's reduction holds across tau; the appendix: LaGR's
advantage grows with stack size), one row per source the logs hold: what made the number
(:mod:`lagrseq.analysis.provenance`), lagrseq's mean with its 95% interval and n (a positive
quantity's modified Cox interval, :func:`lagrseq.analysis.inference.positive_mean_interval`; a
slope's t interval; none below 3 trials), the test and a verdict (docs/verdicts.md):

* a count, a ratio or a reduction: a TOST of the log ratio of lagrseq's value over the paper's,
  with the paper's own ± and n (:func:`lagrseq.analysis.inference.log_ratio_tost`), shown in the
  quantity's units at the paper's value. Where the paper's ± alone leaves the margin out of reach
  (:func:`lagrseq.analysis.inference.min_half_width`) the row is two-valued: consistent with the
  paper (its 95% interval holds 0) or differs; :func:`testability` lists which rows and why. A
  reduction is a magnitude check (:data:`MAGNITUDE`);
* a trend: its direction by Jonckheere-Terpstra's test of the per-trial values, its size by a
  Welch TOST of the slope against the paper's slope over the same cells (margin: a quarter of it);
  a measure the paper never reports says so (:data:`MEASURE_RISES`) and never reads reproduced;
* ``fitted`` for a fitted number whatever its interval; a bound (:data:`BOUND`) for a row built to
  run to one side (misses refused); **no verdict** where any trial's first accepted answer came
  from a fallback, below :data:`lagrseq.analysis.inference.MIN_N_REPRODUCED` trials, or where the
  paper gives no value. A fitted row with the decisions of an authors' answers row reads as it.

Every label is one constant here (:data:`LABELS`). Every margin, its scale and why, is in
:mod:`lagrseq.analysis.margins`. The last column says what explains a gap: nothing below 5 trials,
:data:`NO_GAP` where the test's interval holds 0, else a callable :func:`build` takes
(``explain``; by default the audit's attribution, :func:`lagrseq.analysis.audit.gap_explained_by`,
or a link to the item).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from lagrseq.analysis import audit, inference, margins, stats
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.items import ItemFailure, Match
from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table, interval
from lagrseq.registry import kind_of
from lagrseq.suite import (
    MISS_ROWS,
    PAPER_MODEL_ROWS,
    RECORDED_NAME,
    Item,
    is_authors_provider,
    miss_row,
)

_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")
_PLUS_MINUS = re.compile(r"(?:±|\+-|\+/-)\s*(\d+(?:\.\d+)?)")

Explain = Callable[[Mapping[str, Any]], str]
"""(a scoreboard row's data: item, task, what, provenance, verdict, mean, paper value, margin, ...)
-> the text of its "gap explained by" cell; a text starting with ``#`` is shown as a link."""


def paper_number(text: str) -> float | None:
    found = _NUMBER.search(text)
    return float(found.group()) if found else None


def paper_spread(text: str) -> float | None:
    """The paper's +- of a value written ``126 ± 2.94`` (None when it gives none)."""
    found = _PLUS_MINUS.search(text)
    return float(found.group(1)) if found else None


def source_name(provider: str) -> str:
    if is_authors_provider(provider):
        return RECORDED_NAME
    kind = kind_of(provider)
    if kind is not None and kind.replays and ":" in provider:
        return "recorded store " + provider.split(":", 1)[1].rstrip("/").rsplit("/", 1)[-1]
    return provider


def _fits(m: Match, row: str) -> bool:
    """Whether a matched run stands for the paper's ``row``: the same row, its recorded-GPT
    variant, or (a row per model, Table 3) a run of that model."""
    if m.row == row or m.row == f"{row} ({RECORDED_NAME})" or any(m.row == miss_row(row, x) for x in MISS_ROWS):
        return True
    if m.spec.row is not None and "{provider}" in m.spec.row and m.run is not None:
        model = m.run.config.get("llm", {}).get("model", "")
        return PAPER_MODEL_ROWS.get(model) == row
    return False


def _queries(run: Run) -> np.ndarray:
    return np.array(list(run.total_per_trial("queries").values()), dtype=float)


def _early_area(run: Run, episodes: int = margins.EARLY_EPISODES) -> dict[int, float]:
    """Per trial: the return summed over its first ``episodes`` episodes (the area under its
    return curve there)."""
    e = run.episodes
    early = e[e["episode"] < episodes]
    return {int(t): float(v) for t, v in early.groupby("trial")["return"].sum().items()}


def _reduction(ratio: inference.Estimate) -> inference.Estimate:
    """1 - ratio, in percent (the query reduction SEQ brings) from the ratio LaGR-SEQ / LaGR."""
    return inference.Estimate(100 * (1 - ratio.value), 100 * ratio.se, ratio.df, ratio.n)


def _reduction_interval(ratio: inference.Estimate, level: float) -> inference.Interval:
    """The reduction's interval: the ratio's on the log scale, turned around (so it never exceeds
    100%)."""
    r = ratio.log_interval(level)
    return inference.Interval(r.n, 100 * (1 - r.mean), 100 * (1 - r.high), 100 * (1 - r.low), level)


def paper_estimate(item_id: str, text: str) -> inference.Estimate | None:
    """The paper's value ``text`` (``126 ± 2.94``) of ``item_id`` as an estimate with its ± and
    the item's n (:data:`lagrseq.analysis.margins.PAPER_SAMPLES`); None without a ± or an n."""
    value, spread = paper_number(text), paper_spread(text)
    sample = margins.paper_sample(item_id)
    if value is None or spread is None or sample is None:
        return None
    return inference.paper_estimate(value, spread, sample.n, sample.spread)


def default_explanation(audits: Sequence[audit.Audit | str]) -> Explain:
    """The default "gap explained by": where the logs hold an audit of the row's task, the audit
    rows that account for the gap (:func:`lagrseq.analysis.audit.gap_explained_by`, within the
    row's margin; a task named without its audit gets a link to it); else a link to the item."""
    built = [a for a in audits if not isinstance(a, str)]
    named = {a if isinstance(a, str) else a.task for a in audits}

    def explain(row: Mapping[str, Any]) -> str:
        if built and row["task"] in named:
            found = audit.gap_explained_by(
                built, row["task"], row["preset"], row["quantity"], row["mean"], row["paper"], row["_config"],
                margin=row.get("margin"), interval=(row.get("test_low95", math.nan), row.get("test_high95", math.nan)),
            )
            if found:
                return found
        return f"#audit-{row['task']}" if row["task"] in named and not built else f"#{row['item']}"

    return explain


VERDICTS = (
    inference.REPRODUCED,
    inference.DIFFERS,
    inference.INCONCLUSIVE,
    inference.CONSISTENT,
    inference.FITTED,
    inference.NO_VERDICT,
)
"""Every verdict a judged row can show (the CSV's ``verdict``), beside :data:`LABELS`."""
MAGNITUDE = "magnitude reproduced (magnitude check)"
"""A reduction row whose TOST reads ``reproduced``: its margin (25% of the paper's reduction)
holds every τ cell of the table, so it checks SEQ's reduction's size, not one cell."""
BOUND = "bound (no verdict)"
"""A row built to run to one side (Table 3's "misses refused": a miss is never accepted, so it
runs high): a bound, shown with the band the other miss rows span; never judged."""
MEASURE_RISES = "rises (lagrseq's measure)"
MEASURE_FALLS = "falls (lagrseq's measure)"
MEASURE_FLAT = "no monotone trend shown (lagrseq's measure)"
"""The direction of a trend of a measure the paper never reports: never ``reproduced``."""
FAILED_VERDICT = "failed"
"""The verdict column of an item whose runs failed (shown as FAILED)."""
LABELS = (*VERDICTS, MAGNITUDE, BOUND, MEASURE_RISES, MEASURE_FALLS, MEASURE_FLAT, FAILED_VERDICT)
"""Every verdict label the scoreboard writes (the CSV's ``verdict`` column), in one place."""
NO_GAP = "no gap shown (the test's 95% interval holds 0)"
"""The gap column where the test's interval holds the paper's value."""

LOG, REDUCTION_ROW, DIRECTION, SIZE, HOLDS = "log ratio", "reduction", "direction", "size", "holds"
"""How a row is tested (the CSV's ``test``): TOST of the log ratio (counts and ratios), the same
for a reduction (the ratio SEQ / LaGR), Jonckheere-Terpstra's monotone test (a trend's
direction), a slope's Welch TOST against the paper's slope (its size), a slope against a "holds"
threshold."""


@dataclass(frozen=True)
class _Part:
    """lagrseq's side of one scoreboard row: its estimate, the interval shown (95%, inside the
    quantity's range), what made it and how many trials a fallback decided; ``values``: the
    per-trial values behind it (a count or a ratio), ``ratio``: a reduction's ratio SEQ / LaGR."""

    estimate: inference.Estimate
    shown: inference.Interval
    made: prov.Provenance
    decided: int
    trials: int
    values: np.ndarray | None = None
    ratio: inference.Estimate | None = None


def _part(runs: Sequence[Run], estimate: inference.Estimate, shown: inference.Interval, values: np.ndarray | None = None,
          ratio: inference.Estimate | None = None) -> _Part:
    """The part made from ``runs``: the weakest provenance of them; the trials a fallback decided
    out of the trials of the runs that asked a store (a baseline asks nothing)."""
    made = prov.combined([prov.of_run(r) for r in runs])
    if estimate.n < inference.MIN_N_INTERVAL:
        shown = inference.Interval(estimate.n, estimate.value, math.nan, math.nan, shown.level)
    decided = [prov.decided_by_fallback(r) for r in runs]
    asking = [d for d, r in zip(decided, runs, strict=True) if prov.replays(r)]
    return _Part(estimate, shown, made, sum(sum(d) for d in decided), sum(len(d) for d in asking), values, ratio)


def _count_part(run: Run) -> _Part:
    values = _queries(run)
    return _part([run], inference.mean_estimate(values), inference.positive_mean_interval(values), values)


@dataclass(frozen=True)
class _Judged:
    """A row's test: the verdict it reads, why, its 90% and 95% intervals (of ``lagrseq - paper``,
    or the slope), the difference, whether the row can reach ``reproduced`` and the smallest
    half-width lagrseq's n could reach."""

    verdict: str
    reason: str
    d90: inference.Interval
    d95: inference.Interval
    difference: float = math.nan
    df: float = math.nan
    testable: bool | None = None
    min_half: float = math.nan
    test: str = ""
    p: float = math.nan


def _untested(n: int, reason: str) -> _Judged:
    blank = inference.Interval(n, math.nan, math.nan, math.nan, 0.9)
    return _Judged(inference.NO_VERDICT, reason, blank, blank)


def _log_band_width(margin: float, scale: float) -> float:
    """The width, on the log scale, of the band ``± margin`` around a value ``|scale|``."""
    a = abs(scale)
    return math.log1p(margin / a) - math.log1p(-margin / a) if margin < a else math.inf


def _judge_log(ours: inference.Estimate, paper: inference.Estimate, margin: float, scale: float, test: str) -> _Judged:
    """A TOST of a positive quantity on the log scale, shown in its units (scale: see
    :func:`lagrseq.analysis.inference.log_ratio_tost`), two-valued where the paper's ± leaves the
    margin out of reach."""
    half = inference.min_half_width(paper, ours.n, log=True)
    testable = 2.0 * half < _log_band_width(margin, scale)
    judged = inference.log_ratio_tost(ours, paper, margin, scale, testable=testable)
    d = inference.log_ratio(ours, paper)
    return _Judged(judged.verdict, judged.reason, judged.interval, judged.wide, judged.interval.mean, d.df, testable,
                   abs(scale) * math.expm1(half), test)


def _judge_value(ours: inference.Estimate, paper: inference.Estimate, margin: float, test: str) -> _Judged:
    """A two-sample Welch TOST on the raw scale (a slope against the paper's), two-valued where the
    paper's ± leaves the margin out of reach."""
    half = inference.min_half_width(paper, ours.n)
    testable = half < margin
    difference = inference.contrast([ours, paper], [1.0, -1.0])
    inner, wide = difference.interval(0.9), difference.interval(0.95)
    inner = inference.Interval(ours.n, inner.mean, inner.low, inner.high, inner.level)
    judged = inference.judge(inner, wide, 0.0, margin) if testable else inference.judge_untestable(inner, wide, 0.0, margin)
    return _Judged(judged.verdict, judged.reason, judged.interval, judged.wide, difference.value, difference.df, testable, half, test)


def _judge_direction(groups: Sequence[np.ndarray], key: str, measure: bool) -> _Judged:
    """Jonckheere-Terpstra's monotone test of per-trial ``groups`` in order (a rise claimed); a
    measure the paper never reports reads :data:`MEASURE_RISES` and the like, never reproduced."""
    test = inference.jonckheere(groups, stats.generator(f"jonckheere:{key}"))
    verdict, reason = inference.direction(test)
    blank = inference.Interval(test.n, math.nan, math.nan, math.nan, 0.9)
    if measure and verdict != inference.NO_VERDICT:
        verdict = {inference.REPRODUCED: MEASURE_RISES, inference.DIFFERS: MEASURE_FALLS}.get(verdict, MEASURE_FLAT)
    return _Judged(verdict, reason, blank, blank, test=DIRECTION, p=test.p_rise)


def _judge(item: Item, key: str, part: _Part, paper_est: inference.Estimate | None, paper: str, test: str,
           groups: Sequence[np.ndarray] | None, margin: margins.Margin | None = None) -> tuple[_Judged, margins.Margin | None]:
    """The test of one row by its kind (``test``), under ``margin`` or the margin of ``key`` in the
    item's table."""
    mg = margin if margin is not None else margins.margin(item.id, key)
    ours = part.estimate
    if mg is None:
        if test == DIRECTION and groups is not None:
            return _judge_direction(groups, f"{item.id}|{key}", measure=True), None
        reason = "the paper gives no value of this measure (lagrseq's)" if paper_number(paper) is None else "no margin stated for this quantity"
        return _untested(ours.n, reason), None
    if test == DIRECTION and groups is not None:
        return _judge_direction(groups, f"{item.id}|{key}", measure=paper_est is None), mg
    if test == HOLDS:
        trend = inference.above(ours, mg.value)
        return _Judged(trend.verdict, trend.reason, trend.inner, trend.wide, ours.value, ours.df, None, math.nan, HOLDS), mg
    if paper_est is None:
        return _untested(ours.n, "the paper gives no ± for this value"), mg
    if test == SIZE:
        return _judge_value(ours, paper_est, mg.value, SIZE), mg
    if test == REDUCTION_ROW and part.ratio is not None:
        paper_ratio = _ratio_of_reduction(paper_est)
        judged = _judge_log(part.ratio, paper_ratio, mg.value, -100.0 * paper_ratio.value, REDUCTION_ROW)
        if judged.verdict == inference.REPRODUCED:
            judged = _Judged(MAGNITUDE, judged.reason + "; a magnitude check: the margin holds every τ cell of the table",
                             judged.d90, judged.d95, judged.difference, judged.df, judged.testable, judged.min_half, judged.test)
        return judged, mg
    return _judge_log(ours, paper_est, mg.value, paper_est.value, LOG), mg


def _ratio_of_reduction(reduction: inference.Estimate) -> inference.Estimate:
    """The ratio SEQ / LaGR behind a reduction in percent (:func:`_reduction` turned around)."""
    return inference.Estimate(1.0 - reduction.value / 100.0, reduction.se / 100.0, reduction.df, reduction.n)


def _shown_verdict(judged: _Judged, part: _Part) -> tuple[str, str]:
    """The verdict shown: ``fitted`` for a fitted number, no verdict where a fallback decided a
    trial, else the test's."""
    if part.made.kind == prov.FITTED:
        return inference.FITTED, part.made.why
    if part.decided:
        return inference.NO_VERDICT, f"the fallback decided {part.decided} of {part.trials} trials (their first accepted answer)"
    return judged.verdict, judged.reason


def build(
    items: Sequence[tuple[Item, Sequence[Match]]],
    audits: Sequence[audit.Audit | str] = (),
    explain: Explain | None = None,
    failed: Sequence[tuple[Item, ItemFailure]] = (),
) -> Table:
    """The scoreboard of ``items`` (each with its matched runs). ``explain`` fills the last
    column from each row's data (default: :func:`default_explanation` of ``audits``: the audits
    the logs hold, or the names of the tasks audited), where the test's interval does not hold 0
    (:data:`NO_GAP`) and the row has at least :data:`lagrseq.analysis.inference.MIN_N_REPRODUCED`
    trials. ``failed``: items whose runs failed (``lagrseq reproduce``), one row each after the
    others: FAILED, its reason, and the command that reruns it in the last column."""
    rows: list[dict[str, Any]] = []
    explain = default_explanation(audits) if explain is None else explain

    def add(item: Item, what: str, paper: str, m: Match, part: _Part, key: str, digits: int,
            paper_est: inference.Estimate | None = None, quantity: str | None = None, kind: str = "value",
            test: str = LOG, groups: Sequence[np.ndarray] | None = None, margin: margins.Margin | None = None) -> None:
        """One row: lagrseq's ``part`` against the paper's ``paper_est`` under the margin of
        ``key`` in the item's table (``margin``: one computed from the row's own cells), tested as
        ``test`` says."""
        judged, mg = _judge(item, key, part, paper_est, paper, test, groups, margin)
        row = _row(item, what, paper, m, part, _blank_if_few(judged, part), mg, paper_est,
                   digits=digits, quantity=quantity, kind=kind)
        row["explained_by"] = _gap(row, explain)
        rows.append(row)

    for item, matched in items:
        reference = item.options.get("reference", {})
        if not isinstance(reference, dict) or not reference:
            continue
        present = [m for m in matched if m.run is not None]
        if item.render == "query-table":
            _query_rows(item, reference, present, add)
        elif item.render == "ratio-table":
            _ratio_rows(item, reference, present, add)
    _bounds(rows)
    _same_decisions(rows)
    rows += [_failed_row(item, failure) for item, failure in failed]
    return _board(rows)


def _blank_if_few(judged: _Judged, part: _Part) -> _Judged:
    """The test as judged, without intervals on fewer than :data:`inference.MIN_N_INTERVAL` trials."""
    if part.estimate.n < inference.MIN_N_INTERVAL:  # no interval on so few trials, in the test either
        blank = inference.Interval(part.estimate.n, math.nan, math.nan, math.nan, 0.9)
        return replace(judged, d90=blank, d95=blank)
    return judged


def _row(item: Item, what: str, paper: str, m: Match, part: _Part, judged: _Judged, mg: margins.Margin | None,
         paper_est: inference.Estimate | None, *, digits: int, quantity: str | None, kind: str) -> dict[str, Any]:
    """The data of one scoreboard row (all but its gap column)."""
    sample = margins.paper_sample(item.id)
    ours = part.estimate
    verdict, reason = _shown_verdict(judged, part)
    return {
        "item": item.id,
        "title": item.title.split(":")[0],
        "task": m.spec.task,
        "what": what,
        "kind": kind,
        "test": judged.test,
        "paper": paper,
        "paper_value": paper_est.value if paper_est is not None else paper_number(paper),
        "paper_se": paper_est.se if paper_est is not None else math.nan,
        "paper_n": sample.n if sample is not None else math.nan,
        "paper_n_why": sample.why if sample is not None else "",
        **_margin_cells(judged, mg),
        "source": source_name(m.provider) + (f" ({m.spec.preset} preset)" if m.spec.preset != "upstream" else ""),
        "provenance": part.made.kind,
        "provenance_why": part.made.why + (f"; {m.misses.text()}" if m.misses is not None else ""),
        "on_miss": m.spec.on_miss or "",
        "mean": ours.value,
        "se": ours.se,
        "ci_low": part.shown.low,
        "ci_high": part.shown.high,
        "trials": ours.n,
        "difference": judged.difference,
        "difference_df": judged.df,
        "test_low90": judged.d90.low,
        "test_high90": judged.d90.high,
        "test_low95": judged.d95.low,
        "test_high95": judged.d95.high,
        "p_rise": judged.p,
        "fallback_decided": part.decided,
        "fallback_trials": part.trials,
        **_miss_cells(m),
        "verdict": verdict,
        "verdict_reason": reason,
        "test_verdict": judged.verdict,
        "digits": digits,
        "note": m.note,
        "preset": m.spec.preset,
        "quantity": quantity,
        "_config": m.run.config if m.run is not None else None,
        "_values": part.values,
    }


def _margin_cells(judged: _Judged, mg: margins.Margin | None) -> dict[str, Any]:
    """A row's margin columns: its scale, value, reason and trend, and whether the paper's ± leaves it testable."""
    return {
        "scale": mg.scale if mg is not None else "",
        "margin": mg.value if mg is not None else math.nan,
        "margin_reason": mg.why if mg is not None else "",
        "trend": ("" if judged.test == SIZE else mg.trend) if mg is not None else "",
        "testable": judged.testable,
        "min_half_width": judged.min_half,
    }


def _miss_cells(m: Match) -> dict[str, Any]:
    """A row's miss columns: a recorded store's answers, its misses and what answered them."""
    return {
        "answers": m.misses.answers if m.misses is not None else None,
        "misses": m.misses.missed if m.misses is not None else None,
        "miss_share": m.misses.share if m.misses is not None else None,
        "misses_answered_by": m.misses.answered_by if m.misses is not None else None,
    }


def _board(rows: list[dict[str, Any]]) -> Table:
    """The scoreboard table of ``rows``: its caption, columns, displayed cells and data."""
    display = [_display(r) for r in rows]
    data = pd.DataFrame(rows).drop(columns=["digits", "_config", "_values"], errors="ignore")
    return Table(
        "Scoreboard: the paper's numbers beside lagrseq's (mean [95% interval, on the log scale for counts and ratios] (n)); "
        "the test against the paper's value with its ± and n (TOST of the log ratio for counts, ratios and reductions, shown as "
        "lagrseq - paper at the paper's value; Welch TOST for a slope's size; Jonckheere-Terpstra for a trend's direction), "
        "90% interval; verdict: reproduced / ✗ differs / inconclusive within the stated margin, or, where the paper's ± leaves "
        "the margin out of reach, consistent (the 95% interval holds 0) / ✗ differs; fitted; a bound; "
        f"or no verdict (a fallback decided a trial; fewer than {inference.MIN_N_REPRODUCED} trials)",
        ("paper item", "quantity", "paper", "lagrseq source", "made by", "lagrseq", "test [90%]", "verdict", "gap explained by"),
        tuple(display),
        data,
    )


def _gap(row: Mapping[str, Any], explain: Explain) -> str:
    """The gap column: nothing below :data:`lagrseq.analysis.inference.MIN_N_REPRODUCED` trials,
    :data:`NO_GAP` where the test's 95% interval of ``lagrseq - paper`` holds 0, else ``explain``."""
    if row["trials"] < inference.MIN_N_REPRODUCED:
        return f"— (n = {row['trials']} < {inference.MIN_N_REPRODUCED})"
    low, high = row["test_low95"], row["test_high95"]
    if row["test"] in (LOG, REDUCTION_ROW, SIZE) and math.isfinite(low) and low <= 0.0 <= high:
        return NO_GAP
    return explain(row)


def _bounds(rows: list[dict[str, Any]]) -> None:
    """A row built to run high (misses refused: a miss is never accepted) is a bound: no verdict,
    shown with the band that the cell's miss rows span (refused to rule-based mock)."""
    refused = MISS_ROWS["refuse"]
    for row in rows:
        if row["on_miss"] != "refuse" or f"({refused})" not in row["what"]:
            continue
        if row["test"] != LOG:  # a reduction of two counts that both run high bounds nothing
            row["verdict"], row["verdict_reason"] = inference.NO_VERDICT, "a ratio of two rows that run high (misses refused) is no bound"
            row["explained_by"] = "—"
            continue
        siblings = [r for r in rows if r["item"] == row["item"] and r["what"] == row["what"].replace(refused, MISS_ROWS["mock"])]
        band = ""
        if siblings and math.isfinite(siblings[0]["mean"]):
            low, high = sorted((siblings[0]["mean"], row["mean"]))
            inside = low <= (row["paper_value"] or math.nan) <= high
            band = f"; the band [{low:.1f}, {high:.1f}] (misses refused to misses: rule-based mock) {'holds' if inside else 'does not hold'} the paper's value"
        row["verdict"] = BOUND
        row["verdict_reason"] = "a refused miss is never accepted, so this row runs high by construction: an upper bound" + band
        row["explained_by"] = "a bound: see the band in the verdict"


def _same_decisions(rows: list[dict[str, Any]]) -> None:
    """A fitted row whose per-trial values equal those of an authors' answers row of the same
    cell makes the same decisions: both read the same verdict, labelled so."""
    authors = [r for r in rows if r["provenance"] == prov.AUTHORS and r["_values"] is not None]
    for row in rows:
        if row["provenance"] != prov.FITTED or row["_values"] is None:
            continue
        twin = next((a for a in authors if a["item"] == row["item"] and a["what"] == row["what"]
                     and a["_values"].shape == row["_values"].shape and np.array_equal(a["_values"], row["_values"])), None)
        if twin is None:
            continue
        note = f"the same decisions as {twin['source']} ({twin['provenance']}) and {row['source']} (fitted): identical per-trial values"
        row["verdict"], row["verdict_reason"] = twin["verdict"], f"{twin['verdict_reason']}; {note}"
        twin["verdict_reason"] = f"{twin['verdict_reason']}; {note}"
        row["explained_by"] = twin["explained_by"]


_Add = Callable[..., None]


def _display(r: Mapping[str, Any]) -> tuple[str, ...]:
    if r["verdict"] == FAILED_VERDICT:
        return (r["title"], r["what"], r["paper"], "—", "—", "FAILED", "n/a", f"FAILED: {r['verdict_reason']}", r["explained_by"])
    d = r["digits"]
    if math.isnan(r["ci_low"]):
        why = f"no interval below {inference.MIN_N_INTERVAL} trials" if r["trials"] < inference.MIN_N_INTERVAL else "no interval"
        value = f"{r['mean']:.{d}f} (n={r['trials']}; {why})"
    else:
        value = f"{r['mean']:.{d}f} {interval(r['ci_low'], r['ci_high'], d)} (n={r['trials']})"
    if r["note"]:
        value += f"; {r['note']}"
    test = _test_text(r, d)
    verdict = r["verdict"]
    if verdict == inference.DIFFERS:
        verdict = f"✗ {verdict}"
    if verdict in (inference.NO_VERDICT, BOUND, inference.FITTED) or r["test"] == DIRECTION:
        verdict += f": {r['verdict_reason']}"
    elif r["margin_reason"]:
        if r["trend"]:
            verdict += f" ({r['trend']}: threshold {r['margin']:+.4g} {r['scale']}: {r['margin_reason']})"
        else:
            verdict += f" (margin ±{r['margin']:.4g} {r['scale']}: {r['margin_reason']})"
        if r["testable"] is False:
            verdict += f"; the paper's ± alone gives a 90% half-width of at least {r['min_half_width']:.3g}, over the margin"
    made_by = r["provenance"]
    if r.get("misses"):
        made_by += f" ({r['misses_answered_by']} misses: {r['misses']} of {r['answers']})"
    return (r["title"], r["what"], r["paper"], r["source"], made_by, value, test, verdict, r["explained_by"])


def _test_text(r: Mapping[str, Any], d: int) -> str:
    """The test column: the 90% interval of ``lagrseq - paper`` (on the log scale, shown at the
    paper's value), a slope's interval against its threshold, or the monotone test's p."""
    if r["trials"] < inference.MIN_N_INTERVAL:
        return f"n/a (n = {r['trials']} < {inference.MIN_N_INTERVAL})"
    if r["test"] == DIRECTION and math.isfinite(r["p_rise"]):
        return f"Jonckheere-Terpstra p = {r['p_rise']:.3g} (rise)"
    if math.isnan(r["test_low90"]):
        return "n/a"
    if r["test"] == HOLDS:
        return f"slope {interval(r['test_low90'], r['test_high90'], d + 1)} vs {r['margin']:+.4g}"
    scale = " (log ratio)" if r["test"] in (LOG, REDUCTION_ROW) else ""
    return f"{r['difference']:+.{d}f} {interval(r['test_low90'], r['test_high90'], d)} (df {r['difference_df']:.1f}){scale}"


def _failed_row(item: Item, failure: ItemFailure) -> dict[str, Any]:
    """The scoreboard's row for an item whose runs failed: no number, its reason and advice, and
    the command that reruns it alone (the last column)."""
    reference = item.options.get("reference", {})
    stated = len(reference) if isinstance(reference, dict) else 0
    nan = math.nan
    return {
        "item": item.id,
        "title": item.title.split(":")[0],
        "task": item.runs[0].task if item.runs else "",
        "what": "not measured: a run it needs failed",
        "kind": "failed",
        "test": "",
        "paper": f"{stated} value{'s' if stated != 1 else ''}" if stated else "—",
        "paper_value": None, "paper_se": nan, "paper_n": nan, "paper_n_why": "",
        "scale": "", "margin": nan, "margin_reason": "", "trend": "", "testable": None, "min_half_width": nan,
        "source": "", "provenance": "", "provenance_why": "", "on_miss": "",
        "mean": nan, "se": nan, "ci_low": nan, "ci_high": nan, "trials": 0,
        "difference": nan, "difference_df": nan,
        "test_low90": nan, "test_high90": nan, "test_low95": nan, "test_high95": nan, "p_rise": nan,
        "fallback_decided": 0, "fallback_trials": 0,
        "answers": None, "misses": None, "miss_share": None, "misses_answered_by": None,
        "verdict": FAILED_VERDICT,
        "verdict_reason": f"{failure.reason}; {failure.advice}",
        "test_verdict": "",
        "digits": 0,
        "note": "",
        "preset": "",
        "quantity": None,
        "explained_by": f"rerun it alone: {failure.rerun}",
    }


_Cells = dict[tuple[str, str, str], tuple[Match, _Part]]


def _query_rows(item: Item, reference: Mapping[str, Any], present: Sequence[Match], add: _Add) -> None:
    """Table 2 / Table 3: each cell's queries per run, the query reduction each row's two columns
    imply, and (where the margin table names them) the trends over the rows: the slope of each
    column and of the reduction."""
    header = str(item.options.get("row_header", "")).strip()
    counts = _count_rows(item, reference, present, add, header)
    columns = sorted({k.split("|", 1)[1] for k in reference if "|" in k})
    if len(columns) != 2:
        return
    seq_col = next((c for c in columns if "SEQ" in c and "without" not in c), None)
    lagr_col = next((c for c in columns if c != seq_col), None)
    if seq_col is None or lagr_col is None:
        return
    keys = sorted({k.split("|", 1)[0] for k in reference if "|" in k})
    reductions, paper_reductions = _reduction_rows(item, reference, add, header, counts, keys, seq_col, lagr_col)
    # trends over the rows (Table 2: over τ), where the margin table names them
    try:
        xs = {key: float(key) for key in keys}
    except ValueError:
        return
    if len(set(xs.values())) < 2:
        return
    for column in (seq_col, lagr_col, margins.REDUCTION):
        if margins.margin(item.id, f"{margins.SLOPE}|{column}") is not None:
            _column_trends(item, reference, add, header, counts, reductions, paper_reductions, xs, column)


def _named(header: str, row: str) -> str:
    """A row by its header ("τ = 0", not a bare "0" that reads as a count)."""
    return f"{header} = {row}" if header else row


def _shown(m: Match, row: str) -> str:
    """The row as the table names it: the paper's row, or one of its variants by what answered
    the store's misses (Table 3 on the authors' answers: "GPT4 (misses refused)", ...)."""
    return m.row if m.row is not None and m.row.startswith(f"{row} (misses") else row


def _count_rows(item: Item, reference: Mapping[str, Any], present: Sequence[Match], add: _Add, header: str) -> _Cells:
    """One row per cell's queries per run; the cells by (row, column, provider and miss variant)."""
    counts: _Cells = {}
    for key, paper in reference.items():
        if "|" not in key:
            continue
        row, column = key.split("|", 1)
        for m in present:
            if m.spec.column == column and _fits(m, row):
                assert m.run is not None
                part = _count_part(m.run)
                variant = _shown(m, row)[len(row):]  # "" or " (misses refused)": the same on every row
                counts[(row, column, m.provider + variant)] = (m, part)
                add(item, f"{_named(header, _shown(m, row))}, {column}: queries per run", str(paper), m, part, key, 1,
                    paper_estimate(item.id, str(paper)), quantity=audit.QUERY_COLUMNS.get(column))
    return counts


def _reduction_rows(item: Item, reference: Mapping[str, Any], add: _Add, header: str, counts: _Cells, keys: Sequence[str],
                    seq_col: str, lagr_col: str) -> tuple[dict[tuple[str, str], tuple[Match, _Part]], dict[str, inference.Estimate]]:
    """One row per row and source: the query reduction its two columns imply; the reductions made."""
    reductions: dict[tuple[str, str], tuple[Match, _Part]] = {}
    paper_reductions: dict[str, inference.Estimate] = {}
    for key in keys:
        top_text, bottom_text = str(reference.get(f"{key}|{seq_col}", "")), str(reference.get(f"{key}|{lagr_col}", ""))
        top, bottom = paper_number(top_text), paper_number(bottom_text)
        if top is None or bottom is None:
            continue
        top_est, bottom_est = paper_estimate(item.id, top_text), paper_estimate(item.id, bottom_text)
        paper_est = _reduction(inference.ratio_estimate(top_est, bottom_est)) if top_est and bottom_est else None
        paper = f"{100 * (1 - top / bottom):.1f}%" + (f" ± {paper_est.se:.1f}" if paper_est is not None else "")
        if paper_est is not None:
            paper_reductions[key] = paper_est
        for (row, column, provider), (ms, seq_part) in list(counts.items()):
            if row != key or column != seq_col or (key, lagr_col, provider) not in counts:
                continue
            ml, lagr_part = counts[(key, lagr_col, provider)]
            assert ms.run is not None and ml.run is not None
            ratio = inference.ratio_estimate(seq_part.estimate, lagr_part.estimate)
            part = _part([ms.run, ml.run], _reduction(ratio), _reduction_interval(ratio, 0.95), ratio=ratio)
            reductions[(key, provider)] = (ms, part)
            add(item, f"{_named(header, _shown(ms, key))}: query reduction with SEQ (%)", paper, ms, part,
                f"{key}|{margins.REDUCTION}", 1, paper_est, kind="magnitude", test=REDUCTION_ROW)
    return reductions, paper_reductions


def _column_trends(item: Item, reference: Mapping[str, Any], add: _Add, header: str, counts: _Cells,
                   reductions: Mapping[tuple[str, str], tuple[Match, _Part]], paper_reductions: Mapping[str, inference.Estimate],
                   xs: Mapping[str, float], column: str) -> None:
    """The trend rows of one column (or of the reduction) over the table's rows, one per source."""
    keys = list(xs)
    providers = sorted({p for (_, _, p) in counts})
    for provider in providers:
        cells = [reductions.get((k, provider)) if column == margins.REDUCTION else counts.get((k, column, provider)) for k in keys]
        used = [(k, c) for k, c in zip(keys, cells, strict=True) if c is not None]
        if len({xs[k] for k, _ in used}) < 2:
            continue
        if column == margins.REDUCTION:
            papers = [paper_reductions.get(k) for k, _ in used]
        else:
            papers = [paper_estimate(item.id, str(reference.get(f"{k}|{column}", ""))) for k, _ in used]
        over = header or "rows"
        what = f"trend: query reduction with SEQ over {over}" if column == margins.REDUCTION else f"trend: {column} queries per run over {over}"
        unit = ("points" if column == margins.REDUCTION else "queries") + f" per unit {header or 'x'}"
        _trend(item, add, what, f"{margins.SLOPE}|{column}", [xs[k] for k, _ in used], [c for _, c in used],
               [p for p in papers], unit, holds=column == margins.REDUCTION)


def _trend(item: Item, add: _Add, what: str, key: str, xs: Sequence[float], cells: Sequence[tuple[Match, _Part]],
           papers: Sequence[inference.Estimate | None], unit: str, holds: bool = False) -> None:
    """A trend over a table's rows, from the cells it is measured on (the paper's slope and its
    threshold from the same cells): its direction, Jonckheere-Terpstra on the per-trial values
    (where the cells have them), and its size, the least-squares slope against the paper's with its
    ± (margin: a quarter of the paper's slope); a reduction's trend is the slope against "holds"
    (it falls by less than a quarter of the paper's mean reduction over the range)."""
    weights = inference.slope_weights(xs)
    paper_slope = inference.contrast([p for p in papers if p is not None], weights) if all(p is not None for p in papers) else None
    paper_text = f"{paper_slope.value:+.4g} ± {paper_slope.se:.4g} {unit}" if paper_slope is not None else "not in the paper"
    estimate = inference.contrast([c[1].estimate for c in cells], weights)
    made = prov.combined([c[1].made for c in cells])
    part = _Part(estimate, estimate.interval(0.95), made, sum(c[1].decided for c in cells), sum(c[1].trials for c in cells))
    first = cells[0][0]
    if holds:
        levels = [p.value for p in papers if p is not None]
        rule = margins.holds_threshold(levels, xs) if len(levels) == len(papers) and levels else None
        add(item, f"{what} (slope, holds)", paper_text, first, part, key, 2, paper_slope, kind="trend", test=HOLDS, margin=rule)
        return
    groups = [c[1].values for c in cells]
    if all(g is not None and g.size for g in groups):
        add(item, f"{what} (direction)", "rises" if paper_slope is not None else "not in the paper", first, part, key, 3,
            paper_slope, kind="trend", test=DIRECTION, groups=[g for g in groups if g is not None])
    if paper_slope is not None:
        add(item, f"{what} (slope, size)", paper_text, first, part, key, 3, paper_slope, kind="trend", test=SIZE,
            margin=margins.slope_margin(paper_slope.value, unit))


def _ratio_rows(item: Item, reference: Mapping[str, Any], present: Sequence[Match], add: _Add) -> None:
    """The stack-size table: per stack size, the paper's performance ratio (total return of LaGR
    over Q-learning, paired by trial) and lagrseq's early measure (the same over the first
    :data:`margins.EARLY_EPISODES` episodes, which is not ~1 by construction), and the trend of
    each over stack size."""
    numerator = str(item.options.get("numerator", ""))
    denominator = str(item.options.get("denominator", ""))
    by_provider: dict[str, list[tuple[float, Match, _Part, _Part]]] = {}
    for row, paper in reference.items():
        for m in present:
            if m.spec.column != numerator or not _fits(m, row):
                continue
            under = next((b for b in present if b.spec.column == denominator and b.row == m.row), None)
            if under is None or m.run is None or under.run is None:
                continue
            ratios = stats_ratios(m.run, under.run)
            estimate = inference.mean_estimate(ratios)
            part = _part([m.run, under.run], estimate, inference.positive_mean_interval(ratios), ratios)
            add(item, f"{row} cubes: performance ratio {numerator} / {denominator}", str(paper), m, part, str(row), 3,
                paper_estimate(item.id, str(paper)),
                quantity=audit.RATIO_QUANTITY if (numerator, denominator) == ("LaGR-SEQ", "Q-learning") else None)
            early_values = stats.paired_ratios(_early_area(m.run), _early_area(under.run))
            early = inference.mean_estimate(early_values)
            early_part = _part([m.run, under.run], early, inference.positive_mean_interval(early_values), early_values)
            add(item, f"{row} cubes: early return ratio {numerator} / {denominator}, first {margins.EARLY_EPISODES} episodes "
                "(lagrseq's measure)", "not in the paper", m, early_part, f"{margins.EARLY_AREA}|{row}", 3)
            try:
                by_provider.setdefault(m.provider, []).append((float(row), m, part, early_part))
            except ValueError:
                continue
    for provider_rows in by_provider.values():
        if len(provider_rows) < 2 or len({x for x, *_ in provider_rows}) < 2:
            continue
        provider_rows.sort(key=lambda r: r[0])
        xs = [r[0] for r in provider_rows]
        papers = [paper_estimate(item.id, str(reference.get(_row_key(reference, r[0]), ""))) for r in provider_rows]
        _trend(item, add, f"trend: performance ratio {numerator} / {denominator} over stack size", f"{margins.SLOPE}|ratio", xs,
               [(r[1], r[2]) for r in provider_rows], papers, "per cube")
        _trend(item, add, "trend: early return ratio over stack size (lagrseq's measure)", f"{margins.SLOPE}|{margins.EARLY_AREA}", xs,
               [(r[1], r[3]) for r in provider_rows], [None] * len(provider_rows), "per cube")


def _row_key(reference: Mapping[str, Any], x: float) -> str:
    return next((k for k in reference if _float(k) == x), "")


def _float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def stats_ratios(top: Run, bottom: Run) -> np.ndarray:
    """Per-trial ratios of total return, paired by trial index (the stack-size table's quantity)."""
    return stats.paired_ratios(top.total_per_trial("return"), bottom.total_per_trial("return"))


def testability(board: Table) -> Table:
    """Which of the scoreboard's judged rows can read ``reproduced`` at the paper's precision: per
    paper item, quantity and lagrseq's n, the paper's ± and n, the margin, and the smallest 90%
    half-width of ``lagrseq - paper`` that n trials could reach however small their spread
    (:func:`lagrseq.analysis.inference.min_half_width`); where it is not below the margin, the row's
    scale is two-valued (consistent with the paper, or differs)."""
    columns = ["item", "what", "paper", "paper_se", "paper_n", "trials", "margin", "min_half_width", "testable", "test"]
    data = board.data
    if data.empty or not set(columns) <= set(data.columns):
        judged = pd.DataFrame(columns=[*columns, "title"])
    else:
        judged = data[data["testable"].notna() & data["test"].isin([LOG, REDUCTION_ROW, SIZE])]
        judged = judged.drop_duplicates(["item", "what", "trials"])
    rows = []
    for _, r in judged.iterrows():
        testable = bool(r["testable"])
        scale = "reproduced / differs / inconclusive" if testable else f"{inference.CONSISTENT} / differs"
        why = (f"the paper's ± ({r['paper_se']:.4g}, n = {int(r['paper_n'])}) alone gives a half-width of at least "
               f"{r['min_half_width']:.4g} {'<' if testable else '>='} the margin ±{r['margin']:.4g}")
        rows.append((r["title"], r["what"], r["paper"], str(int(r["trials"])), f"±{r['margin']:.4g}", f"{r['min_half_width']:.4g}",
                     "yes" if testable else "no", scale, why))
    frame = judged[columns].reset_index(drop=True)
    return Table(
        "Scoreboard rows testable at the paper's precision: the smallest 90% half-width of lagrseq - paper that lagrseq's n "
        "could reach (its own spread 0), against the row's margin; rows that cannot reach reproduced are judged "
        "consistent with the paper (the 95% interval holds 0) or differs",
        ("paper item", "quantity", "paper", "lagrseq n", "margin", "smallest half-width", "testable", "verdicts it can read", "why"),
        tuple(rows),
        frame,
    )
