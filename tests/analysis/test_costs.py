"""Costs from /query records only: counts by outcome, tokens, spent and re-priced USD."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from lagrseq.analysis import costs, loading
from lagrseq.analysis.loading import EPISODE_COLUMNS, QUERY_COLUMNS, Run, RunKey


def _query(
    source: str | None,
    model: str = "gpt-4",
    tokens: tuple[int, int] | None = (100, 10),
    usd: float | None = 0.0,
    provider: str = "recorded",
) -> dict:
    queried = source is not None
    return {
        "trial": 0,
        "decision": int(queried),
        "queried": queried,
        "accepted": queried and source == "live",
        "model": model if queried else None,
        "provider": provider if queried else None,
        "prompt_tokens": tokens[0] if queried and tokens else None,
        "completion_tokens": tokens[1] if queried and tokens else None,
        "cost_usd": usd if queried else None,
        "source": source,
    }


def _run(method: str, records: list[dict], trials: int = 2, provider: str = "recorded:s") -> Run:
    frame = pd.DataFrame.from_records(records, columns=list(QUERY_COLUMNS))
    key = RunKey("cube-stacking", method, "upstream", provider, 0, method[:8].ljust(8, "0"))
    return Run(
        key, {}, (), tuple(range(trials)), pd.DataFrame(columns=list(EPISODE_COLUMNS)), frame, 0
    )


RUNS = [
    _run(
        "lagr-seq",
        [
            _query("recorded", usd=0.01),
            _query("live", usd=0.02),
            _query(None),
            _query("recorded", usd=0.01),
        ],
    ),
    _run(
        "lagr",
        [_query("mock", model="mock", provider="mock"), _query("mock", model="mock", provider="mock"), _query(None)],
        provider="mock",
    ),
    _run("lagr", [_query("live", model="gpt-3.5-turbo", usd=0.5)]),
]


def test_costs_per_run_count_outcomes_tokens_and_usd() -> None:
    table = costs.by_run(RUNS)
    data = table.data
    first = data.iloc[0]
    assert (first.decisions, first.queries) == (4, 3)
    assert (first.replayed, first.sent, first.mock) == (2, 1, 0)
    assert (first.prompt_tokens, first.completion_tokens) == (300, 30)
    assert first.usd_spent == pytest.approx(0.04)
    assert table.rows[0][3] == "1.5"  # queries per trial
    assert "usd_repriced" not in data


def test_costs_per_method_sum_runs() -> None:
    table = costs.by_method(RUNS)
    lagr = table.data[table.data["method"] == "lagr"].iloc[0]
    assert (lagr.runs, lagr.trials, lagr.queries) == (2, 4, 3)
    assert (lagr.mock, lagr.sent) == (2, 1)
    assert lagr.usd_spent == pytest.approx(0.5)


def test_a_price_function_re_costs_from_token_usage() -> None:
    def price(model: str, prompt: int, completion: int) -> float | None:
        per_token = {"gpt-4": 1e-4, "gpt-3.5-turbo": 1e-6}.get(model)
        return None if per_token is None else per_token * (prompt + completion)

    data = costs.by_run(RUNS, price).data
    assert data.loc[0, "usd_repriced"] == pytest.approx(3 * 110 * 1e-4)
    assert math.isnan(data.loc[1, "usd_repriced"])  # the mock's model has no price
    assert data.loc[2, "usd_repriced"] == pytest.approx(110 * 1e-6)
    assert costs.by_run(RUNS, price).rows[1][-1] == "n/a"


def test_costs_from_real_logs_read_no_transition(runs_dir: Path) -> None:
    logs = loading.load([runs_dir])
    data = costs.by_run(logs.runs).data
    seq = data[data["method"] == "lagr-seq"].iloc[0]
    run = next(r for r in logs.runs if r.key.method == "lagr-seq")
    assert seq.queries == sum(run.total_per_trial("queries").values())
    assert seq.mock == seq.queries and seq.usd_spent == 0.0
    baseline = data[data["method"] == "baseline"].iloc[0]
    assert baseline.queries == 0


def test_an_unknown_price_stays_unknown_per_method() -> None:
    def price(model: str, prompt: int, completion: int) -> float | None:
        return None if model == "mock" else 1.0

    data = costs.by_method(RUNS, price).data
    lagr = data[data["method"] == "lagr"].iloc[0]
    assert math.isnan(lagr.usd_repriced)  # one of its runs used an unpriced model
    seq = data[data["method"] == "lagr-seq"].iloc[0]
    assert seq.usd_repriced == 3.0


OUTCOME_RUN = _run(
    "lagr-seq",
    [
        _query("recorded", model="gpt-3.5-turbo-0613", tokens=None),  # an authors' answer: no usage
        _query("live", model="gpt-3.5-turbo", usd=None),  # a live answer the price table lacks
        _query("mock", model="mock"),  # a store miss the mock answered
        {**_query("miss", tokens=None), "accepted": False},
        _query("calibrated", tokens=None),
        _query(None),
    ],
)


def test_outcome_columns_add_up_to_the_queries_and_unknown_usage_is_not_zero() -> None:
    def price(model: str, prompt: int, completion: int) -> float | None:
        return 1e-6 * (prompt + completion)

    table = costs.by_run([OUTCOME_RUN], price)
    row = table.data.iloc[0]
    counts = {name: int(row[name]) for name in ("sent", "replayed", "mock", "mock_fallback", "refused_miss", "calibrated_draw")}
    assert counts == {"sent": 1, "replayed": 1, "mock": 0, "mock_fallback": 1, "refused_miss": 1, "calibrated_draw": 1}
    assert sum(counts.values()) == row.queries == 5
    cells = dict(zip(table.columns, table.rows[0], strict=True))
    assert cells["tokens"] == "n/a"  # the authors' answer logged no usage
    assert cells["USD spent"] == "n/a"  # the unpriced live answer
    assert cells["USD at current prices"] == "n/a"
    assert cells["refused miss"] == cells["calibrated draw"] == cells["mock fallback"] == "1"


def test_decided_queries_need_no_usage_to_be_priced() -> None:
    run = _run("lagr-seq", [_query("recorded", usd=0.0), _query("miss", tokens=None), _query("calibrated", tokens=None)])
    table = costs.by_run([run], lambda model, prompt, completion: 1e-3 * (prompt + completion))
    cells = dict(zip(table.columns, table.rows[0], strict=True))
    assert (cells["tokens"], cells["USD spent"], cells["USD at current prices"]) == ("110", "0.0000", "0.1100")


def test_an_old_log_without_outcomes_counts_its_queries_by_derived_outcome() -> None:
    golden = Path(__file__).resolve().parents[2] / "fixtures" / "golden"
    (run,) = loading.load([golden]).runs
    assert "outcome" not in run.queries or run.queries["outcome"].isna().all()  # written before log format 4
    row = costs.run_costs([run]).iloc[0]
    assert row.queries > 0 and row.mock == row.queries
    assert sum(int(row[name]) for name in ("sent", "replayed", "mock_fallback", "refused_miss", "calibrated_draw")) == 0
