"""Provenance and verdicts on the scoreboard (issue 19): what made each number, read from the
logged provider and configuration; three-way equivalence against the paper with a stated margin;
``fitted`` for a fitted number whatever its interval; never ``reproduced`` below 5 trials."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lagrseq import config as cfg
from lagrseq.analysis import inference, items, loading, scoreboard
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.loading import EPISODE_COLUMNS, QUERY_COLUMNS, Run, RunKey
from lagrseq.analysis.tables import to_markdown
from lagrseq.running import runner
from lagrseq.suite import AUTHORS_STORE_NAME, Item, RunSpec

# -- one test per provenance class --------------------------------------------------------------


def test_authors_answers_are_the_store_reproduce_imports() -> None:
    made = prov.provenance(f"recorded:/tmp/out/{AUTHORS_STORE_NAME}", {"method": "lagr-seq", "llm": {"model": "gpt-4"}})
    assert made.kind == prov.AUTHORS and prov.AUTHORS_STORE_NAME == AUTHORS_STORE_NAME


def test_another_recorded_store_is_an_open_model_named_by_its_model() -> None:
    made = prov.provenance("recorded:recorded_llm/smollm2-135m-cube-t0.jsonl", {"method": "lagr", "llm": {"model": "SmolLM2-135M-Instruct"}})
    assert made.kind == prov.OPEN_MODEL and "SmolLM2-135M-Instruct" in made.why
    assert prov.provenance("local:model.gguf", {"method": "lagr"}).kind == prov.OPEN_MODEL


@pytest.mark.parametrize(("profile", "temperature", "why"), [("authors-t0", 0.0, "calibrated"), ("authors-t0", 0.5, "temperature model"), ("authors-gpt4", 0.0, "calibrated")])
def test_profiles_calibrated_on_the_authors_answers_and_their_temperature_model_are_fitted(profile: str, temperature: float, why: str) -> None:
    made = prov.provenance(f"mock:{profile}", {"method": "lagr-seq", "llm": {"temperature": temperature}})
    assert made.kind == prov.FITTED and why in made.why


@pytest.mark.parametrize("provider", ["mock", "mock:ideal", "mock:oracle"])
def test_the_plain_mock_and_profiles_fixed_by_definition_are_rule_based(provider: str) -> None:
    assert prov.provenance(provider, {"method": "lagr", "llm": {"temperature": 1.0}}).kind == prov.RULE_BASED


def test_a_baseline_asks_nothing_whatever_provider_its_log_names() -> None:
    assert prov.provenance("mock:authors-t0", {"method": "baseline"}).kind == prov.NO_LLM
    # a ratio over a baseline takes its numerator's class; fitted wins over anything
    parts = [prov.provenance("mock:authors-t0", {"method": "lagr"}), prov.provenance("mock", {"method": "baseline"})]
    assert prov.combined(parts).kind == prov.FITTED


def test_an_unknown_or_malformed_provider_is_unknown_not_a_crash() -> None:
    assert prov.provenance("carrier-pigeon:x", {"llm": "not a table"}).kind == prov.UNKNOWN
    assert prov.provenance("mock", {"llm": {"temperature": "hot"}}).kind == prov.RULE_BASED


# -- the scoreboard on hand-made trials ---------------------------------------------------------


def _run(method: str, provider: str, queries: list[float], temperature: float = 0.0) -> Run:
    """A run whose trial k asked ``queries[k]`` times (one episode per trial)."""
    rows = [{"trial": k, "episode": 0, "return": 1.0, "queries": q, "global_step": 10, "solved": True} for k, q in enumerate(queries)]
    frame = pd.DataFrame.from_records(rows, columns=list(EPISODE_COLUMNS))
    config = {"method": method, "llm": {"temperature": temperature, "model": "gpt-3.5-turbo"}}
    key = RunKey("cube-stacking", method, "upstream", provider, 0, f"{method}{temperature}")
    return Run(key, config, (), tuple(range(len(queries))), frame, pd.DataFrame(columns=list(QUERY_COLUMNS)), 0)


def _board(seq: list[float], lagr: list[float], provider: str = "mock", temperature: float = 0.0, paper: tuple[str, str] = ("100 ± 2", "200 ± 2")) -> pd.DataFrame:
    specs = [
        RunSpec("LaGR-SEQ", "cube-stacking", "lagr-seq", "upstream", None, row="0", column="LaGR-SEQ"),
        RunSpec("LaGR", "cube-stacking", "lagr", "upstream", None, row="0", column="LaGR (without SEQ)"),
    ]
    item = Item("table2", "Table 2: queries", "query-table", tuple(specs), options={"reference": {"0|LaGR-SEQ": paper[0], "0|LaGR (without SEQ)": paper[1]}})
    runs = [_run("lagr-seq", provider, seq, temperature), _run("lagr", provider, lagr, temperature)]
    matched = [items.Match(spec, spec.label, run, provider=provider) for spec, run in zip(specs, runs, strict=True)]
    board = scoreboard.build([(item, matched)])
    assert "verdict" in board.columns and "made by" in board.columns
    assert all("(n=" in row[5] for row in board.rows)  # every cell shows n
    return board.data.set_index("what")


SEQ_CELL = "0, LaGR-SEQ: queries per run"
LAGR_CELL = "0, LaGR (without SEQ): queries per run"
REDUCTION = "0: query reduction with SEQ (%)"


def test_tight_trials_at_the_papers_value_are_reproduced_with_the_margin_stated() -> None:
    data = _board([99.0, 100.0, 101.0, 100.5, 99.5, 100.0], [199.0, 200.0, 201.0, 200.0, 200.5, 199.5])
    assert data.loc[SEQ_CELL, "verdict"] == inference.REPRODUCED
    assert data.loc[SEQ_CELL, "margin"] == pytest.approx(10.0)  # 10% of 100 beats the paper's +-2
    assert data.loc[SEQ_CELL, "margin_reason"] == "10% of the paper's value"
    assert data.loc[SEQ_CELL, "provenance"] == prov.RULE_BASED
    assert data.loc[REDUCTION, "verdict"] == inference.REPRODUCED and data.loc[REDUCTION, "mean"] == pytest.approx(50.0, abs=0.1)


def test_tight_trials_far_from_the_paper_differ() -> None:
    data = _board([59.0, 60.0, 61.0, 60.0, 60.5], [199.0, 200.0, 201.0, 200.0, 200.5])
    assert data.loc[SEQ_CELL, "verdict"] == inference.DIFFERS
    assert data.loc[LAGR_CELL, "verdict"] == inference.REPRODUCED


def test_the_papers_own_spread_is_the_margin_where_it_is_larger() -> None:
    data = _board([70.0, 75.0, 72.0, 74.0, 73.0], [200.0] * 5, paper=("90 ± 25", "200 ± 1"))
    assert data.loc[SEQ_CELL, "margin"] == pytest.approx(25.0) and data.loc[SEQ_CELL, "margin_reason"] == "the paper's ±"


def test_wide_trials_are_inconclusive_and_fewer_than_5_never_reproduced() -> None:
    assert _board([40.0, 160.0, 90.0, 120.0, 70.0], [200.0] * 5).loc[SEQ_CELL, "verdict"] == inference.INCONCLUSIVE
    few = _board([100.0, 100.5, 99.5], [200.0, 200.5, 199.5])
    assert set(few["verdict"]) == {inference.INCONCLUSIVE} and set(few["trials"]) == {3}


def test_a_fitted_number_is_fitted_however_well_it_matches() -> None:
    data = _board([99.0, 100.0, 101.0, 100.5, 99.5, 100.0], [199.0, 200.0, 201.0, 200.0, 200.5, 199.5], provider="mock:authors-t0", temperature=0.5)
    assert set(data["verdict"]) == {inference.FITTED} and set(data["provenance"]) == {prov.FITTED}
    assert "temperature model" in data.loc[SEQ_CELL, "verdict_reason"]


def test_the_gap_column_is_a_hook_the_audits_can_fill() -> None:
    specs = [RunSpec("LaGR-SEQ", "cube-stacking", "lagr-seq", "upstream", None, row="0", column="LaGR-SEQ")]
    item = Item("table2", "Table 2", "query-table", tuple(specs), options={"reference": {"0|LaGR-SEQ": "126 ± 2.94"}})
    matched = [items.Match(specs[0], "x", _run("lagr-seq", "mock", [130.0, 131.0, 129.0]), provider="mock")]
    assert scoreboard.build([(item, matched)]).rows[0][-1] == "#table2"
    assert scoreboard.build([(item, matched)], ["cube-stacking"]).rows[0][-1] == "#audit-cube-stacking"
    board = scoreboard.build([(item, matched)], explain=lambda row: f"unexplained ({row['verdict']}, {row['provenance']})")
    assert board.rows[0][-1] == "unexplained (inconclusive, rule-based mock)"


# -- read back from real logs -------------------------------------------------------------------


def test_provenance_and_the_stack_size_ratio_are_read_back_from_logged_runs(tmp_path: Path) -> None:
    """Real logs: LaGR and LaGR-SEQ on mock:authors-t0 at tau = 0.5 and Q-learning, 5 cubes. The
    scoreboard's ratio row is LaGR / Q-learning per trial (the paper's caption), fitted (the
    temperature model), whatever the suite's labels say."""
    runs_dir = tmp_path / "runs"
    for method in ("lagr", "lagr-seq", "baseline"):
        config = cfg.load("cube-stacking", method, "upstream", overrides=["run.episodes=8", "task.stack_size=5", "llm.temperature=0.5"])
        runner.run_trials(config, 3, 0, "mock:authors-t0", runner.run_directory(runs_dir, config, "mock:authors-t0", 0))
    logs = loading.load([runs_dir])
    common = {"task": "cube-stacking", "preset": "upstream", "provider": "mock:authors-t0", "overrides": ("task.stack_size=5", "llm.temperature=0.5"), "episodes": 8}
    specs = (
        RunSpec("typed as rule-based", method="lagr", row="5", column="LaGR", **common),  # type: ignore[arg-type]
        RunSpec("SEQ", method="lagr-seq", row="5", column="LaGR-SEQ", **common),  # type: ignore[arg-type]
        RunSpec("Q", method="baseline", row="5", column="Q-learning", **common),  # type: ignore[arg-type]
    )
    item = Item("appendix-stack-size", "Appendix table", "ratio-table", specs, options={"numerator": "LaGR", "denominator": "Q-learning", "reference": {"5": "1.05 ± 0.01"}})
    matched = items.match(item, logs.runs, "mock")
    assert [m.run is not None for m in matched] == [True, True, True]
    board = scoreboard.build([(item, matched)])
    (row,) = board.data.to_dict("records")
    lagr, base = matched[0].run, matched[2].run
    assert lagr is not None and base is not None and lagr.key.method == "lagr" and base.key.method == "baseline"
    top, bottom = lagr.total_per_trial("return"), base.total_per_trial("return")
    assert row["mean"] == pytest.approx(np.mean([top[t] / bottom[t] for t in top]))
    assert row["what"] == "5 cubes: performance ratio LaGR / Q-learning" and row["trials"] == 3
    assert row["provenance"] == prov.FITTED and row["verdict"] == inference.FITTED
    assert "| fitted |" in to_markdown(board)
    table = items.build_ratio_table(item, matched).tables[0][1]
    assert table.rows[0][1] == prov.FITTED and table.columns[2].startswith("performance ratio LaGR / Q-learning")
