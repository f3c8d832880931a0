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
            "task": run.key.task,
            "method": run.key.method,
            "preset": run.key.preset,
            "provider": run.key.provider,
            "seed": run.key.seed,
            "config": run.key.digest,
            "variant": run.key.variant,
            "trials": len(run.trials),
            "decisions": int(len(queries)),
            "queries": int(len(sent)),
            **{f"from_{s}": int(source.get(s, 0)) for s in SOURCES},
            "accepted": int(sent["accepted"].fillna(False).astype(bool).sum()) if len(sent) else 0,
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


def by_run(runs: Sequence[Run], price: Price | None = None) -> Table:
    """Costs of each run."""
    frame = run_costs(runs, price)
    columns = ["run", "trials", "queries", "per trial", "recorded", "live", "mock", "tokens", "USD"]
    if price is not None:
        columns.append("USD at current prices")
    rows = []
    for _, r in frame.iterrows():
        name = f"{r.task}/{r.method} {r.preset} {r.provider} seed{r.seed} {r.config}"
        if r.variant:
            name += f" {r.variant}"
        cells = [
            name,
            str(r.trials),
            str(r.queries),
            number(r.queries / r.trials if r.trials else float("nan"), 1),
            str(r.from_recorded),
            str(r.from_live),
            str(r.from_mock),
            str(r.prompt_tokens + r.completion_tokens),
            _usd(r.usd_logged),
        ]
        if price is not None:
            cells.append(_usd(r.usd_repriced))
        rows.append(tuple(cells))
    return Table("LLM costs per run", tuple(columns), tuple(rows), frame)


def by_method(runs: Sequence[Run], price: Price | None = None) -> Table:
    """Costs summed over the runs of each task and method."""
    frame = run_costs(runs, price)
    if frame.empty:
        data = frame
    else:
        sums = [
            c
            for c in frame.columns
            if c not in ("task", "method", "preset", "provider", "seed", "config", "variant")
        ]
        data = frame.groupby(["task", "method"], sort=True)[sums].sum().reset_index()
        data.insert(2, "runs", frame.groupby(["task", "method"], sort=True).size().to_numpy())
    columns = [
        "task",
        "method",
        "runs",
        "trials",
        "queries",
        "per trial",
        "recorded",
        "live",
        "mock",
        "tokens",
        "USD",
    ]
    if price is not None:
        columns.append("USD at current prices")
    rows = []
    for _, r in data.iterrows():
        cells = [
            r.task,
            r.method,
            str(r.runs),
            str(r.trials),
            str(r.queries),
            number(r.queries / r.trials if r.trials else float("nan"), 1),
            str(r.from_recorded),
            str(r.from_live),
            str(r.from_mock),
            str(r.prompt_tokens + r.completion_tokens),
            _usd(r.usd_logged),
        ]
        if price is not None:
            cells.append(_usd(r.usd_repriced))
        rows.append(tuple(cells))
    return Table("LLM costs per method", tuple(columns), tuple(rows), data)
