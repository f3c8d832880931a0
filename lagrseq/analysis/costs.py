"""What the LLM cost: queries sent, where the answers came from (recorded store, live server,
mock), tokens and US dollars, per run and per method.

Only ``/query`` records and metadata are used (no transition is read). USD is the sum of each
query's logged ``cost_usd``; with a ``price`` function (model, prompt tokens, completion tokens ->
USD or None when the model has no price), it is also recomputed from the logged token usage, so
a newer price table re-costs old runs without touching them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table, number

Price = Callable[[str, int, int], float | None]
SOURCES = ("recorded", "live", "mock")


def _repriced(queries: pd.DataFrame, price: Price) -> float:
    total = 0.0
    for model, prompt, completion in zip(
        queries["model"], queries["prompt_tokens"], queries["completion_tokens"], strict=True
    ):
        usd = price(str(model), int(prompt or 0), int(completion or 0))
        if usd is None:
            return float("nan")
        total += usd
    return total


def run_costs(runs: Sequence[Run], price: Price | None = None) -> pd.DataFrame:
    """One row per run: decisions, queries, answers by source, tokens, USD."""
    rows = []
    for run in runs:
        queries = run.queries
        sent = queries[queries["queried"].astype(bool)] if not queries.empty else queries
        source = sent["source"].value_counts() if not sent.empty else pd.Series(dtype=int)
        row = {
            **run.key.columns(),
            "variant": run.key.variant,
            "trials": len(run.trials),
            "decisions": int(len(queries)),
            "queries": int(len(sent)),
            **{f"from_{s}": int(source.get(s, 0)) for s in SOURCES},
            "accepted": int((sent["accepted"] == True).sum()) if len(sent) else 0,  # noqa: E712 (None counts as not accepted)
            "prompt_tokens": int(sent["prompt_tokens"].fillna(0).sum()) if len(sent) else 0,
            "completion_tokens": int(sent["completion_tokens"].fillna(0).sum()) if len(sent) else 0,
            "usd_logged": float(sent["cost_usd"].fillna(0.0).sum()) if len(sent) else 0.0,
        }
        if price is not None:
            row["usd_repriced"] = _repriced(sent, price) if len(sent) else 0.0
        rows.append(row)
    return pd.DataFrame(rows)


def _usd(value: float) -> str:
    return "n/a" if np.isnan(value) else f"{value:.4f}"


_COUNTS = ("trials", "queries", "per trial", "recorded", "live", "mock", "tokens", "USD")
_KEYS = ("task", "method", "preset", "provider", "seed", "config", "variant")


def _table(
    title: str, first: list[str], leads: Sequence[tuple[str, ...]], data: pd.DataFrame, priced: bool
) -> Table:
    """Display rows: each row's ``leads`` cells, then the counts both cost tables share."""
    columns = [*first, *_COUNTS] + (["USD at current prices"] if priced else [])
    rows = []
    for lead, (_, r) in zip(leads, data.iterrows(), strict=True):
        cells = [
            *lead,
            str(r.trials),
            str(r.queries),
            number(r.queries / r.trials if r.trials else float("nan"), 1),
            str(r.from_recorded),
            str(r.from_live),
            str(r.from_mock),
            str(r.prompt_tokens + r.completion_tokens),
            _usd(r.usd_logged),
        ]
        if priced:
            cells.append(_usd(r.usd_repriced))
        rows.append(tuple(cells))
    return Table(title, tuple(columns), tuple(rows), data)


def by_run(runs: Sequence[Run], price: Price | None = None) -> Table:
    """Costs of each run."""
    frame = run_costs(runs, price)
    leads = [
        (
            f"{r.task}/{r.method} {r.preset} {r.provider} seed{r.seed} {r.config}"
            + (f" {r.variant}" if r.variant else ""),
        )
        for _, r in frame.iterrows()
    ]
    return _table("LLM costs per run", ["run"], leads, frame, price is not None)


def by_method(runs: Sequence[Run], price: Price | None = None) -> Table:
    """Costs summed over the runs of each task and method (an unknown price stays unknown)."""
    frame = run_costs(runs, price)
    if frame.empty:
        data = frame
    else:
        groups = frame.groupby(["task", "method"], sort=True)
        sums = [c for c in frame.columns if c not in _KEYS]
        data = groups[sums].agg(lambda column: column.sum(skipna=False)).reset_index()
        data.insert(2, "runs", groups.size().to_numpy())
    leads = [(r.task, r.method, str(r.runs)) for _, r in data.iterrows()]
    return _table(
        "LLM costs per method", ["task", "method", "runs"], leads, data, price is not None
    )
