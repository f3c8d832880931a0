"""The scoreboard: every number the paper states beside lagrseq's value from every source.

For each reference value of a table item (Table 2, Table 3, the stack-size ratios) and the query
reductions those tables imply (1 - LaGR-SEQ / LaGR), one row per source the logs hold (the mock,
a calibrated mock profile, the authors' recorded answers, any other recorded store): what made the
number (:mod:`lagrseq.analysis.provenance`, from the run's logged provider and configuration),
lagrseq's mean with its 95% Student-t interval and n, and a three-way verdict against the paper's
value (:func:`lagrseq.analysis.inference.judge`): ``reproduced`` (the 90% interval lies inside the
margin band, at least 5 trials), ``differs`` (the 95% interval excludes the band) or
``inconclusive``; a fitted number's verdict is ``fitted``, whatever its interval. The margin is the
larger of 10% of the paper's value and the paper's own +- (:func:`inference.margin_for`), stated
per row. The last column says what explains the gap: a callable that :func:`build` takes
(``explain``); by default, where the logs hold an audit of the row's task,
:func:`lagrseq.analysis.audit.gap_explained_by` (the audit rows that account for the gap, with
their sum, or ``unexplained``), else a link to the item.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from lagrseq.analysis import audit, inference, stats
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.items import ItemFailure, Match, fallback_decided
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


def _reduction(seq: np.ndarray, lagr: np.ndarray, level: float) -> inference.Interval:
    """1 - mean(seq) / mean(lagr), in percent, with the delta-method t interval of the ratio
    (:func:`inference.ratio_interval`) turned around."""
    r = inference.ratio_interval(seq, lagr, level)
    return inference.Interval(r.n, 100 * (1 - r.mean), 100 * (1 - r.high), 100 * (1 - r.low), level)


def margin_reason(value: float, spread: float | None) -> str:
    """Why the margin is what it is: 10% of the paper's value, or its own +- where larger."""
    relative = inference.RELATIVE_MARGIN * abs(value)
    if spread is not None and abs(spread) > relative:
        return "the paper's ±"
    return f"{inference.RELATIVE_MARGIN:.0%} of the paper's value"


def default_explanation(audits: Sequence[audit.Audit | str]) -> Explain:
    """The default "gap explained by": where the logs hold an audit of the row's task, the audit
    rows that account for the gap (:func:`lagrseq.analysis.audit.gap_explained_by`; a task named
    without its audit gets a link to it); else a link to the item."""
    built = [a for a in audits if not isinstance(a, str)]
    named = {a if isinstance(a, str) else a.task for a in audits}

    def explain(row: Mapping[str, Any]) -> str:
        if built and row["task"] in named:
            found = audit.gap_explained_by(
                built, row["task"], row["preset"], row["quantity"], row["mean"], row["paper"], row["_config"]
            )
            if found:
                return found
        return f"#audit-{row['task']}" if row["task"] in named and not built else f"#{row['item']}"

    return explain


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

    def add(item: Item, what: str, paper: str, m: Match, made: prov.Provenance, inner: inference.Interval, wide: inference.Interval, digits: int, spread: float | None = None, quantity: str | None = None) -> None:
        value = paper_number(paper)
        spread = paper_spread(paper) if spread is None else spread
        margin = inference.margin_for(value, spread) if value is not None else float("nan")
        if value is None:
            verdict, reason = inference.INCONCLUSIVE, "no paper value"
        else:
            judged = inference.judge(inner, wide, value, margin)
            verdict, reason = judged.verdict, judged.reason
            if made.kind == prov.FITTED:
                verdict, reason = inference.FITTED, made.why
            elif m.run is not None and m.misses is not None and m.misses.answered_by_fallback:
                decided, trials = fallback_decided(m.run)
                if decided and verdict in (inference.REPRODUCED, inference.DIFFERS):
                    verdict = inference.INCONCLUSIVE
                    reason = (
                        f"no verdict: the {m.misses.answered_by} fallback, not the recorded answers, gave the first "
                        f"accepted answer in {decided} of {trials} trials"
                    )
        row = {
            "item": item.id,
            "title": item.title.split(":")[0],
            "task": m.spec.task,
            "what": what,
            "paper": paper,
            "paper_value": value,
            "margin": margin,
            "margin_reason": margin_reason(value, spread) if value is not None else "",
            "source": source_name(m.provider) + (f" ({m.spec.preset} preset)" if m.spec.preset != "upstream" else ""),
            "provenance": made.kind,
            "provenance_why": made.why + (f"; {m.misses.text()}" if m.misses is not None else ""),
            "mean": wide.mean,
            "ci_low": wide.low,
            "ci_high": wide.high,
            "ci90_low": inner.low,
            "ci90_high": inner.high,
            "trials": wide.n,
            "verdict": verdict,
            "verdict_reason": reason,
            "digits": digits,
            "note": m.note,
            # a number made on a recorded store: its answers, those the store lacked, and what
            # answered them (refused, or a fallback that can be right)
            "answers": m.misses.answers if m.misses is not None else None,
            "misses": m.misses.missed if m.misses is not None else None,
            "miss_share": m.misses.share if m.misses is not None else None,
            "misses_answered_by": m.misses.answered_by if m.misses is not None else None,
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
            header = str(item.options.get("row_header", "")).strip()

            def named(row: str, header: str = header) -> str:
                """A row by its header ("τ = 0", not a bare "0" that reads as a count)."""
                return f"{header} = {row}" if header else row

            for key, paper in reference.items():
                if "|" not in key:
                    continue
                row, column = key.split("|", 1)
                for m in present:
                    if m.spec.column == column and _fits(m, row):
                        assert m.run is not None
                        values = _queries(m.run)
                        shown = m.row if m.row is not None and m.row.startswith(f"{row} (misses") else row
                        add(item, f"{named(shown)}, {column}: queries per run", str(paper), m, prov.of_run(m.run),
                            inference.t_interval(values, 1 - 2 * alpha), inference.t_interval(values, 1 - alpha), 1,
                            quantity=audit.QUERY_COLUMNS.get(column))
            # the query reduction SEQ brings, where the paper gives both columns of a row
            columns = sorted({k.split("|", 1)[1] for k in reference if "|" in k})
            if len(columns) == 2:
                seq_col = next((c for c in columns if "SEQ" in c and "without" not in c), None)
                lagr_col = next((c for c in columns if c != seq_col), None)
                for key in sorted({k.split("|", 1)[0] for k in reference if "|" in k}):
                    top, bottom = paper_number(str(reference.get(f"{key}|{seq_col}", ""))), paper_number(str(reference.get(f"{key}|{lagr_col}", "")))
                    if top is None or bottom is None or seq_col is None:
                        continue
                    paper = f"{100 * (1 - top / bottom):.1f}%"
                    seq_runs = [m for m in present if m.spec.column == seq_col and _fits(m, key)]
                    for ms in seq_runs:
                        ml = next((m for m in present if m.spec.column == lagr_col and m.provider == ms.provider and m.row == ms.row), None)
                        if ml is None or ms.run is None or ml.run is None:
                            continue
                        seq, lagr = _queries(ms.run), _queries(ml.run)
                        made = prov.combined([prov.of_run(ms.run), prov.of_run(ml.run)])
                        shown = ms.row if ms.row is not None and ms.row.startswith(f"{key} (misses") else key
                        add(item, f"{named(shown)}: query reduction with SEQ (%)", paper, ms, made,
                            _reduction(seq, lagr, 1 - 2 * alpha), _reduction(seq, lagr, 1 - alpha), 1, spread=0.0)
        elif item.render == "ratio-table":
            numerator = str(item.options.get("numerator", ""))
            denominator = str(item.options.get("denominator", ""))
            for row, paper in reference.items():
                for m in present:
                    if m.spec.column != numerator or not _fits(m, row):
                        continue
                    under = next((b for b in present if b.spec.column == denominator and b.row == m.row), None)
                    if under is None or m.run is None or under.run is None:
                        continue
                    ratios = stats_ratios(m.run, under.run)
                    made = prov.combined([prov.of_run(m.run), prov.of_run(under.run)])
                    add(item, f"{row} cubes: performance ratio {numerator} / {denominator}", str(paper), m, made,
                        inference.t_interval(ratios, 1 - 2 * alpha), inference.t_interval(ratios, 1 - alpha), 3,
                        quantity=audit.RATIO_QUANTITY if (numerator, denominator) == ("LaGR-SEQ", "Q-learning") else None)
    rows += [_failed_row(item, failure) for item, failure in failed]
    display = []
    for r in rows:
        if r["verdict"] == FAILED_VERDICT:
            display.append((r["title"], r["what"], r["paper"], "—", "—", "FAILED", f"FAILED: {r['verdict_reason']}", r["explained_by"]))
            continue
        d = r["digits"]
        value = f"{r['mean']:.{d}f} [{r['ci_low']:.{d}f}, {r['ci_high']:.{d}f}] (n={r['trials']})"
        if np.isnan(r["ci_low"]):
            value = f"{r['mean']:.{d}f} (n={r['trials']}; no interval)"
        if r["note"]:
            value += f"; {r['note']}"
        verdict = r["verdict"]
        if verdict == inference.DIFFERS:
            verdict = f"✗ {verdict}"
        if r["paper_value"] is not None and r["verdict"] != inference.FITTED:
            verdict += f" (margin ±{r['margin']:.3g}: {r['margin_reason']})"
        made_by = r["provenance"]
        if r["misses"]:
            made_by += f" ({r['misses_answered_by']} misses: {r['misses']} of {r['answers']})"
        display.append((r["title"], r["what"], r["paper"], r["source"], made_by, value, verdict, r["explained_by"]))
    data = pd.DataFrame(rows).drop(columns=["digits", "_config"], errors="ignore")
    return Table(
        "Scoreboard: the paper's numbers beside lagrseq's (mean [95% t-interval] (n)); verdict: reproduced / ✗ differs / "
        "inconclusive against the paper's value ± margin (TOST), or fitted",
        ("paper item", "quantity", "paper", "lagrseq source", "made by", "lagrseq", "verdict", "gap explained by"),
        tuple(display),
        data,
    )


FAILED_VERDICT = "failed"
"""The verdict column of an item whose runs failed (shown as FAILED)."""


def _failed_row(item: Item, failure: ItemFailure) -> dict[str, Any]:
    """The scoreboard's row for an item whose runs failed: no number, its reason and advice, and
    the command that reruns it alone (the last column)."""
    reference = item.options.get("reference", {})
    stated = len(reference) if isinstance(reference, dict) else 0
    return {
        "item": item.id,
        "title": item.title.split(":")[0],
        "task": item.runs[0].task if item.runs else "",
        "what": "not measured: a run it needs failed",
        "paper": f"{stated} value{'s' if stated != 1 else ''}" if stated else "—",
        "paper_value": None,
        "margin": float("nan"),
        "margin_reason": "",
        "source": "",
        "provenance": "",
        "provenance_why": "",
        "mean": float("nan"),
        "ci_low": float("nan"),
        "ci_high": float("nan"),
        "ci90_low": float("nan"),
        "ci90_high": float("nan"),
        "trials": 0,
        "verdict": FAILED_VERDICT,
        "verdict_reason": f"{failure.reason}; {failure.advice}",
        "note": "",
        "preset": "",
        "quantity": None,
        "explained_by": f"rerun it alone: {failure.rerun}",
    }


def stats_ratios(top: Run, bottom: Run) -> np.ndarray:
    """Per-trial ratios of total return, paired by trial index (the stack-size table's quantity)."""
    return stats.paired_ratios(top.total_per_trial("return"), bottom.total_per_trial("return"))
