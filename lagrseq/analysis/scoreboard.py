"""The scoreboard: every number the paper states beside lagrseq's value from every source.

For each reference value of a table item (Table 2, Table 3, the stack-size ratios), the query
reductions those tables imply (1 - LaGR-SEQ / LaGR) and the trends the paper claims over a table's
rows (Table 2: queries rise with tau, SEQ's reduction holds across tau; the appendix: LaGR's
advantage grows with stack size), one row per source the logs hold: what made the number
(:mod:`lagrseq.analysis.provenance`), lagrseq's mean with its 95% interval and n (counts and ratios
on the log scale, so it never leaves their range; a slope's t interval), and a verdict:

* against a paper value, a two-sample Welch TOST of lagrseq's mean against the paper's value with
  the paper's own ± (a standard error) and n (:func:`lagrseq.analysis.inference.tost`):
  ``reproduced`` (the 90% interval of the difference lies inside ± margin), ``differs`` (the 95%
  interval lies outside) or ``inconclusive``;
* for a trend, the slope against a threshold (:func:`lagrseq.analysis.inference.above`);
* ``fitted`` for a fitted number whatever its interval; **no verdict** where any trial's first
  accepted answer came from a fallback (:func:`lagrseq.analysis.provenance.decided_by_fallback`;
  the row says how many trials), where lagrseq has fewer than
  :data:`lagrseq.analysis.inference.MIN_N_REPRODUCED` trials, or where the paper gives no value.

Every margin and threshold, its scale and why, is in one table, :mod:`lagrseq.analysis.margins`,
fixed from the paper's numbers. Beside the paper's stack-size ratio (total return over 100
episodes, ~1 by construction once Q-learning levels off) the table adds lagrseq's early measure:
the same ratio over the first :data:`lagrseq.analysis.margins.EARLY_EPISODES` episodes. The last
column says what explains the gap: a callable that :func:`build` takes (``explain``); by default,
where the logs hold an audit of the row's task, :func:`lagrseq.analysis.audit.gap_explained_by`
(within the row's margin), else a link to the item.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from lagrseq.analysis import audit, inference, margins, stats
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.items import ItemFailure, Match
from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table
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
                margin=row.get("margin"),
            )
            if found:
                return found
        return f"#audit-{row['task']}" if row["task"] in named and not built else f"#{row['item']}"

    return explain


@dataclass(frozen=True)
class _Part:
    """lagrseq's side of one scoreboard row: its estimate, the interval shown (95%, inside the
    quantity's range), what made it and how many trials a fallback decided."""

    estimate: inference.Estimate
    shown: inference.Interval
    made: prov.Provenance
    decided: int
    trials: int


def _part(runs: Sequence[Run], estimate: inference.Estimate, shown: inference.Interval) -> _Part:
    """The part made from ``runs``: the weakest provenance of them; the trials a fallback decided
    out of the trials of the runs that asked a store (a baseline asks nothing)."""
    made = prov.combined([prov.of_run(r) for r in runs])
    decided = [prov.decided_by_fallback(r) for r in runs]
    asking = [d for d, r in zip(decided, runs, strict=True) if prov.replays(r)]
    return _Part(estimate, shown, made, sum(sum(d) for d in decided), sum(len(d) for d in asking))


def _count_part(run: Run) -> _Part:
    estimate = inference.mean_estimate(_queries(run))
    return _part([run], estimate, estimate.log_interval(0.95))


def build(
    items: Sequence[tuple[Item, Sequence[Match]]],
    audits: Sequence[audit.Audit | str] = (),
    explain: Explain | None = None,
    failed: Sequence[tuple[Item, ItemFailure]] = (),
) -> Table:
    """The scoreboard of ``items`` (each with its matched runs). ``explain`` fills the last
    column from each row's data (default: :func:`default_explanation` of ``audits``: the audits
    the logs hold, or the names of the tasks audited). ``failed``: items whose runs failed
    (``lagrseq reproduce``), one row each after the others: FAILED, its reason, and the command
    that reruns it in the last column."""
    rows: list[dict[str, Any]] = []
    explain = default_explanation(audits) if explain is None else explain
    alpha = inference.ALPHA

    def add(item: Item, what: str, paper: str, m: Match, part: _Part, key: str, digits: int,
            paper_est: inference.Estimate | None = None, quantity: str | None = None, kind: str = "value") -> None:
        """One row: lagrseq's ``part`` against the paper's ``paper_est`` under the margin of
        ``key`` in the item's table (a trend row: against the margin's threshold)."""
        mg = margins.margin(item.id, key)
        sample = margins.paper_sample(item.id)
        ours = part.estimate
        difference = inference.contrast([ours, paper_est], [1.0, -1.0]) if paper_est is not None else None
        judged_verdict, judged_reason = inference.NO_VERDICT, "no margin stated for this quantity"
        d90 = d95 = inference.Interval(ours.n, math.nan, math.nan, math.nan, 0.9)
        if mg is not None and mg.trend:
            trend = inference.above(ours, mg.value, alpha)
            judged_verdict, judged_reason = trend.verdict, trend.reason
            d90, d95 = trend.inner, trend.wide
        elif mg is not None and paper_est is not None:
            judged = inference.tost(ours, paper_est, mg.value, alpha)
            judged_verdict, judged_reason = judged.verdict, judged.reason
            d90, d95 = judged.interval, judged.wide
        elif mg is not None:
            judged_reason = "the paper gives no ± for this value"
        elif paper_number(paper) is None:
            judged_reason = "the paper gives no value of this measure (lagrseq's)"
        verdict, reason = judged_verdict, judged_reason
        if part.made.kind == prov.FITTED:
            verdict, reason = inference.FITTED, part.made.why
        elif part.decided:
            verdict, reason = inference.NO_VERDICT, f"the fallback decided {part.decided} of {part.trials} trials (their first accepted answer)"
        row = {
            "item": item.id,
            "title": item.title.split(":")[0],
            "task": m.spec.task,
            "what": what,
            "kind": kind,
            "paper": paper,
            "paper_value": paper_est.value if paper_est is not None else paper_number(paper),
            "paper_se": paper_est.se if paper_est is not None else math.nan,
            "paper_n": sample.n if sample is not None else math.nan,
            "paper_n_why": sample.why if sample is not None else "",
            "scale": mg.scale if mg is not None else "",
            "margin": mg.value if mg is not None else math.nan,
            "margin_reason": mg.why if mg is not None else "",
            "trend": mg.trend if mg is not None else "",
            "source": source_name(m.provider) + (f" ({m.spec.preset} preset)" if m.spec.preset != "upstream" else ""),
            "provenance": part.made.kind,
            "provenance_why": part.made.why + (f"; {m.misses.text()}" if m.misses is not None else ""),
            "mean": ours.value,
            "se": ours.se,
            "ci_low": part.shown.low,
            "ci_high": part.shown.high,
            "trials": ours.n,
            "difference": difference.value if difference is not None else math.nan,
            "difference_df": difference.df if difference is not None else math.nan,
            "test_low90": d90.low,
            "test_high90": d90.high,
            "test_low95": d95.low,
            "test_high95": d95.high,
            "fallback_decided": part.decided,
            "fallback_trials": part.trials,
            # a number made on a recorded store: its answers, those the store lacked, and what
            # answered them (refused, or a fallback that can be right)
            "answers": m.misses.answers if m.misses is not None else None,
            "misses": m.misses.missed if m.misses is not None else None,
            "miss_share": m.misses.share if m.misses is not None else None,
            "misses_answered_by": m.misses.answered_by if m.misses is not None else None,
            "verdict": verdict,
            "verdict_reason": reason,
            "test_verdict": judged_verdict,
            "digits": digits,
            "note": m.note,
            "preset": m.spec.preset,
            "quantity": quantity,
            "_config": m.run.config if m.run is not None else None,
        }
        row["explained_by"] = explain(row)
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
    rows += [_failed_row(item, failure) for item, failure in failed]
    display = [_display(r) for r in rows]
    data = pd.DataFrame(rows).drop(columns=["digits", "_config"], errors="ignore")
    return Table(
        "Scoreboard: the paper's numbers beside lagrseq's (mean [95% interval, on the log scale for counts and ratios] (n)); "
        "the test against the paper's value with its ± and n (Welch TOST, 90% interval of lagrseq - paper) or, for a trend, "
        "of the slope against its threshold; verdict: reproduced / ✗ differs / inconclusive within the stated margin, fitted, "
        f"or no verdict (a fallback decided a trial; fewer than {inference.MIN_N_REPRODUCED} trials)",
        ("paper item", "quantity", "paper", "lagrseq source", "made by", "lagrseq", "test [90%]", "verdict", "gap explained by"),
        tuple(display),
        data,
    )


_Add = Callable[..., None]


def _display(r: Mapping[str, Any]) -> tuple[str, ...]:
    if r["verdict"] == FAILED_VERDICT:
        return (r["title"], r["what"], r["paper"], "—", "—", "FAILED", "n/a", f"FAILED: {r['verdict_reason']}", r["explained_by"])
    d = r["digits"]
    if math.isnan(r["ci_low"]):
        value = f"{r['mean']:.{d}f} (n={r['trials']}; no interval)"
    else:
        value = f"{r['mean']:.{d}f} [{r['ci_low']:.{d}f}, {r['ci_high']:.{d}f}] (n={r['trials']})"
    if r["note"]:
        value += f"; {r['note']}"
    if math.isnan(r["test_low90"]):
        test = "n/a"
    elif r["trend"]:
        test = f"slope [{r['test_low90']:.{d + 1}f}, {r['test_high90']:.{d + 1}f}] vs {r['margin']:+.4g}"
    else:
        test = f"{r['difference']:+.{d}f} [{r['test_low90']:.{d}f}, {r['test_high90']:.{d}f}] (df {r['difference_df']:.1f})"
    verdict = r["verdict"]
    if verdict == inference.DIFFERS:
        verdict = f"✗ {verdict}"
    if verdict == inference.NO_VERDICT:
        verdict += f": {r['verdict_reason']}"
    elif verdict != inference.FITTED and r["margin_reason"]:
        if r["trend"]:
            verdict += f" ({r['trend']}: threshold {r['margin']:+.4g} {r['scale']}: {r['margin_reason']})"
        else:
            verdict += f" (margin ±{r['margin']:.4g} {r['scale']}: {r['margin_reason']})"
    made_by = r["provenance"]
    if r.get("misses"):
        made_by += f" ({r['misses_answered_by']} misses: {r['misses']} of {r['answers']})"
    return (r["title"], r["what"], r["paper"], r["source"], made_by, value, test, verdict, r["explained_by"])


FAILED_VERDICT = "failed"
"""The verdict column of an item whose runs failed (shown as FAILED)."""


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
        "paper": f"{stated} value{'s' if stated != 1 else ''}" if stated else "—",
        "paper_value": None, "paper_se": nan, "paper_n": nan, "paper_n_why": "",
        "scale": "", "margin": nan, "margin_reason": "", "trend": "",
        "source": "", "provenance": "", "provenance_why": "",
        "mean": nan, "se": nan, "ci_low": nan, "ci_high": nan, "trials": 0,
        "difference": nan, "difference_df": nan,
        "test_low90": nan, "test_high90": nan, "test_low95": nan, "test_high95": nan,
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


def _query_rows(item: Item, reference: Mapping[str, Any], present: Sequence[Match], add: _Add) -> None:
    """Table 2 / Table 3: each cell's queries per run, the query reduction each row's two columns
    imply, and (where the margin table names them) the trends over the rows: the slope of each
    column and of the reduction."""
    header = str(item.options.get("row_header", "")).strip()

    def named(row: str) -> str:
        """A row by its header ("τ = 0", not a bare "0" that reads as a count)."""
        return f"{header} = {row}" if header else row

    def shown(m: Match, row: str) -> str:
        """The row as the table names it: the paper's row, or one of its variants by what answered
        the store's misses (Table 3 on the authors' answers: "GPT4 (misses refused)", ...)."""
        return m.row if m.row is not None and m.row.startswith(f"{row} (misses") else row

    # (row, column, source): the source is the provider and, for a row's miss variants, the variant
    counts: dict[tuple[str, str, str], tuple[Match, _Part]] = {}
    for key, paper in reference.items():
        if "|" not in key:
            continue
        row, column = key.split("|", 1)
        for m in present:
            if m.spec.column == column and _fits(m, row):
                assert m.run is not None
                part = _count_part(m.run)
                variant = shown(m, row)[len(row):]  # "" or " (misses refused)": the same on every row
                counts[(row, column, m.provider + variant)] = (m, part)
                add(item, f"{named(shown(m, row))}, {column}: queries per run", str(paper), m, part, key, 1,
                    paper_estimate(item.id, str(paper)), quantity=audit.QUERY_COLUMNS.get(column))
    columns = sorted({k.split("|", 1)[1] for k in reference if "|" in k})
    if len(columns) != 2:
        return
    seq_col = next((c for c in columns if "SEQ" in c and "without" not in c), None)
    lagr_col = next((c for c in columns if c != seq_col), None)
    if seq_col is None or lagr_col is None:
        return
    keys = sorted({k.split("|", 1)[0] for k in reference if "|" in k})
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
            part = _part([ms.run, ml.run], _reduction(ratio), _reduction_interval(ratio, 0.95))
            reductions[(key, provider)] = (ms, part)
            add(item, f"{named(shown(ms, key))}: query reduction with SEQ (%)", paper, ms, part, f"{key}|{margins.REDUCTION}", 1, paper_est)
    # trends over the rows (Table 2: over τ), where the margin table names them
    try:
        xs = {key: float(key) for key in keys}
    except ValueError:
        return
    if len(set(xs.values())) < 2:
        return
    weights = inference.slope_weights([xs[k] for k in keys])
    providers = sorted({p for (_, _, p) in counts})
    for column in (seq_col, lagr_col, margins.REDUCTION):
        if margins.margin(item.id, f"{margins.SLOPE}|{column}") is None:
            continue
        if column == margins.REDUCTION:
            papers = [paper_reductions.get(k) for k in keys]
        else:
            papers = [paper_estimate(item.id, str(reference.get(f"{k}|{column}", ""))) for k in keys]
        paper_slope = inference.contrast([p for p in papers if p is not None], weights) if all(p is not None for p in papers) else None
        unit = "points" if column == margins.REDUCTION else "queries"
        paper_text = f"{paper_slope.value:+.2f} ± {paper_slope.se:.2f} {unit} per unit {header or 'x'}" if paper_slope is not None else "n/a"
        what = (f"trend: query reduction with SEQ over {header or 'rows'} (slope)" if column == margins.REDUCTION
                else f"trend: {column} queries per run over {header or 'rows'} (slope)")
        for provider in providers:
            cells = [reductions.get((k, provider)) if column == margins.REDUCTION else counts.get((k, column, provider)) for k in keys]
            if any(c is None for c in cells):
                continue
            found = [c for c in cells if c is not None]
            estimate = inference.contrast([c[1].estimate for c in found], weights)
            made = prov.combined([c[1].made for c in found])
            part = _Part(estimate, estimate.interval(0.95), made, sum(c[1].decided for c in found), sum(c[1].trials for c in found))
            add(item, what, paper_text, found[0][0], part, f"{margins.SLOPE}|{column}", 2, paper_slope, kind="trend")


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
            part = _part([m.run, under.run], estimate, estimate.log_interval(0.95))
            add(item, f"{row} cubes: performance ratio {numerator} / {denominator}", str(paper), m, part, str(row), 3,
                paper_estimate(item.id, str(paper)),
                quantity=audit.RATIO_QUANTITY if (numerator, denominator) == ("LaGR-SEQ", "Q-learning") else None)
            early = inference.mean_estimate(stats.paired_ratios(_early_area(m.run), _early_area(under.run)))
            early_part = _part([m.run, under.run], early, early.log_interval(0.95))
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
        weights = inference.slope_weights([r[0] for r in provider_rows])
        papers = [paper_estimate(item.id, str(reference.get(_row_key(reference, r[0]), ""))) for r in provider_rows]
        paper_slope = inference.contrast([p for p in papers if p is not None], weights) if all(p is not None for p in papers) else None
        for index, (what, key) in enumerate(((f"trend: performance ratio {numerator} / {denominator} over stack size (slope)", "ratio"),
                                             ("trend: early return ratio over stack size (slope, lagrseq's measure)", margins.EARLY_AREA))):
            parts = [r[2] if index == 0 else r[3] for r in provider_rows]
            estimate = inference.contrast([p.estimate for p in parts], weights)
            part = _Part(estimate, estimate.interval(0.95), prov.combined([p.made for p in parts]),
                         sum(p.decided for p in parts), sum(p.trials for p in parts))
            shown = (f"{paper_slope.value:+.4f} ± {paper_slope.se:.4f} per cube" if paper_slope is not None and index == 0
                     else "not in the paper")
            add(item, what, shown, provider_rows[0][1], part, f"{margins.SLOPE}|{key}", 3,
                paper_slope if index == 0 else None, kind="trend")


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
