"""Provenance and verdicts on the scoreboard: what made each number, read from the
logged provider and configuration; three-way equivalence against the paper with a stated margin;
``fitted`` for a fitted number whatever its interval; never ``reproduced`` below 5 trials."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from lagrseq import config as cfg
from lagrseq.analysis import inference, items, loading, margins, scoreboard
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.loading import EPISODE_COLUMNS, QUERY_COLUMNS, Run, RunKey
from lagrseq.analysis.tables import to_markdown
from lagrseq.running import runner
from lagrseq.suite import AUTHORS_STORE_NAME, RECORDED_NAME, Item, RunSpec, load_suite

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


def _board(seq: list[float], lagr: list[float], provider: str = "mock", temperature: float = 0.0, paper: tuple[str, str] = ("126 ± 2.94", "284 ± 0.94")) -> pd.DataFrame:
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
TIGHT_SEQ = [125.0, 126.0, 127.0, 126.5, 125.5, 126.0]
TIGHT_LAGR = [283.0, 284.0, 285.0, 284.0, 284.5, 283.5]


def test_trials_at_the_papers_value_are_reproduced_where_the_papers_own_se_allows_it() -> None:
    """The test is two-sample: the paper's ± (a standard error over 10 runs) widens the interval.
    LaGR's 284 ± 0.94 leaves room inside its margin (±5.15, half the step to τ = 0.5); LaGR-SEQ's
    126 ± 2.94 alone gives a 90% half-width of at least 126 (exp(t(0.95, 5) 2.94 / 126) - 1) > 3.5,
    its margin: no data can show it reproduced, so its scale is two-valued (consistent or differs)."""
    data = _board(TIGHT_SEQ, TIGHT_LAGR)
    assert data.loc[LAGR_CELL, "verdict"] == inference.REPRODUCED and bool(data.loc[LAGR_CELL, "testable"])
    assert data.loc[LAGR_CELL, "margin"] == pytest.approx(5.15) and "half the step" in data.loc[LAGR_CELL, "margin_reason"]
    assert data.loc[LAGR_CELL, "paper_se"] == pytest.approx(0.94) and data.loc[LAGR_CELL, "paper_n"] == 10
    assert data.loc[SEQ_CELL, "verdict"] == inference.CONSISTENT and data.loc[SEQ_CELL, "margin"] == pytest.approx(3.5)
    assert not data.loc[SEQ_CELL, "testable"]
    relative = 2.94 / 126  # the paper's relative s.e.; Cox's term for the spread's uncertainty beside it
    floor = 126 * math.expm1(stats.t.ppf(0.95, 5) * math.sqrt(relative**2 + math.log1p(10 * relative**2) ** 2 / 18))
    assert data.loc[SEQ_CELL, "min_half_width"] == pytest.approx(floor) and floor > 3.5
    assert data.loc[SEQ_CELL, "test_high90"] - data.loc[SEQ_CELL, "test_low90"] > 2 * 3.5
    assert data.loc[SEQ_CELL, "provenance"] == prov.RULE_BASED
    assert data.loc[REDUCTION, "verdict"] == scoreboard.MAGNITUDE and data.loc[REDUCTION, "mean"] == pytest.approx(55.6, abs=0.1)
    assert data.loc[REDUCTION, "margin"] == pytest.approx(13.91) and data.loc[REDUCTION, "scale"] == "percentage points"


def test_the_log_ratio_test_against_the_papers_value_matches_a_hand_computation() -> None:
    """LaGR: five trials 283, 284, 285, 284, 284.5 (mean 284.1, variance 0.55) against 284 ± 0.94
    (s.e., n = 10): d = log(284.1 / 284); per arm the relative variance r^2 = (se / mean)^2 plus
    Cox's log(1 + n r^2)^2 / (2 (n - 1)); Hsu's df min(4, 9) = 4; shown at the paper's value,
    284 (exp(d ± t se) - 1)."""
    data = _board(TIGHT_SEQ[:5], [283.0, 284.0, 285.0, 284.0, 284.5])
    row = data.loc[LAGR_CELL]
    d = math.log(284.1 / 284)

    def arm(relative: float, n: int) -> float:
        return relative**2 + math.log1p(n * relative**2) ** 2 / (2 * (n - 1))

    se = math.sqrt(arm(math.sqrt(0.55 / 5) / 284.1, 5) + arm(0.94 / 284, 10))
    half = stats.t.ppf(0.95, 4) * se
    assert row["difference"] == pytest.approx(284 * math.expm1(d)) and row["difference_df"] == 4
    assert (row["test_low90"], row["test_high90"]) == (pytest.approx(284 * math.expm1(d - half)), pytest.approx(284 * math.expm1(d + half)))
    assert row["test"] == scoreboard.LOG


def test_trials_far_from_the_paper_differ() -> None:
    data = _board([59.0, 60.0, 61.0, 60.0, 60.5], TIGHT_LAGR)
    assert data.loc[SEQ_CELL, "verdict"] == inference.DIFFERS
    assert data.loc[LAGR_CELL, "verdict"] == inference.REPRODUCED


def test_wide_trials_are_inconclusive_and_fewer_than_5_get_no_verdict() -> None:
    assert _board(TIGHT_SEQ, [250.0, 320.0, 284.0, 300.0, 270.0]).loc[LAGR_CELL, "verdict"] == inference.INCONCLUSIVE
    few = _board([126.0, 126.5, 125.5], [284.0, 284.5, 283.5])
    assert set(few["verdict"]) == {inference.NO_VERDICT} and set(few["trials"]) == {3}
    assert "no verdict below 5 trials" in few.loc[LAGR_CELL, "verdict_reason"]
    assert set(few["explained_by"]) == {"— (n = 3 < 5)"}  # no gap judged below 5 trials


def test_an_untestable_cell_reads_consistent_or_differs_never_reproduced_or_inconclusive() -> None:
    """LaGR-SEQ at τ = 0 (126 ± 2.94 against ±3.5) whatever the trials: the interval holds 0
    (consistent) or not (differs)."""
    for values in (TIGHT_SEQ, [120.0, 140.0, 126.0, 131.0, 118.0], [59.0, 60.0, 61.0, 60.0, 60.5], [131.0, 131.5, 132.0, 131.0, 132.5]):
        verdict = _board(values, TIGHT_LAGR).loc[SEQ_CELL, "verdict"]
        assert verdict in (inference.CONSISTENT, inference.DIFFERS), values


def test_the_gap_column_says_no_gap_where_the_tests_interval_holds_zero() -> None:
    data = _board(TIGHT_SEQ, TIGHT_LAGR)
    assert data.loc[SEQ_CELL, "explained_by"] == scoreboard.NO_GAP
    assert data.loc[SEQ_CELL, "test_low95"] <= 0 <= data.loc[SEQ_CELL, "test_high95"]
    far = _board([59.0, 60.0, 61.0, 60.0, 60.5], TIGHT_LAGR)
    assert far.loc[SEQ_CELL, "explained_by"] == "#table2"  # the default link where no audit is held


@settings(max_examples=25, deadline=None)
@given(centre=st.floats(40, 400), spread=st.floats(0.1, 60), n=st.integers(5, 12))
def test_a_row_reads_reproduced_only_where_its_scale_allows_it(centre: float, spread: float, n: int) -> None:
    values = [max(1.0, centre + spread * ((k % 5) - 2) / 2) for k in range(n)]
    data = _board(values, values)
    for cell in (SEQ_CELL, LAGR_CELL):
        if data.loc[cell, "verdict"] in (inference.REPRODUCED, inference.INCONCLUSIVE):
            assert bool(data.loc[cell, "testable"])
        if not data.loc[cell, "testable"]:
            assert data.loc[cell, "verdict"] in (inference.CONSISTENT, inference.DIFFERS)


def test_intervals_of_counts_and_reductions_stay_inside_their_range() -> None:
    """Three very different trials (n = 3): a plain t interval of the mean would reach below 0
    queries; on the log scale it stays positive, and the reduction stays below 100%. Two trials
    get no interval at all."""
    data = _board([2.0, 80.0, 3.0], [5.0, 300.0, 7.0])
    assert data.loc[SEQ_CELL, "ci_low"] > 0 and data.loc[LAGR_CELL, "ci_low"] > 0
    assert data.loc[REDUCTION, "ci_high"] < 100
    assert inference.t_interval([2.0, 80.0, 3.0]).low < 0  # what it replaces
    two = _board([2.0, 80.0], [5.0, 300.0])
    assert two[["ci_low", "ci_high", "test_low90"]].isna().all().all()


@settings(max_examples=20, deadline=None)
@given(seq=st.lists(st.integers(0, 500), min_size=2, max_size=12), lagr=st.lists(st.integers(1, 900), min_size=2, max_size=12))
def test_every_count_and_reduction_interval_on_the_board_stays_in_range(seq: list[int], lagr: list[int]) -> None:
    data = _board([float(v) for v in seq], [float(v) for v in lagr])
    for cell, n in ((SEQ_CELL, len(seq)), (LAGR_CELL, len(lagr)), (REDUCTION, min(len(seq), len(lagr)))):
        if n < inference.MIN_N_INTERVAL:
            assert math.isnan(data.loc[cell, "ci_low"]) and math.isnan(data.loc[cell, "ci_high"])
    if min(len(seq), len(lagr)) < inference.MIN_N_INTERVAL:
        return
    for cell in (SEQ_CELL, LAGR_CELL):
        assert data.loc[cell, "ci_low"] >= 0 and data.loc[cell, "ci_low"] <= data.loc[cell, "mean"] <= data.loc[cell, "ci_high"]
    if sum(seq) > 0:
        assert data.loc[REDUCTION, "ci_low"] <= data.loc[REDUCTION, "mean"] <= data.loc[REDUCTION, "ci_high"] < 100


def test_a_fitted_number_is_fitted_however_well_it_matches() -> None:
    data = _board(TIGHT_SEQ, TIGHT_LAGR, provider="mock:authors-t0", temperature=0.5)
    assert set(data["verdict"]) == {inference.FITTED} and set(data["provenance"]) == {prov.FITTED}
    assert "temperature model" in data.loc[SEQ_CELL, "verdict_reason"]


# -- margins ------------------------------------------------------------------------------------


def _references() -> dict[str, dict[str, str]]:
    suite = load_suite()
    return {i.id: dict(i.options["reference"]) for i in suite.items if isinstance(i.options.get("reference"), dict)}


def _value(text: str) -> float:
    number = scoreboard.paper_number(text)
    assert number is not None
    return number


def test_every_paper_value_of_the_suite_has_a_margin_and_a_paper_sample() -> None:
    for item_id, reference in _references().items():
        assert margins.paper_sample(item_id) is not None, item_id
        for key in reference:
            assert margins.margin(item_id, key) is not None, (item_id, key)


def test_the_count_margins_are_half_the_smallest_step_to_a_neighbouring_cell() -> None:
    """Tables 2 and 3: half the smallest difference between a cell and a neighbour (the next row
    of its column, the other column of its row), so the bands of neighbouring cells never overlap."""
    for item_id in ("table2", "table3"):
        reference = {k: _value(v) for k, v in _references()[item_id].items()}
        rows = sorted({k.split("|")[0] for k in reference}, key=lambda r: (_float_or(r), r))
        columns = sorted({k.split("|")[1] for k in reference})
        for key, value in reference.items():
            row, column = key.split("|")
            i = rows.index(row)
            neighbours = [f"{r}|{column}" for r in rows[max(0, i - 1):i + 2] if r != row] + [f"{row}|{c}" for c in columns if c != column]
            expected = min(abs(value - reference[n]) for n in neighbours if n in reference) / 2
            found = margins.margin(item_id, key)
            assert found is not None and found.scale == margins.QUERIES
            assert found.value == pytest.approx(expected, rel=2e-3), key


def _float_or(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.inf


def test_ratio_and_reduction_margins_are_a_quarter_of_the_papers_advantage() -> None:
    """A ratio on its advantage (ratio - 1), a reduction (SEQ's advantage, 1 - SEQ / LaGR) as a
    quarter of itself: 1.05 gets ±0.0125, so 0.95 (LaGR worse) can never be reproduced."""
    for key, text in _references()["appendix-stack-size"].items():
        found = margins.margin("appendix-stack-size", key)
        assert found is not None and found.scale.startswith("ratio")
        assert found.value == pytest.approx(0.25 * (_value(text) - 1.0), rel=2e-3)
        assert margins.margin("appendix-stack-size-paper-preset", key) == found
    for item_id in ("table2", "table3"):
        reference = {k: _value(v) for k, v in _references()[item_id].items()}
        for row in {k.split("|")[0] for k in reference}:
            seq, lagr = reference[f"{row}|LaGR-SEQ"], reference[f"{row}|LaGR (without SEQ)"]
            found = margins.margin(item_id, f"{row}|{margins.REDUCTION}")
            assert found is not None and found.scale == margins.POINTS
            assert found.value == pytest.approx(25 * (1 - seq / lagr), rel=2e-3)


def test_trend_thresholds_are_a_quarter_of_the_papers_slope() -> None:
    t2 = {k: _value(v) for k, v in _references()["table2"].items()}
    for column in ("LaGR-SEQ", "LaGR (without SEQ)"):
        found = margins.margin("table2", f"{margins.SLOPE}|{column}")
        assert found is not None and found.trend == "rises"
        assert found.value == pytest.approx(0.25 * (t2[f"1|{column}"] - t2[f"0|{column}"]), rel=2e-3)
    mean_reduction = np.mean([100 * (1 - t2[f"{r}|LaGR-SEQ"] / t2[f"{r}|LaGR (without SEQ)"]) for r in ("0", "0.5", "1")])
    holds = margins.margin("table2", f"{margins.SLOPE}|{margins.REDUCTION}")
    assert holds is not None and holds.trend == "holds" and holds.value == pytest.approx(-0.25 * mean_reduction, rel=2e-3)
    ratio = margins.margin("appendix-stack-size", f"{margins.SLOPE}|ratio")
    assert ratio is not None and ratio.value == pytest.approx(0.25 * (1.33 - 1.05) / 6, rel=2e-3)


def test_the_stack_size_ratio_near_one_differs_on_the_advantage_scale() -> None:
    """The paper preset's 5-cube ratio 1.007 [1.001, 1.014] against 1.05 ±
    0.01 was `reproduced` under ±10% of the ratio; on the advantage (±0.0125) it differs."""
    ours = inference.mean_estimate([1.0, 1.004, 1.007, 1.01, 1.014, 1.003, 1.008, 1.006, 1.009, 1.009])
    paper = inference.paper_estimate(1.05, 0.01, 10)
    found = margins.margin("appendix-stack-size", "5")
    assert found is not None
    assert inference.tost(ours, paper, found.value).verdict == inference.DIFFERS
    assert inference.tost(ours, paper, 0.105).verdict == inference.REPRODUCED  # the old margin


# -- trends -------------------------------------------------------------------------------------


def _trend_board(seq: dict[str, list[float]], lagr: dict[str, list[float]], provider: str = "mock") -> pd.DataFrame:
    reference = {"0|LaGR-SEQ": "126 ± 2.94", "0|LaGR (without SEQ)": "284 ± 0.94", "0.5|LaGR-SEQ": "133 ± 1.41",
                 "0.5|LaGR (without SEQ)": "294.3 ± 3.2", "1|LaGR-SEQ": "138.33 ± 7.31", "1|LaGR (without SEQ)": "331.66 ± 1.44"}
    specs, runs = [], []
    for tau in ("0", "0.5", "1"):
        for method, column, values in (("lagr-seq", "LaGR-SEQ", seq[tau]), ("lagr", "LaGR (without SEQ)", lagr[tau])):
            specs.append(RunSpec(f"{column} {tau}", "cube-stacking", method, "upstream", None, row=tau, column=column))
            runs.append(_run(method, provider, values, float(tau)))
    item = Item("table2", "Table 2: queries", "query-table", tuple(specs), options={"reference": reference, "row_header": "τ"})
    matched = [items.Match(spec, spec.label, run, provider=provider) for spec, run in zip(specs, runs, strict=True)]
    return scoreboard.build([(item, matched)]).data.set_index("what")


def _around(centre: float, n: int = 10, spread: float = 2.0) -> list[float]:
    return [centre + spread * ((k % 5) - 2) / 2 for k in range(n)]


def test_table2s_trends_are_tested_for_direction_and_size_apart() -> None:
    """Queries that rise with τ as the paper's do: Jonckheere-Terpstra finds the rise in each
    column (direction), the least-squares slope (the τ = 1 mean minus the τ = 0 mean) is judged
    against the paper's slope with its ± (size: LaGR's 47.66 ± 1.72 is testable, LaGR-SEQ's
    12.33 ± 7.88 is not); the reduction moves by about -1.3 points, far above "holds" (-14.06).
    Flat queries differ from the paper's size; a collapsing reduction does not hold."""
    seq = {"0": _around(126), "0.5": _around(133), "1": _around(140)}
    lagr = {"0": _around(284), "0.5": _around(300), "1": _around(330)}
    data = _trend_board(seq, lagr)
    rise = data.loc["trend: LaGR-SEQ queries per run over τ (direction)"]
    assert rise["kind"] == "trend" and rise["test"] == scoreboard.DIRECTION and rise["verdict"] == inference.REPRODUCED
    assert rise["p_rise"] < 0.05
    size = data.loc["trend: LaGR-SEQ queries per run over τ (slope, size)"]
    assert size["mean"] == pytest.approx(14.0) and size["paper_value"] == pytest.approx(12.33)
    assert size["margin"] == pytest.approx(0.25 * 12.33) and not size["testable"]
    assert size["verdict"] == inference.CONSISTENT
    lagr_size = data.loc["trend: LaGR (without SEQ) queries per run over τ (slope, size)"]
    assert bool(lagr_size["testable"]) and lagr_size["verdict"] == inference.REPRODUCED  # 46 against 47.66 ± 1.72, margin ±11.9
    holds = data.loc["trend: query reduction with SEQ over τ (slope, holds)"]
    assert holds["trend"] == "holds" and holds["verdict"] == inference.REPRODUCED
    assert holds["mean"] == pytest.approx(100 * ((1 - 140 / 330) - (1 - 126 / 284)), abs=1e-6)
    assert holds["margin"] == pytest.approx(-14.06, abs=0.01)
    flat = _trend_board({t: _around(126) for t in seq}, {t: _around(284) for t in lagr})
    assert flat.loc["trend: LaGR (without SEQ) queries per run over τ (slope, size)", "verdict"] == inference.DIFFERS
    assert flat.loc["trend: LaGR (without SEQ) queries per run over τ (direction)", "verdict"] == inference.INCONCLUSIVE
    collapsing = _trend_board({"0": _around(126), "0.5": _around(200), "1": _around(300)}, {t: _around(284) for t in lagr})
    assert collapsing.loc["trend: query reduction with SEQ over τ (slope, holds)", "verdict"] == inference.DIFFERS


def test_a_slope_half_the_papers_no_longer_reads_reproduced() -> None:
    """LaGR's paper slope is 47.66 per unit τ; trials rising half as fast (284 -> 308) rise
    (direction reproduced) but their size differs from the paper's."""
    lagr = {"0": _around(284), "0.5": _around(296), "1": _around(308)}
    data = _trend_board({t: _around(126) for t in lagr}, lagr)
    assert data.loc["trend: LaGR (without SEQ) queries per run over τ (direction)", "verdict"] == inference.REPRODUCED
    assert data.loc["trend: LaGR (without SEQ) queries per run over τ (slope, size)", "verdict"] == inference.DIFFERS


# -- no verdict where the fallback decided: real runs on a recorded store -----------------------


def test_a_row_where_the_fallback_decided_a_trial_gets_no_verdict_and_says_how_many(tmp_path: Path) -> None:
    """Real logs on a recorded store with misses answered by the mock: at 5 cubes no prompt is in
    the 8-cube store, so the mock gives every first accepted answer (no verdict, counted); at 8
    cubes every prompt is recorded (a verdict). The frontier and the tables count the same trials
    (one helper, :func:`provenance.decided_by_fallback`)."""
    from lagrseq.running.wiring import provider_options

    store = "recorded:recorded_llm/qwen2.5-coder-1.5b-cube-t0.jsonl"
    runs_dir = tmp_path / "runs"
    for stack in (5, 8):
        for method in ("lagr", "baseline"):
            provider = store if method == "lagr" else "mock"
            model = ["llm.model=qwen2.5-coder-1.5b-instruct-q4_k_m"] if provider == store else []
            config = cfg.load("cube-stacking", method, "upstream", overrides=["run.episodes=6", f"task.stack_size={stack}", *model])
            options = provider_options(provider, {"on_miss": "mock"}) if provider == store else None
            runner.run_trials(config, 5, 0, provider, runner.run_directory(runs_dir, config, provider, 0), provider_options=options)
    logs = loading.load([runs_dir], jobs=1)
    common = {"task": "cube-stacking", "preset": "upstream", "episodes": 6}
    specs = []
    for stack in (5, 8):
        overrides = (f"task.stack_size={stack}", "llm.model=qwen2.5-coder-1.5b-instruct-q4_k_m")
        specs += [RunSpec("LaGR", method="lagr", row=str(stack), column="LaGR", provider=store, overrides=overrides, **common),  # type: ignore[arg-type]
                  RunSpec("Q", method="baseline", row=str(stack), column="Q-learning", provider="mock", overrides=overrides[:1], **common)]  # type: ignore[arg-type]
    item = Item("appendix-stack-size", "Appendix table", "ratio-table", tuple(specs),
                options={"numerator": "LaGR", "denominator": "Q-learning", "reference": {"5": "1.05 ± 0.01", "8": "1.28 ± 0.04"}})
    matched = items.match(item, logs.runs, "mock")
    assert all(m.run is not None for m in matched), [m.reason for m in matched]
    decided = {m.row: prov.decided_by_fallback(m.run) for m in matched if m.run is not None and m.spec.method == "lagr"}
    assert decided == {"5": [True] * 5, "8": [False] * 5}
    assert items.fallback_decided(matched[0].run) == (5, 5)  # type: ignore[arg-type]
    board = scoreboard.build([(item, matched)])
    data = board.data.set_index("what")
    five = data.loc["5 cubes: performance ratio LaGR / Q-learning"]
    assert five["verdict"] == inference.NO_VERDICT and (five["fallback_decided"], five["fallback_trials"]) == (5, 5)
    assert five["verdict_reason"].startswith("the fallback decided 5 of 5 trials")
    assert five["test_verdict"] in scoreboard.VERDICTS and five["test_verdict"] != inference.NO_VERDICT  # computed, not shown as a verdict
    eight = data.loc["8 cubes: performance ratio LaGR / Q-learning"]
    assert eight["fallback_decided"] == 0 and eight["verdict"] in (inference.CONSISTENT, inference.DIFFERS)  # 1.28 ± 0.04: not testable to ±0.07
    trend = data.loc["trend: performance ratio LaGR / Q-learning over stack size (slope, size)"]
    assert trend["verdict"] == inference.NO_VERDICT and "5 of 10 trials" in trend["verdict_reason"]
    assert any("no verdict: the fallback decided 5 of 5 trials" in row[7] for row in board.rows)


def test_the_gap_column_is_a_hook_the_audits_can_fill() -> None:
    specs = [RunSpec("LaGR-SEQ", "cube-stacking", "lagr-seq", "upstream", None, row="0", column="LaGR-SEQ")]
    item = Item("table2", "Table 2", "query-table", tuple(specs), options={"reference": {"0|LaGR-SEQ": "126 ± 2.94"}})
    matched = [items.Match(specs[0], "x", _run("lagr-seq", "mock", [60.0, 61.0, 59.0, 60.0, 60.5]), provider="mock")]
    assert scoreboard.build([(item, matched)]).rows[0][-1] == "#table2"
    assert scoreboard.build([(item, matched)], ["cube-stacking"]).rows[0][-1] == "#audit-cube-stacking"
    board = scoreboard.build([(item, matched)], explain=lambda row: f"unexplained ({row['verdict']}, {row['provenance']})")
    assert board.rows[0][-1] == "unexplained (differs, rule-based mock)"
    few = [items.Match(specs[0], "x", _run("lagr-seq", "mock", [60.0, 61.0, 59.0]), provider="mock")]
    assert scoreboard.build([(item, few)], explain=lambda row: "never asked").rows[0][-1] == "— (n = 3 < 5)"


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
    row, early = board.data.to_dict("records")
    # beside the paper's measure, lagrseq's early one: the return over the first 10 episodes (all 8 here)
    assert early["what"].startswith("5 cubes: early return ratio") and early["mean"] == pytest.approx(row["mean"])
    assert early["verdict"] == inference.FITTED and early["paper"] == "not in the paper"
    lagr, base = matched[0].run, matched[2].run
    assert lagr is not None and base is not None and lagr.key.method == "lagr" and base.key.method == "baseline"
    top, bottom = lagr.total_per_trial("return"), base.total_per_trial("return")
    assert row["mean"] == pytest.approx(np.mean([top[t] / bottom[t] for t in top]))
    assert row["what"] == "5 cubes: performance ratio LaGR / Q-learning" and row["trials"] == 3
    assert row["provenance"] == prov.FITTED and row["verdict"] == inference.FITTED
    assert "| fitted |" in to_markdown(board)
    table = items.build_ratio_table(item, matched).tables[0][1]
    assert table.rows[0][1] == prov.FITTED and table.columns[2].startswith("performance ratio LaGR / Q-learning")


def test_the_testability_table_lists_each_judged_row_and_why() -> None:
    """Table 2's τ = 0 cells at 6 trials: LaGR (284 ± 0.94 against ±5.15) can reach reproduced,
    LaGR-SEQ (126 ± 2.94 against ±3.5) cannot; the reduction can."""
    specs = [
        RunSpec("LaGR-SEQ", "cube-stacking", "lagr-seq", "upstream", None, row="0", column="LaGR-SEQ"),
        RunSpec("LaGR", "cube-stacking", "lagr", "upstream", None, row="0", column="LaGR (without SEQ)"),
    ]
    item = Item("table2", "Table 2: queries", "query-table", tuple(specs), options={"reference": {"0|LaGR-SEQ": "126 ± 2.94", "0|LaGR (without SEQ)": "284 ± 0.94"}})
    runs = [_run("lagr-seq", "mock", TIGHT_SEQ), _run("lagr", "mock", TIGHT_LAGR)]
    matched = [items.Match(spec, spec.label, run, provider="mock") for spec, run in zip(specs, runs, strict=True)]
    table = scoreboard.testability(scoreboard.build([(item, matched)]))
    by_what = {row[1]: row for row in table.rows}
    assert by_what[SEQ_CELL][6] == "no" and inference.CONSISTENT in by_what[SEQ_CELL][7] and ">= the margin ±3.5" in by_what[SEQ_CELL][8]
    assert by_what[LAGR_CELL][6] == "yes" and by_what[REDUCTION][6] == "yes"
    assert list(table.data["testable"]) == [False, True, True]


AUTHORS_STORE = f"recorded:/data/{AUTHORS_STORE_NAME}"


def _table3_board(refused: list[float], mock: list[float]) -> pd.DataFrame:
    """Table 3's GPT4 LaGR-SEQ cell on the authors' answers, misses refused and answered by the
    mock (no query records: no trial decided by a fallback)."""
    specs = [
        RunSpec("refused", "image-completion", "lagr-seq", "upstream", AUTHORS_STORE, on_miss="refuse", row="GPT4 (misses refused)", column="LaGR-SEQ"),
        RunSpec("mock", "image-completion", "lagr-seq", "upstream", AUTHORS_STORE, on_miss="mock", row="GPT4 (misses: rule-based mock)", column="LaGR-SEQ"),
        RunSpec("refused", "image-completion", "lagr", "upstream", AUTHORS_STORE, on_miss="refuse", row="GPT4 (misses refused)", column="LaGR (without SEQ)"),
    ]
    reference = {"GPT4|LaGR-SEQ": "59.5 ± 13.79", "GPT4|LaGR (without SEQ)": "92.3 ± 25.03"}
    item = Item("table3", "Table 3: queries", "query-table", tuple(specs), options={"reference": reference, "row_header": "LLM"})
    runs = [_run("lagr-seq", AUTHORS_STORE, refused), _run("lagr-seq", AUTHORS_STORE, mock), _run("lagr", AUTHORS_STORE, [2 * v for v in refused])]
    matched = [items.Match(spec, spec.label, run, provider=AUTHORS_STORE) for spec, run in zip(specs, runs, strict=True)]
    return scoreboard.build([(item, matched)]).data.set_index("what")


def test_the_misses_refused_row_is_a_bound_with_the_band_not_a_verdict() -> None:
    """A refused miss is never accepted, so the row runs high: whatever its test reads it shows
    no verdict but a bound, with the band from the mock row to it and whether the band holds the
    paper's value."""
    data = _table3_board([580.0, 600.0, 590.0, 585.0, 595.0], [20.0, 22.0, 24.0, 21.0, 23.0])
    refused = data.loc["LLM = GPT4 (misses refused), LaGR-SEQ: queries per run"]
    assert refused["verdict"] == scoreboard.BOUND and refused["test_verdict"] == inference.DIFFERS
    assert "[22.0, 590.0]" in refused["verdict_reason"] and "holds the paper's value" in refused["verdict_reason"]
    assert refused["explained_by"].startswith("a bound")
    mock = data.loc["LLM = GPT4 (misses: rule-based mock), LaGR-SEQ: queries per run"]
    assert mock["verdict"] != scoreboard.BOUND
    assert set(data["verdict"]) <= set(scoreboard.LABELS)
    reduction = data.loc["LLM = GPT4 (misses refused): query reduction with SEQ (%)"]
    assert reduction["verdict"] == inference.NO_VERDICT and "no bound" in reduction["verdict_reason"]
    above = _table3_board([580.0, 600.0, 590.0, 585.0, 595.0], [200.0, 220.0, 240.0, 210.0, 230.0])
    assert "does not hold" in above.loc["LLM = GPT4 (misses refused), LaGR-SEQ: queries per run", "verdict_reason"]


def test_a_fitted_row_with_the_authors_rows_decisions_reads_as_that_row() -> None:
    """Table 2 at τ = 0 on the authors' recorded answers and on mock:authors-t0, trial for trial
    the same counts (the same decisions): both show the authors' row's verdict and say why; a fitted
    row with other counts stays fitted."""
    reference = {"0|LaGR (without SEQ)": "284 ± 0.94"}

    def board(fitted_counts: list[float]) -> pd.DataFrame:
        specs = [RunSpec("authors", "cube-stacking", "lagr", "upstream", AUTHORS_STORE, row=f"0 ({RECORDED_NAME})", column="LaGR (without SEQ)"),
                 RunSpec("fitted", "cube-stacking", "lagr", "upstream", "mock:authors-t0", row="0", column="LaGR (without SEQ)")]
        item = Item("table2", "Table 2: queries", "query-table", tuple(specs), options={"reference": reference, "row_header": "τ"})
        runs = [_run("lagr", AUTHORS_STORE, TIGHT_LAGR), _run("lagr", "mock:authors-t0", fitted_counts)]
        matched = [items.Match(spec, spec.label, run, provider=str(spec.provider)) for spec, run in zip(specs, runs, strict=True)]
        return scoreboard.build([(item, matched)]).data

    data = board(TIGHT_LAGR)
    assert list(data["provenance"]) == [prov.AUTHORS, prov.FITTED]
    assert list(data["verdict"]) == [inference.REPRODUCED, inference.REPRODUCED]
    assert all("the same decisions as" in reason for reason in data["verdict_reason"])
    other = board([v + 1 for v in TIGHT_LAGR])
    assert list(other["verdict"]) == [inference.REPRODUCED, inference.FITTED]


def _return_run(method: str, returns: list[float], stack: int) -> Run:
    """A run whose trial k earned ``returns[k]`` in one episode."""
    rows = [{"trial": k, "episode": 0, "return": r, "queries": 1.0, "global_step": 10, "solved": True} for k, r in enumerate(returns)]
    frame = pd.DataFrame.from_records(rows, columns=list(EPISODE_COLUMNS))
    key = RunKey("cube-stacking", method, "upstream", "mock", 0, f"{method}{stack}")
    return Run(key, {"method": method, "llm": {"temperature": 0.0}}, (), tuple(range(len(returns))), frame, pd.DataFrame(columns=list(QUERY_COLUMNS)), 0)


def _stack_board(ratios: dict[str, list[float]], reference: dict[str, str]) -> pd.DataFrame:
    specs, runs = [], []
    for stack, values in ratios.items():
        specs += [RunSpec("LaGR", "cube-stacking", "lagr", "upstream", None, row=stack, column="LaGR"),
                  RunSpec("Q", "cube-stacking", "baseline", "upstream", None, row=stack, column="Q-learning")]
        runs += [_return_run("lagr", [100.0 * v for v in values], int(stack)), _return_run("baseline", [100.0] * len(values), int(stack))]
    item = Item("appendix-stack-size", "Appendix table", "ratio-table", tuple(specs),
                options={"numerator": "LaGR", "denominator": "Q-learning", "reference": reference})
    matched = [items.Match(spec, spec.label, run, provider="mock") for spec, run in zip(specs, runs, strict=True)]
    return scoreboard.build([(item, matched)]).data.set_index("what")


def test_a_trends_threshold_comes_from_the_same_cells_as_its_slope() -> None:
    """Only 8 and 11 cubes measured: the paper's slope is (1.33 - 1.28) / 3 per cube over those
    cells, and the size margin a quarter of it (not the 5-to-11 slope's)."""
    data = _stack_board({"8": _around(1.28, spread=0.02), "11": _around(1.33, spread=0.02)}, {"8": "1.28 ± 0.04", "11": "1.33 ± 0.19"})
    size = data.loc["trend: performance ratio LaGR / Q-learning over stack size (slope, size)"]
    assert size["paper_value"] == pytest.approx((1.33 - 1.28) / 3)
    assert size["margin"] == pytest.approx(0.25 * (1.33 - 1.28) / 3)


def test_the_early_return_ratios_trend_is_lagrseqs_measure_and_never_reproduced() -> None:
    """Early ratios rising clearly over 5, 8 and 11 cubes: the direction row says it rises, as
    lagrseq's measure; no row of a measure without a paper value reads reproduced."""
    ratios = {"5": _around(1.05, spread=0.01), "8": _around(1.3, spread=0.01), "11": _around(1.6, spread=0.01)}
    data = _stack_board(ratios, {"5": "1.05 ± 0.01", "8": "1.28 ± 0.04", "11": "1.33 ± 0.19"})
    early = data.loc["trend: early return ratio over stack size (lagrseq's measure) (direction)"]
    assert early["verdict"] == scoreboard.MEASURE_RISES and early["p_rise"] < 0.05
    unpaper = data[data["paper"] == "not in the paper"]
    assert len(unpaper) == 4 and inference.REPRODUCED not in set(unpaper["verdict"])
    assert set(data["verdict"]) <= set(scoreboard.LABELS)
    direction = data.loc["trend: performance ratio LaGR / Q-learning over stack size (direction)"]
    assert direction["verdict"] == inference.REPRODUCED


def test_the_testability_table_of_an_empty_scoreboard_is_empty() -> None:
    table = scoreboard.testability(scoreboard.build([]))
    assert table.rows == () and list(table.data.columns)[:2] == ["item", "what"] and table.data.empty
