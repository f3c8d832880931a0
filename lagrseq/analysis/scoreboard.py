"""The scoreboard: every number the paper states beside lagrseq's value from every source.

For each reference value of a table item (Table 2, Table 3, the stack-size ratios) and the query
reductions those tables imply (1 - LaGR-SEQ / LaGR), one row per source the logs hold (the mock,
a calibrated mock profile, the authors' recorded answers, any other recorded store): lagrseq's
mean with its 95% percentile-bootstrap interval, and whether the paper's value falls inside it.
The last column links what explains the gap (the audit, where the logs hold one, else the item).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from lagrseq.analysis import stats
from lagrseq.analysis.items import Match
from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table
from lagrseq.suite import PAPER_MODEL_ROWS, RECORDED_NAME, Item, is_authors_provider

_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def paper_number(text: str) -> float | None:
    found = _NUMBER.search(text)
    return float(found.group()) if found else None


def source_name(provider: str) -> str:
    if is_authors_provider(provider):
        return RECORDED_NAME
    if provider.startswith("recorded:"):
        return "recorded store " + provider.split(":", 1)[1].rstrip("/").rsplit("/", 1)[-1]
    return provider


def _fits(m: Match, row: str) -> bool:
    """Whether a matched run stands for the paper's ``row``: the same row, its recorded-GPT
    variant, or (a row per model, Table 3) a run of that model."""
    if m.row == row or m.row == f"{row} ({RECORDED_NAME})":
        return True
    if m.spec.row is not None and "{provider}" in m.spec.row and m.run is not None:
        model = m.run.config.get("llm", {}).get("model", "")
        return PAPER_MODEL_ROWS.get(model) == row
    return False


def _queries(run: Run) -> np.ndarray:
    return np.array(list(run.total_per_trial("queries").values()), dtype=float)


def _reduction(seq: np.ndarray, lagr: np.ndarray, rng: np.random.Generator) -> tuple[float, float, float]:
    """1 - mean(seq) / mean(lagr) with a percentile-bootstrap interval (each resampled)."""
    point = 1 - seq.mean() / lagr.mean()
    a = seq[rng.integers(0, len(seq), size=(2000, len(seq)))].mean(axis=1)
    b = lagr[rng.integers(0, len(lagr), size=(2000, len(lagr)))].mean(axis=1)
    low, high = np.percentile(1 - a / b, [2.5, 97.5])
    return float(point), float(low), float(high)


def build(items: Sequence[tuple[Item, Sequence[Match]]], audit_tasks: Sequence[str] = ()) -> Table:
    rows: list[dict[str, Any]] = []

    def add(item: Item, what: str, paper: str, m: Match, mean: float, low: float, high: float, n: int, digits: int) -> None:
        value = paper_number(paper)
        inside = value is not None and low <= value <= high
        task = m.spec.task
        explain = f"#audit-{task}" if task in audit_tasks else f"#{item.id}"
        rows.append(
            {
                "item": item.id,
                "title": item.title.split(":")[0],
                "what": what,
                "paper": paper,
                "source": source_name(m.provider) + (f" ({m.spec.preset} preset)" if m.spec.preset != "upstream" else ""),
                "mean": mean,
                "ci_low": low,
                "ci_high": high,
                "trials": n,
                "paper_inside": inside,
                "explained_by": explain,
                "digits": digits,
                "note": m.note,
            }
        )

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
                        s = stats.summarize(_queries(m.run), stats.generator(f"{m.run.key.name}/queries"))
                        add(item, f"{named(row)}, {column}: queries per run", str(paper), m, s.mean, s.ci_low, s.ci_high, s.n, 1)
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
                        point, low, high = _reduction(_queries(ms.run), _queries(ml.run), stats.generator(f"{ms.run.key.name}/reduction"))
                        add(item, f"{named(key)}: query reduction with SEQ (%)", paper, ms, 100 * point, 100 * low, 100 * high, len(ms.run.trials), 1)
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
                    ratios = stats.paired_ratios(m.run.total_per_trial("return"), under.run.total_per_trial("return"))
                    s = stats.summarize(ratios, stats.generator(f"{m.run.key.name}/{under.run.key.name}/ratio"))
                    add(item, f"{row} cubes: performance ratio", str(paper), m, s.mean, s.ci_low, s.ci_high, s.n, 3)
    display = []
    for r in rows:
        d = r["digits"]
        mark = "inside" if r["paper_inside"] else "✗ outside"
        value = f"{r['mean']:.{d}f} [{r['ci_low']:.{d}f}, {r['ci_high']:.{d}f}] (n={r['trials']})"
        if r["note"]:
            value += f"; {r['note']}"
        display.append((r["title"], r["what"], r["paper"], r["source"], value, mark, r["explained_by"]))
    data = pd.DataFrame(rows).drop(columns=["digits"], errors="ignore")
    return Table(
        "Scoreboard: the paper's numbers beside lagrseq's (mean [95% bootstrap CI]); ✗ where the paper's value lies outside",
        ("paper item", "quantity", "paper", "lagrseq source", "lagrseq", "paper's value", "gap explained by"),
        tuple(display),
        data,
    )
