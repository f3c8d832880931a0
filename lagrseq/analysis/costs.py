"""What the LLM cost: queries decided, how each was decided (sent to a live server, replayed from
a recorded store, the mock, or decided without a model: a refused miss, a calibrated draw),
tokens and US dollars, per run and per method.

Only ``/query`` records and metadata are used (no transition is read). The outcome columns add
up to the query count. USD spent is the sum of each query's logged ``cost_usd`` (n/a when one is
null: an unpriced model); with a ``price`` function (model, prompt tokens, completion tokens ->
USD or None when the model has no price), the answers are also re-costed from their logged token
usage, so a newer price table re-costs old runs without touching them. Unknown usage (logged as
null: the authors' recorded answers have none) makes tokens and the re-costed USD n/a, never 0.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table, number
from lagrseq.logs.events import OUTCOMES, query_outcome

Price = Callable[[str, int, int], float | None]
DECIDED = ("refused_miss", "calibrated_draw")
"""Outcomes decided without asking a model: no tokens, nothing to price."""


def _outcomes(queries: pd.DataFrame) -> pd.Series:
    """Each query's outcome: the logged one (log format 4), else derived from its provider and
    source (:func:`lagrseq.logs.events.query_outcome`), so old logs count alike."""
    logged = queries["outcome"] if "outcome" in queries else pd.Series([None] * len(queries), index=queries.index)
    derived = [
        found if isinstance(found, str) else query_outcome(provider, source)
        for found, provider, source in zip(logged, queries["provider"], queries["source"], strict=True)
    ]
    return pd.Series(derived, index=queries.index, dtype=object)


def _tokens(answered: pd.DataFrame, column: str) -> float:
    """The sum of a token column over answers a model gave; NaN when one is unknown (null)."""
    values = answered[column]
    return float("nan") if values.isna().any() else float(values.sum())


def _repriced(answered: pd.DataFrame, price: Price) -> float:
    total = 0.0
    for model, prompt, completion in zip(
        answered["model"], answered["prompt_tokens"], answered["completion_tokens"], strict=True
    ):
        if pd.isna(prompt) or pd.isna(completion):
            return float("nan")
        usd = price(str(model), int(prompt), int(completion))
        if usd is None:
            return float("nan")
        total += usd
    return total


def _row(run: Run, price: Price | None) -> dict[str, object]:
    queries = run.queries
    sent = queries[queries["queried"].astype(bool)] if not queries.empty else queries
    outcome = _outcomes(sent) if len(sent) else pd.Series(dtype=object)
    answered = sent[~outcome.isin(DECIDED)] if len(sent) else sent
    costs = sent["cost_usd"] if len(sent) else pd.Series(dtype=float)
    row: dict[str, object] = {
        **run.key.columns(),
        "variant": run.key.variant,
        "trials": len(run.trials),
        "decisions": int(len(queries)),
        "queries": int(len(sent)),
        **{name: int((outcome == name).sum()) for name in OUTCOMES},
        "accepted": int((sent["accepted"] == True).sum()) if len(sent) else 0,  # noqa: E712 (None counts as not accepted)
        "prompt_tokens": _tokens(answered, "prompt_tokens") if len(answered) else 0.0,
        "completion_tokens": _tokens(answered, "completion_tokens") if len(answered) else 0.0,
        "usd_spent": float("nan") if costs.isna().any() else float(costs.sum()),
    }
    if price is not None:
        row["usd_repriced"] = _repriced(answered, price) if len(answered) else 0.0
    return row


def run_costs(runs: Sequence[Run], price: Price | None = None) -> pd.DataFrame:
    """One row per run: decisions, queries, queries per outcome (they add up to ``queries``),
    tokens (NaN: some usage unknown), USD spent and, with ``price``, re-costed (NaN: unknown)."""
    return pd.DataFrame([_row(run, price) for run in runs])


def _usd(value: float) -> str:
    return "n/a" if np.isnan(value) else f"{value:.4f}"


def _count(value: float) -> str:
    return "n/a" if np.isnan(value) else str(int(value))


_OUTCOME_HEADS = tuple(name.replace("_", " ") for name in OUTCOMES)
_COUNTS = ("trials", "queries", "per trial", *_OUTCOME_HEADS, "tokens", "USD spent")
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
            *(str(int(r[name])) for name in OUTCOMES),
            _count(float(r.prompt_tokens) + float(r.completion_tokens)),
            _usd(float(r.usd_spent)),
        ]
        if priced:
            cells.append(_usd(float(r.usd_repriced)))
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
    """Costs summed over the runs of each task and method (an unknown count or price stays
    unknown)."""
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
