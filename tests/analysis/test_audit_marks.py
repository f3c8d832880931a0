"""The audit's statistics on hand-made runs: Holm-corrected marks, the "indicative" rule below 10
trials, the interaction contrasts of the 2x2x2 design and the scoreboard's gap attribution."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence

import numpy as np
import pandas as pd
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy import stats as scipy_stats

from lagrseq import config as cfg
from lagrseq.analysis import audit, inference
from lagrseq.analysis.loading import EPISODE_COLUMNS, QUERY_COLUMNS, Run, RunKey

TASK = "cube-stacking"
EPS, GUIDED, SEQ_EPS = audit.INTERACTIONS[TASK]
FIELDS = audit.audited_fields(TASK)


def _welch_p(x: np.ndarray, y: np.ndarray) -> float:
    """Two-sided p-value of Welch's test of equal means, from SciPy (the reference the audit's
    own t arithmetic is checked against)."""
    return float(scipy_stats.ttest_ind(x, y, equal_var=False).pvalue)


def _run(method: str, preset: str, switched: Sequence[str], queries: Sequence[float], returns: Sequence[float] | None = None) -> Run:
    """A run as the loader gives it: the preset's configuration with ``switched`` fields set to
    their switched values, one episode per trial holding the given queries and return."""
    sets = [audit.override(f, audit.switched_value(f, preset, FIELDS)) for f in sorted(switched)]
    config = json.loads(cfg.load(TASK, method, preset, None, sets).to_json())
    returns = list(returns) if returns is not None else [100.0 + 0.5 * i for i in range(len(queries))]
    episodes = pd.DataFrame(
        [
            {
                "trial": t, "episode": 0, "return": float(r), "length": 50, "queries": float(q), "accepted": 0,
                "epsilon": 0.1, "solved": True, "guided_steps": 0, "global_step": 50,
            }
            for t, (q, r) in enumerate(zip(queries, returns, strict=True))
        ],
        columns=list(EPISODE_COLUMNS),
    )
    digest = hashlib.sha256(json.dumps([method, preset, sorted(switched)]).encode()).hexdigest()[:8]
    key = RunKey(TASK, method, preset, "mock", 0, digest)
    return Run(key, config, (), tuple(range(len(queries))), episodes, pd.DataFrame(columns=list(QUERY_COLUMNS)), 0)


def _noise(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, 1.0, n)


# -- Holm marks and the indicative rule -----------------------------------------------------------


def test_marks_are_holm_corrected_over_the_whole_family() -> None:
    frame = pd.DataFrame({"p": [0.001, 0.02, 0.03, 0.2, math.nan], "trials": [10, 10, 10, 10, 10]})
    marked = audit.mark(frame)
    # m = 4 (the NaN is no comparison): adjusted 0.004, 0.06, 0.06, 0.2
    assert marked["family_size"].tolist() == [4] * 5
    assert np.allclose(marked["p_holm"].to_numpy()[:4], [0.004, 0.06, 0.06, 0.2])
    assert marked["marked"].tolist() == [True, False, False, False, False]  # 0.02 and 0.03 alone would be


def test_fewer_than_ten_trials_is_indicative_and_never_marked() -> None:
    frame = pd.DataFrame({"p": [1e-9, 1e-9], "trials": [9, 10]})
    marked = audit.mark(frame)
    assert marked["indicative"].tolist() == [True, False]
    assert marked["marked"].tolist() == [False, True]


def _one_field_runs(trials: int) -> list[Run]:
    """The upstream preset and three one-field switches with known effects on LaGR's queries:
    a large one, one of about 2.6 standard errors (p about 0.02 alone, not after Holm), none."""
    base = 300 + _noise(trials, 1)
    runs = [_run(m, "upstream", [], base if m == "lagr" else 100 + _noise(trials, 2)) for m in audit.METHODS]
    effects = {EPS: -50.0, GUIDED: 1.15, "lagr.trigger": 0.0}
    for field, effect in effects.items():
        values = 300 + effect + _noise(trials, 7)
        runs.append(_run("lagr", "upstream", [field], values))
    return runs


@pytest.mark.parametrize("trials", [3, 12])
def test_build_marks_only_holm_significant_effects_with_enough_trials(trials: int) -> None:
    (made,) = audit.build(_one_field_runs(trials))
    rows = made.data[made.data["quantity"] == "queries without SEQ"].set_index("field")
    assert set(rows.index) == {EPS, GUIDED, "lagr.trigger"}
    m = int(made.data["family_size"].iloc[0])
    assert m == int(np.isfinite(made.data["p"]).sum()) and f"m = {m} comparisons" in made.table.title
    for field in rows.index:  # Welch's interval, the same as inference's
        a = 300 + {EPS: -50.0, GUIDED: 1.15, "lagr.trigger": 0.0}[field] + _noise(trials, 7)
        expected = inference.welch_interval(a, 300 + _noise(trials, 1))
        assert rows.loc[field, "ci_low"] == pytest.approx(expected.low) and rows.loc[field, "ci_high"] == pytest.approx(expected.high)
        assert rows.loc[field, "p"] == pytest.approx(_welch_p(a, 300 + _noise(trials, 1)))
    column = made.table.columns.index("queries without SEQ")
    eps_cell = next(r[column] for r in made.table.rows if EPS in r[0])
    assert f"n={trials}" in eps_cell
    if trials < audit.MIN_N_MARK:
        assert not made.data["marked"].any() and made.data["indicative"].all()
        assert "indicative" in eps_cell and "*" not in eps_cell
    else:
        assert rows.loc[EPS, "marked"] and eps_cell.endswith("*")
        assert not rows.loc["lagr.trigger", "marked"]
        assert not made.data["indicative"].any()


# -- interaction contrasts ------------------------------------------------------------------------

BASE, A, B, C, AB, ABC = 300.0, -20.0, 10.0, 5.0, -80.0, 30.0
"""Designed queries: Y = BASE + A a + B b + C c + AB a b + ABC a b c (a, b, c the three switches)."""


def _designed(corner: frozenset[str], trials: int) -> np.ndarray:
    """The same noise in every corner: the contrasts' weights sum to 0, so each contrast's value is
    exactly the designed one, while its interval has the width of that noise."""
    a, b, c = (EPS in corner), (GUIDED in corner), (SEQ_EPS in corner)
    return BASE + A * a + B * b + C * c + AB * a * b + ABC * a * b * c + _noise(trials, 0)


def _interaction_runs(trials: int) -> list[Run]:
    runs = []
    subsets = [frozenset(s) for s in ([], [EPS], [GUIDED], [SEQ_EPS], [EPS, GUIDED], [EPS, SEQ_EPS], [GUIDED, SEQ_EPS], [EPS, GUIDED, SEQ_EPS])]
    for corner in subsets:
        for method in audit.METHODS:
            if audit.relevant_part(corner, method) != corner:
                continue  # the method's run of this corner is that of the part it reads
            runs.append(_run(method, "upstream", sorted(corner), _designed(corner, trials)))
    return runs


def test_interaction_contrasts_recover_the_designed_interactions() -> None:
    trials = 10
    (made,) = audit.build(_interaction_runs(trials))
    assert made.corners is not None and made.interactions is not None
    seq = made.interactions[made.interactions["quantity"] == "queries with SEQ"].set_index("contrast")
    # with c at the preset's value, the a x b contrast is AB; a x c and b x c are 0; a x b x c is ABC
    expected = {f"{EPS} x {GUIDED}": AB, f"{EPS} x {SEQ_EPS}": 0.0, f"{GUIDED} x {SEQ_EPS}": 0.0, f"{EPS} x {GUIDED} x {SEQ_EPS}": ABC}
    assert set(seq.index) == set(expected)
    for name, value in expected.items():
        row = seq.loc[name]
        assert row["value"] == pytest.approx(value, abs=1e-9)
        assert row["ci_low"] < value < row["ci_high"] and row["ci_high"] - row["ci_low"] > 1, (name, row.to_dict())
    assert seq.loc[f"{EPS} x {GUIDED}", "marked"] and seq.loc[f"{EPS} x {GUIDED} x {SEQ_EPS}", "marked"]
    # LaGR cannot read the secondary's epsilon: its corners with it are its runs without it
    lagr = made.interactions[made.interactions["quantity"] == "queries without SEQ"].set_index("contrast")
    assert set(lagr.index) == {f"{EPS} x {GUIDED}"}  # the others hold the secondary's field: no comparison
    assert lagr.loc[f"{EPS} x {GUIDED}", "ci_low"] <= AB <= lagr.loc[f"{EPS} x {GUIDED}", "ci_high"]
    # the contrast's value is the signed sum of the corner means it is made of
    means = made.corners[made.corners["quantity"] == "queries with SEQ"].set_index("corner")["mean"]
    both = means[" + ".join(sorted((EPS, GUIDED)))] - means[EPS] - means[GUIDED] + means["none (the preset)"]
    assert seq.loc[f"{EPS} x {GUIDED}", "value"] == pytest.approx(both)
    assert made.interaction_table is not None and any(r[0].startswith("interaction ") for r in made.interaction_table.rows)
    assert len(audit.outputs(made)) == 2


def test_the_contrast_of_two_groups_is_welchs_difference() -> None:
    x, y = 3 + _noise(7, 1), 2 * _noise(5, 2)
    interval, p = audit.contrast([(1.0, x), (-1.0, y)])
    expected = inference.welch_interval(x, y)
    assert (interval.mean, interval.low, interval.high) == pytest.approx((expected.mean, expected.low, expected.high))
    assert p == pytest.approx(_welch_p(x, y))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6), min_size=0, max_size=6), st.lists(st.floats(-1e6, 1e6), min_size=0, max_size=6), st.floats(-3, 3))
@example([0.0, 1.4102126736151046e-132], [0.0, 0.0], 0.0)  # squared variances underflow to 0
def test_contrast_is_finite_or_nan_on_any_groups(x: list[float], y: list[float], w: float) -> None:
    interval, p = audit.contrast([(1.0, np.array(x)), (w, np.array(y))])
    assert interval.n == min(len(x), len(y))
    assert math.isnan(p) or 0.0 <= p <= 1.0
    if not math.isnan(interval.low):
        assert interval.low <= interval.mean + 1e-6 * (1 + abs(interval.mean)) and interval.mean <= interval.high + 1e-6 * (1 + abs(interval.mean))


# -- the gap attribution --------------------------------------------------------------------------


def _audit(effects: dict[str, tuple[float, int, float]], temperature: float = 0.0, corners: pd.DataFrame | None = None) -> audit.Audit:
    """An audit whose upstream rows on LaGR's queries have the given (effect, trials, p)."""
    rows = [
        {
            "preset": "upstream", "field": f, "switched_to": "x", "quantity": "queries without SEQ", "preset_mean": 100.0,
            "switched_mean": 100.0 + e, "effect": e, "ci_low": e - 1, "ci_high": e + 1, "p": p,
            "excludes_zero": abs(e) > 1, "trials": n, "trials_switched": n, "trials_preset": n,
        }
        for f, (e, n, p) in effects.items()
    ]
    data = audit.mark(pd.DataFrame(rows))
    configs = {p: audit._flat(json.loads(cfg.load(TASK, "lagr-seq", p).to_json())) for p in audit.PRESETS}
    return audit.Audit(TASK, audit._table(TASK, data), data, "mock:authors-t0", temperature, corners=corners, preset_configs=configs)


def test_the_gap_is_explained_by_the_rows_that_add_up_to_it() -> None:
    made = _audit({"a": (150.0, 10, 1e-6), "b": (40.0, 10, 1e-6), "c": (-30.0, 10, 1e-6), "d": (80.0, 10, 0.4)})
    # paper 290, measured 100: gap +190 = a + b (c goes the other way, d is not beyond noise)
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "290 ± 1")
    assert text is not None and text.startswith("a (+150) + b (+40) = +190 of gap +190")
    # a gap no marked effect reaches: partly, the rest unexplained
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "600 ± 1")
    assert text is not None and text.startswith("partly: a (+150) + b (+40) = +190 of gap +500")
    # a gap the other way: only c goes that way
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "20 ± 1")
    assert text is not None and text.startswith("partly: c (-30) = -30 of gap -80")
    # no marked effect goes that way (d is not beyond noise, b is marked but the other way)
    text = audit.gap_explained_by([_audit({"b": (40.0, 10, 1e-6), "d": (-80.0, 10, 0.4)})], TASK, "upstream", "queries without SEQ", 100.0, "20 ± 1")
    assert text is not None and text.startswith("unexplained (gap -80")
    # the other direction's rows (the paper preset's) never explain an upstream row
    text = audit.gap_explained_by([made], TASK, "paper", "queries without SEQ", 100.0, "290 ± 1")
    assert text is not None and text.startswith("unexplained")
    # inside the margin (10% of the paper's value): nothing to explain
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "105 ± 1")
    assert text is not None and text.startswith("no gap beyond the margin")


def test_a_gap_whose_test_interval_holds_zero_is_no_gap_shown() -> None:
    """A point gap of +30.5 far beyond the margin, but the test's interval of lagrseq - paper
    (-85.2 to +24.2) holds 0: no gap is shown, so none is called unexplained; an interval inside
    the margin is no gap beyond it; one outside it is explained as before."""
    made = _audit({"a": (150.0, 10, 1e-6)})
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "130.5 ± 1", margin=16.4, interval=(-85.2, 24.2))
    assert text is not None and text.startswith("no gap shown")
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "103 ± 1", margin=16.4, interval=(-10.0, -1.0))
    assert text is not None and text.startswith("no gap beyond the margin (the test's 95% interval")
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "250 ± 1", margin=16.4, interval=(-170.0, -130.0))
    assert text is not None and text.startswith("a (+150) = +150 of gap +150")


def test_an_effect_far_larger_than_the_gap_explains_nothing_of_it() -> None:
    """Found in the quick suite's report: lagr.solution_scope (+759) was named as "partly"
    explaining a gap of +18.5. An effect beyond the gap plus the margin measures another regime."""
    made = _audit({"big": (759.0, 10, 1e-6), "small": (10.0, 10, 1e-6)})
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "150 ± 1")
    assert text is not None and text.startswith("partly: small (+10) = +10 of gap +50")
    only_big = _audit({"big": (759.0, 10, 1e-6)})
    text = audit.gap_explained_by([only_big], TASK, "upstream", "queries without SEQ", 100.0, "150 ± 1")
    assert text is not None and text.startswith("unexplained (gap +50; the audited effects that way overshoot it, e.g. big (+759)")


def test_rows_the_audit_never_measured_say_so() -> None:
    made = _audit({"a": (150.0, 10, 1e-6)})
    tau = json.loads(cfg.load(TASK, "lagr", "upstream", None, ["llm.temperature=0.5"]).to_json())
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "294.3 ± 3.2", tau)
    assert text == "not audited: τ = 0.5 was never audited (audit-cube-stacking ran at τ = 0)"
    cubes = json.loads(cfg.load(TASK, "lagr-seq", "upstream", None, ["task.stack_size=5"]).to_json())
    text = audit.gap_explained_by([made], TASK, "upstream", audit.RATIO_QUANTITY, 1.0, "1.5 ± 0.1", cubes)
    assert text == "not audited: this run's task.stack_size = 5 differs from the audited upstream preset (audit-cube-stacking)"
    # the audited preset's own configuration is covered
    same = json.loads(cfg.load(TASK, "lagr", "upstream").to_json())
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "250 ± 1", same)
    assert text is not None and text.startswith("a (+150) = +150 of gap +150")
    text = audit.gap_explained_by([made], TASK, "upstream", None, 0.5, "44%")
    assert text is not None and text.startswith("not audited:")
    assert audit.gap_explained_by([made], "image-completion", "upstream", "queries with SEQ", 1.0, "59.5") is None


def test_indicative_effects_explain_only_where_nothing_is_marked_and_say_so() -> None:
    made = _audit({"a": (150.0, 3, 1e-6), "b": (40.0, 3, 1e-6)})
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "290 ± 1")
    assert text is not None and "indicative" in text and text.startswith("a (+150) + b (+40) = +190")


def test_an_interaction_run_that_closes_the_gap_is_named() -> None:
    corners = pd.DataFrame(
        [
            {"corner": "none (the preset)", "switched": 0, "quantity": "queries without SEQ", "mean": 100.0, "ci_low": 99.0, "ci_high": 101.0, "trials": 10},
            {"corner": f"{GUIDED} + {EPS}", "switched": 2, "quantity": "queries without SEQ", "mean": 286.2, "ci_low": 285.0, "ci_high": 287.0, "trials": 10},
        ]
    )
    made = _audit({"a": (20.0, 10, 1e-6)}, corners=corners)
    text = audit.gap_explained_by([made], TASK, "upstream", "queries without SEQ", 100.0, "284 ± 0.94")
    assert text is not None and text.startswith(f"{GUIDED} + {EPS} switched together (+186, n=10) of gap +184")


def test_a_positive_quantitys_mean_interval_is_on_the_log_scale_and_none_below_three_trials() -> None:
    """100, 10, 190 queries (n = 3): the plain t interval reaches below 0; the log-scale one does
    not; two trials get no interval at all, nor does an effect on two."""
    values = np.array([100.0, 10.0, 190.0])
    assert inference.t_interval(values).low < 0
    shown = audit.mean_interval(values, "queries with SEQ")
    assert 0 < shown.low < 100 < shown.high
    assert audit.mean_interval(np.array([-5.0, 2.0, 9.0]), "total return (LaGR-SEQ)").low < 0  # not positive: t
    assert math.isnan(audit.mean_interval(values[:2], "queries with SEQ").low)
    effect, p = audit.contrast([(1.0, values[:2]), (-1.0, values[1:])])
    assert math.isnan(effect.low) and math.isnan(p)
