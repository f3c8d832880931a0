"""The small-sample inference behind every verdict: t quantiles, coverage, equivalence,
non-inferiority and Holm, on hand-made cases and by simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.analysis import inference as inf

# Student's t quantiles from published tables (two-sided 95%: the 0.975 quantile).
TABLE = [(1, 12.7062047), (2, 4.30265273), (3, 3.18244631), (4, 2.77644511), (9, 2.26215716),
         (29, 2.04522964), (100, 1.98397152)]


@pytest.mark.parametrize(("df", "quantile"), TABLE)
def test_t_quantiles_match_the_tables(df: int, quantile: float) -> None:
    assert inf.t_ppf(0.975, df) == pytest.approx(quantile, rel=1e-7)
    assert inf.t_ppf(0.025, df) == pytest.approx(-quantile, rel=1e-7)
    assert inf.t_cdf(quantile, df) == pytest.approx(0.975, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(p=st.floats(0.001, 0.999), df=st.floats(0.5, 500))
def test_quantile_and_cdf_are_inverse(p: float, df: float) -> None:
    assert inf.t_cdf(inf.t_ppf(p, df), df) == pytest.approx(p, abs=1e-9)


def test_agrees_with_scipy_where_installed() -> None:
    stats = pytest.importorskip("scipy.stats")
    for df in (1.5, 2, 3.7, 7, 40):
        for p in (0.6, 0.9, 0.95, 0.975, 0.995):
            assert inf.t_ppf(p, df) == pytest.approx(stats.t.ppf(p, df), rel=1e-8)


@pytest.mark.parametrize("n", [3, 5, 10])
def test_the_t_interval_covers_at_its_nominal_level_on_normal_data(n: int) -> None:
    """Nominal 95% covers at least 93% at n = 5 on normal data (the
    percentile bootstrap covers about 84% there). 4,000 simulated experiments per n."""
    rng = np.random.default_rng(12345 + n)
    samples = rng.normal(10.0, 3.0, size=(4000, n))
    covered = 0
    for row in samples:
        interval = inf.t_interval(row, 0.95)
        covered += interval.low <= 10.0 <= interval.high
    assert covered / 4000 >= 0.93


def test_the_percentile_bootstrap_under_covers_at_small_n_which_is_why_it_is_not_used() -> None:
    from lagrseq.analysis.stats import bootstrap_ci

    rng = np.random.default_rng(7)
    samples = rng.normal(0.0, 1.0, size=(600, 5))
    boot = np.random.default_rng(8)
    covered = sum(lo <= 0.0 <= hi for lo, hi in (bootstrap_ci(row, boot, resamples=2000) for row in samples))
    assert covered / 600 < 0.90


def test_interval_of_one_value_has_no_bounds_and_nan_values_are_dropped() -> None:
    one = inf.t_interval([4.0])
    assert one.n == 1 and one.mean == 4.0 and math.isnan(one.low)
    assert inf.t_interval([1.0, float("nan"), 3.0]).n == 2


# -- equivalence: reproduced, differs, inconclusive -------------------------------------------------


def test_tight_trials_near_the_paper_value_are_reproduced() -> None:
    verdict = inf.equivalence([99.0, 100.0, 101.0, 100.5, 99.5, 100.0], target=100.0, margin=10.0)
    assert verdict.verdict == inf.REPRODUCED
    assert verdict.interval.level == pytest.approx(0.90)


def test_tight_trials_far_from_the_paper_value_differ() -> None:
    verdict = inf.equivalence([59.0, 60.0, 61.0, 60.0, 60.5], target=100.0, margin=10.0)
    assert verdict.verdict == inf.DIFFERS


def test_wide_trials_are_inconclusive() -> None:
    verdict = inf.equivalence([60.0, 140.0, 100.0, 80.0, 120.0], target=100.0, margin=10.0)
    assert verdict.verdict == inf.INCONCLUSIVE


def test_no_verdict_either_way_below_the_minimum_number_of_trials() -> None:
    verdict = inf.equivalence([100.0, 100.1, 99.9], target=100.0, margin=10.0)
    assert verdict.verdict == inf.NO_VERDICT and "3 < 5" in verdict.reason
    assert inf.equivalence([50.0, 50.1, 49.9], target=100.0, margin=10.0).verdict == inf.NO_VERDICT  # not "differs"
    assert inf.equivalence([100.0], 100.0, 10.0).verdict == inf.NO_VERDICT


def test_the_margin_is_ten_percent_or_the_papers_spread() -> None:
    assert inf.margin_for(284.0) == pytest.approx(28.4)
    assert inf.margin_for(59.5, 30.0) == 30.0
    assert inf.margin_for(-50.0, None) == pytest.approx(5.0)


# -- non-inferiority ------------------------------------------------------------------------------


def test_non_inferior_inferior_and_inconclusive() -> None:
    rng = np.random.default_rng(3)
    control = rng.normal(100.0, 5.0, 12)
    same = rng.normal(100.0, 5.0, 12)
    worse = rng.normal(60.0, 5.0, 12)
    noisy = rng.normal(92.0, 40.0, 12)
    assert inf.noninferiority(same, control, margin=15.0).verdict == inf.NON_INFERIOR
    assert inf.noninferiority(worse, control, margin=15.0).verdict == inf.INFERIOR
    assert inf.noninferiority(noisy, control, margin=15.0).verdict == inf.INCONCLUSIVE


def test_lower_is_better_outcomes_flip_the_direction() -> None:
    control = [500.0, 520.0, 480.0, 510.0, 490.0, 505.0, 495.0, 515.0, 485.0, 500.0]
    slower = [x + 300.0 for x in control]
    faster = [x - 100.0 for x in control]
    assert inf.noninferiority(slower, control, 50.0, higher_is_better=False).verdict == inf.INFERIOR
    assert inf.noninferiority(faster, control, 50.0, higher_is_better=False).verdict == inf.NON_INFERIOR


def test_fewer_than_ten_trials_is_never_a_verdict() -> None:
    result = inf.noninferiority([100.0] * 3 + [101.0] * 2, [100.0, 99.0, 101.0, 100.0, 100.0], 10.0)
    assert result.verdict == inf.INCONCLUSIVE and result.n_treatment == 5

# -- paired non-inferiority ----------------------------------------------------------------------

# Steps to the first solve of 10 paired trials: the trials differ a lot (the environment's draws),
# the policies within a pair hardly at all.
CONTROL = [26.0, 161.0, 16.0, 12.0, 32.0, 33.0, 89.0, 9.0, 22.0, 10.0]


def test_paired_differences_by_hand() -> None:
    """d = 0..9 steps slower (lower is better): mean 4.5, sd 3.02765, se 0.957427, t(0.95, 9)
    1.833113, so the slowdown's one-sided 95% bound is 4.5 + 1.7551 = 6.2551 (and 2.7449 below)."""
    treatment = [c + d for c, d in zip(CONTROL, range(10), strict=True)]
    result = inf.paired_noninferiority(treatment, CONTROL, 7.0, higher_is_better=False)
    assert result.test == "paired t" and (result.n_treatment, result.n_control) == (10, 10)
    assert result.difference == pytest.approx(-4.5)
    assert result.bound == pytest.approx(-6.25508, abs=1e-4)
    assert result.verdict == inf.NON_INFERIOR
    assert inf.paired_noninferiority(treatment, CONTROL, 2.0, higher_is_better=False).verdict == inf.INFERIOR
    assert inf.paired_noninferiority(treatment, CONTROL, 5.0, higher_is_better=False).verdict == inf.INCONCLUSIVE
    # the same numbers unpaired: the trials' spread (sd 49) swamps the margin
    welch = inf.noninferiority(treatment, CONTROL, 7.0, higher_is_better=False)
    assert welch.test == "Welch" and welch.verdict == inf.INCONCLUSIVE


def test_paired_agrees_with_scipy_where_installed() -> None:
    stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(5)
    control = rng.normal(50.0, 30.0, 12)
    treatment = control + rng.normal(2.0, 3.0, 12)
    result = inf.paired_noninferiority(treatment, control, 4.0, higher_is_better=False)
    # H0: treatment - control >= 4 (inferior by the margin or more), against less
    expected = stats.ttest_1samp(treatment - control - 4.0, 0.0, alternative="less").pvalue
    assert result.p == pytest.approx(expected, rel=1e-6)


def test_paired_edge_cases() -> None:
    same = inf.paired_noninferiority(CONTROL, CONTROL, 3.0, higher_is_better=False)
    assert (same.verdict, same.bound, same.p) == (inf.NON_INFERIOR, 0.0, 0.0)  # no spread: exact
    late = inf.paired_noninferiority([c + 5 for c in CONTROL], CONTROL, 3.0, higher_is_better=False)
    assert (late.verdict, late.p) == (inf.INFERIOR, 1.0)
    few = inf.paired_noninferiority(CONTROL[:5], CONTROL[:5], 3.0, higher_is_better=False)
    assert few.verdict == inf.INCONCLUSIVE and few.n_treatment == 5
    # a pair with a NaN is dropped whole: 9 pairs left, below the minimum
    holed = inf.paired_noninferiority([math.nan, *CONTROL[1:]], CONTROL, 3.0, higher_is_better=False)
    assert holed.n_treatment == 9 and holed.verdict == inf.INCONCLUSIVE
    assert inf.paired_noninferiority([1.0], [1.0], 1.0).verdict == inf.INCONCLUSIVE
    with pytest.raises(ValueError, match="same length"):
        inf.paired_noninferiority([1.0, 2.0], [1.0], 1.0)
    with pytest.raises(ValueError, match="margin"):
        inf.paired_noninferiority([1.0, 2.0], [1.0, 2.0], -1.0)


@settings(max_examples=60, deadline=None)
@given(
    offsets=st.lists(st.floats(-1e4, 1e4), min_size=10, max_size=10),
    shifts=st.lists(st.floats(-20.0, 20.0), min_size=10, max_size=10),
)
def test_what_a_pair_shares_cancels(offsets: list[float], shifts: list[float]) -> None:
    """Adding any per-pair amount (a trial's environment) to both arms leaves the paired verdict
    as it was: only the within-pair differences count."""
    control = np.array(CONTROL)
    treatment = control + np.array(shifts)
    base = inf.paired_noninferiority(treatment, control, 5.0, higher_is_better=False)
    moved = inf.paired_noninferiority(treatment + offsets, control + offsets, 5.0, higher_is_better=False)
    assert moved.verdict == base.verdict
    assert moved.difference == pytest.approx(base.difference, abs=1e-6)


def test_the_paired_bound_covers_at_its_nominal_level() -> None:
    """One-sided 95%: on normal differences the bound lies below the true mean difference in at
    least 93% of 4,000 simulated experiments of 10 pairs (benchmarks/coverage.py --paired prints
    it for skewed differences too)."""
    rng = np.random.default_rng(2026)
    trial = rng.normal(0.0, 50.0, size=(4000, 10))
    control = 40.0 + trial + rng.normal(0.0, 3.0, size=(4000, 10))
    treatment = 42.0 + trial + rng.normal(0.0, 3.0, size=(4000, 10))
    hits = 0
    for x, y in zip(treatment, control, strict=True):
        # larger is better here: the advantage is +2, the lower bound must lie below it
        hits += inf.paired_noninferiority(x, y, 10.0).bound <= 2.0
    assert hits / 4000 >= 0.93


# -- Holm -----------------------------------------------------------------------------------------


def test_holm_matches_a_worked_example_and_is_monotone() -> None:
    adjusted = inf.holm([0.01, 0.04, 0.03, 0.005, float("nan")])
    # sorted: 0.005*4=0.02, 0.01*3=0.03, 0.03*2=0.06, 0.04*1 -> max(0.06, 0.04)=0.06
    assert adjusted[:4] == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert math.isnan(adjusted[4])


@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40))
def test_holm_never_lowers_a_p_value_and_keeps_order(ps: list[float]) -> None:
    adjusted = inf.holm(ps)
    assert np.all(adjusted >= np.asarray(ps) - 1e-15) and np.all(adjusted <= 1.0)
    order = np.argsort(ps, kind="stable")
    assert np.all(np.diff(adjusted[order]) >= -1e-15)


# -- the ratio of two means (the query reduction) -------------------------------------------------


def test_the_ratio_interval_of_two_means_covers_and_degrades_honestly() -> None:
    """Delta-method t interval of mean(x) / mean(y): nominal 95% covers at least 93% at n = 5
    (benchmarks/coverage.py prints it at every n); no bounds without two values per arm or with a
    zero denominator; judged like a mean by :func:`inference.judge`."""
    rng = np.random.default_rng(99)
    hits = 0
    for _ in range(1500):
        iv = inf.ratio_interval(rng.normal(100.0, 10.0, 5), rng.normal(200.0, 20.0, 5))
        hits += iv.low <= 0.5 <= iv.high
    assert hits / 1500 >= 0.93
    exact = inf.ratio_interval([50.0, 50.0], [100.0, 100.0])
    assert (exact.mean, exact.low, exact.high) == (0.5, 0.5, 0.5)
    assert math.isnan(inf.ratio_interval([1.0], [2.0, 3.0]).low)
    assert math.isnan(inf.ratio_interval([1.0, 2.0], [0.0, 0.0]).mean)
    narrow = inf.ratio_interval([49.0, 50.0, 51.0, 50.0, 50.0], [100.0, 99.0, 101.0, 100.0, 100.0], 0.90)
    wide = inf.ratio_interval([49.0, 50.0, 51.0, 50.0, 50.0], [100.0, 99.0, 101.0, 100.0, 100.0], 0.95)
    assert inf.judge(narrow, wide, 0.5, 0.05).verdict == inf.REPRODUCED
    assert inf.judge(narrow, wide, 0.8, 0.05).verdict == inf.DIFFERS
    assert inf.judge(inf.t_interval([1.0]), inf.t_interval([1.0]), 1.0, 0.1).verdict == inf.NO_VERDICT


# -- the paper's uncertainty: two-sample Welch TOST against a value with its ± and n -------------


def test_a_papers_plus_minus_is_a_standard_error_or_a_standard_deviation_converted() -> None:
    se = inf.paper_estimate(92.3, 25.03, 10)
    assert (se.value, se.se, se.df, se.n) == (92.3, 25.03, 9.0, 10)
    sd = inf.paper_estimate(92.3, 25.03, 10, spread="sd")
    assert sd.se == pytest.approx(25.03 / math.sqrt(10))
    with pytest.raises(ValueError, match="standard error"):
        inf.paper_estimate(1.0, 0.1, 10, spread="iqr")
    with pytest.raises(ValueError, match="n >= 2"):
        inf.paper_estimate(1.0, 0.1, 1)


def test_tost_against_table3s_gpt4_lagr_value_by_hand() -> None:
    """The case of lagrseq's LaGR on the authors' answers (46, 38, 24, 20, 20 queries) against
    the paper's 92.3 ± 25.03 (s.e., n = 10). By hand: mean 29.6, variance 138.8 (se^2 27.76);
    difference -62.7, se sqrt(27.76 + 626.5009) = 25.5785, Welch-Satterthwaite df
    654.2609^2 / (27.76^2 / 4 + 626.5009^2 / 9) = 9.7721; 95%: -62.7 ± 2.2354 x 25.5785 =
    [-119.88, -5.53]. Against the margin ±16.4 the interval overlaps the band: inconclusive,
    not `differs` (the verdict when 92.3 was treated as exact)."""
    ours = inf.mean_estimate([46.0, 38.0, 24.0, 20.0, 20.0])
    assert (ours.value, ours.se**2, ours.df) == (pytest.approx(29.6), pytest.approx(27.76), 4.0)
    paper = inf.paper_estimate(92.3, 25.03, 10)
    difference = inf.contrast([ours, paper], [1.0, -1.0])
    assert difference.se == pytest.approx(25.5785, abs=1e-4) and difference.df == pytest.approx(9.7721, abs=1e-4)
    wide = difference.interval(0.95)
    assert (wide.low, wide.high) == (pytest.approx(-119.88, abs=0.01), pytest.approx(-5.53, abs=0.01))
    judged = inf.tost(ours, paper, 16.4)
    assert judged.verdict == inf.INCONCLUSIVE and judged.wide.low == pytest.approx(wide.low)
    exact = inf.Estimate(92.3, 0.0, 1e9, 10)  # the old test: the paper's value as if exact
    assert inf.tost(ours, exact, 16.4).verdict == inf.DIFFERS


def test_tost_reproduces_only_when_both_uncertainties_fit_inside_the_margin() -> None:
    ours = inf.mean_estimate([100.0, 100.2, 99.8, 100.1, 99.9, 100.0])
    assert inf.tost(ours, inf.paper_estimate(100.0, 0.5, 10), 2.0).verdict == inf.REPRODUCED
    assert inf.tost(ours, inf.paper_estimate(100.0, 3.0, 10), 2.0).verdict == inf.INCONCLUSIVE  # the paper's own ± too wide
    assert inf.tost(inf.mean_estimate([100.0, 100.1, 99.9]), inf.paper_estimate(100.0, 0.5, 10), 2.0).verdict == inf.NO_VERDICT


def test_satterthwaite_and_contrasts_by_hand() -> None:
    # two terms: (a + b)^2 / (a^2 / da + b^2 / db)
    assert inf.satterthwaite([4.0, 1.0], [4.0, 9.0]) == pytest.approx(25.0 / (16.0 / 4 + 1.0 / 9))
    assert inf.satterthwaite([0.0, 0.0], [4.0, 9.0]) == 13.0  # no spread: the dfs add up
    assert inf.slope_weights([0.0, 0.5, 1.0]) == pytest.approx([-1.0, 0.0, 1.0])  # last minus first over the range
    assert inf.slope_weights([5.0, 8.0, 11.0]) == pytest.approx([-1 / 6, 0.0, 1 / 6])
    with pytest.raises(ValueError, match="two distinct"):
        inf.slope_weights([1.0, 1.0])
    parts = [inf.Estimate(126.0, 2.94, 9.0, 10), inf.Estimate(133.0, 1.41, 9.0, 10), inf.Estimate(138.33, 7.31, 9.0, 10)]
    slope = inf.contrast(parts, inf.slope_weights([0.0, 0.5, 1.0]))
    assert slope.value == pytest.approx(12.33) and slope.se == pytest.approx(math.hypot(2.94, 7.31))
    assert slope.df == pytest.approx((2.94**2 + 7.31**2) ** 2 / (2.94**4 / 9 + 7.31**4 / 9))


def test_directional_claims_against_a_threshold() -> None:
    rising = inf.mean_estimate([10.0, 11.0, 12.0, 10.5, 11.5])
    assert inf.above(rising, 3.0).verdict == inf.REPRODUCED
    assert inf.above(rising, 20.0).verdict == inf.DIFFERS
    assert inf.above(inf.mean_estimate([-5.0, 15.0, 3.0, 8.0, -2.0]), 3.0).verdict == inf.INCONCLUSIVE
    assert inf.above(inf.mean_estimate([10.0, 11.0, 12.0]), 3.0).verdict == inf.NO_VERDICT


# -- intervals that respect their quantity ------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(values=st.lists(st.floats(0.0, 1e6, allow_nan=False), min_size=2, max_size=20))
def test_the_log_scale_interval_of_a_count_never_leaves_zero_to_infinity(values: list[float]) -> None:
    estimate = inf.mean_estimate(values)
    iv = estimate.log_interval(0.95)
    if estimate.value > 0:
        assert 0 < iv.low <= estimate.value <= iv.high < math.inf
    else:
        assert iv.low == iv.high == 0.0


@settings(max_examples=150, deadline=None)
@given(top=st.lists(st.floats(0.1, 1e4), min_size=2, max_size=12), bottom=st.lists(st.floats(0.1, 1e4), min_size=2, max_size=12))
def test_a_ratios_log_interval_is_positive_so_a_reduction_stays_below_100_percent(top: list[float], bottom: list[float]) -> None:
    ratio = inf.ratio_estimate(inf.mean_estimate(top), inf.mean_estimate(bottom))
    iv = ratio.log_interval(0.95)
    assert 0 < iv.low <= ratio.value <= iv.high
    assert 100 * (1 - iv.low) < 100


def test_the_log_scale_interval_covers_at_the_trial_counts_of_the_suite() -> None:
    """Queries per trial are positive and skewed: lognormal counts (cv about 0.5) at n = 5 and 10;
    the nominal 95% log-scale interval of the mean covers at least 92% (benchmarks/coverage.py
    prints every n)."""
    rng = np.random.default_rng(2024)
    true = 100.0 * math.exp(0.5 * 0.47**2)
    for n in (5, 10):
        hits = 0
        for _ in range(2000):
            iv = inf.mean_estimate(100.0 * rng.lognormal(0.0, 0.47, n)).log_interval(0.95)
            hits += iv.low <= true <= iv.high
        assert hits / 2000 >= 0.92, n


def test_the_positive_mean_interval_is_the_modified_cox_interval() -> None:
    """Logs of 10, 20, 40: mean m = log(20), variance s^2 = (log 2)^2; the interval is
    exp(m + s^2 / 2 ± t(0.975, 2) sqrt(s^2 / 3 + s^4 / 4)), with the sample mean beside it."""
    from scipy.stats import t

    shown = inf.positive_mean_interval([10.0, 20.0, 40.0])
    s2 = math.log(2.0) ** 2
    half = t.ppf(0.975, 2) * math.sqrt(s2 / 3 + s2 * s2 / 4)
    assert shown.mean == pytest.approx(70 / 3)
    assert (shown.low, shown.high) == (pytest.approx(20 * math.exp(s2 / 2 - half)), pytest.approx(20 * math.exp(s2 / 2 + half)))
    assert math.isnan(inf.positive_mean_interval([10.0, 20.0]).low)  # none below 3 values
    with_zero = inf.positive_mean_interval([0.0, 20.0, 40.0])
    # repr, not ==: its undefined fields are NaN, and NaN equals nothing (Python 3.13's dataclass
    # __eq__ compares field by field, with no identity shortcut)
    assert repr(with_zero) == repr(inf.mean_estimate([0.0, 20.0, 40.0]).log_interval(0.95))


def test_the_positive_mean_interval_covers_skewed_counts() -> None:
    """Log-normal counts with a coefficient of variation of 1.2 (Table 3's measured skew), n = 10:
    the modified Cox interval covers at least 93% (the delta-method log interval about 89%)."""
    rng = np.random.default_rng(7)
    sigma = math.sqrt(math.log(1 + 1.2**2))
    truth = math.exp(sigma**2 / 2)
    hits = sum(
        bool(iv.low <= truth <= iv.high)
        for iv in (inf.positive_mean_interval(rng.lognormal(0.0, sigma, 10)) for _ in range(2000))
    )
    assert hits / 2000 >= 0.93


def test_the_log_ratio_test_against_a_skewed_paper_arm_covers_at_nominal_95() -> None:
    """lagrseq's 30 trials against a paper arm of 10 runs given as mean ± s.e., both log-normal
    with a coefficient of variation of 1.2: the log ratio's 95% interval with Hsu's df covers the
    true ratio at least 93% of the time."""
    rng = np.random.default_rng(11)
    sigma = math.sqrt(math.log(1 + 1.2**2))
    hits = 0
    for _ in range(2000):
        ours = inf.mean_estimate(rng.lognormal(0.0, sigma, 30))
        runs = 1.3 * rng.lognormal(0.0, sigma, 10)
        paper = inf.paper_estimate(float(runs.mean()), float(runs.std(ddof=1)) / math.sqrt(10), 10)
        low, high = inf.log_ratio(ours, paper).interval(0.95)
        hits += low <= math.log(1 / 1.3) <= high
    assert hits / 2000 >= 0.93


@settings(max_examples=50, deadline=None)
@given(groups=st.lists(st.lists(st.floats(0, 100), min_size=3, max_size=6), min_size=3, max_size=3))
def test_jonckheere_is_symmetric_under_reversal(groups: list[list[float]]) -> None:
    """Reversing the order of the groups turns J into its complement (the pairs between groups,
    ties half each way); a rise's and a fall's p-values both count the observed value, so they
    add to at least 1."""
    forward = inf.jonckheere(groups, np.random.default_rng(0), resamples=500)
    backward = inf.jonckheere(groups[::-1], np.random.default_rng(0), resamples=500)
    sizes = [len(g) for g in groups]
    pairs = sum(a * b for i, a in enumerate(sizes) for b in sizes[i + 1:])
    assert forward.statistic + backward.statistic == pytest.approx(pairs)
    assert 0 < forward.p_rise <= 1 and 0 < forward.p_fall <= 1 and forward.p_rise + forward.p_fall >= 1


SCALES = st.floats(-1e150, 1e150, allow_nan=False)
"""Finite values from subnormal to huge: their variances' squares under- and overflow."""


@settings(max_examples=200, deadline=None)
@given(x=st.lists(SCALES, min_size=3, max_size=6), y=st.lists(SCALES, min_size=3, max_size=6))
def test_welch_intervals_hold_their_estimate_at_every_scale(x: list[float], y: list[float]) -> None:
    """Welch's interval, the ratio interval and a contrast give an interval around their estimate
    for any finite values: tiny spreads (1e-140, whose squares underflow to 0) and huge ones
    (1e150, whose squares overflow) included."""
    from lagrseq.analysis import audit

    for shown in (inf.welch_interval(x, y), audit.contrast([(1.0, np.array(x)), (-1.0, np.array(y))])[0]):
        assert shown.low <= shown.mean <= shown.high, shown
    ratio = inf.ratio_interval(x, y)
    assert math.isnan(ratio.mean) or math.isnan(ratio.low) or ratio.low <= ratio.mean <= ratio.high, ratio


def test_welch_satterthwaite_degrees_of_freedom_keep_their_ratio_at_any_scale() -> None:
    """Equal variances of 3-value means: 4 degrees of freedom, at 1, 1e-280 (whose square is
    0.0) and 1e300 (whose square is infinite); an infinite variance gives the smaller n - 1; a
    NaN variance adds none when it is the only one and makes the result NaN beside a real one."""
    for v in (1.0, 1e-280, 1e300):
        assert inf.satterthwaite([v, v], [2, 2]) == pytest.approx(4.0)
    assert inf.satterthwaite([1e-280, 0.0], [2, 4]) == pytest.approx(2.0)
    assert inf.satterthwaite([math.inf, 1.0], [2, 4]) == 2.0
    assert inf.satterthwaite([math.nan, 0.0], [2, 4]) == 6.0  # no positive variance: as if none
    assert math.isnan(inf.satterthwaite([math.nan, 1.0], [2, 4]))


def test_jonckheere_matches_the_statistic_and_its_exact_tail_by_hand() -> None:
    """Groups (1, 2), (3, 4), (5, 6): every one of the 12 pairs from an earlier group is smaller,
    J = 12, the largest value; of the 90 labellings (6! / (2! 2! 2!)) only this one reaches it,
    so the exact p of a rise is 1/90 and the permutation estimate is near it."""
    test = inf.jonckheere([[1, 2], [3, 4], [5, 6]], np.random.default_rng(1), resamples=20000)
    assert test.statistic == 12.0
    assert test.p_rise == pytest.approx(1 / 90, abs=0.003) and test.p_fall == 1.0


def test_a_row_with_an_untestable_margin_reads_consistent_or_differs() -> None:
    paper = inf.paper_estimate(126.0, 2.94, 10)
    assert inf.min_half_width(paper, 10) == pytest.approx(t_ppf_09(9) * 2.94, rel=1e-3)
    ours = inf.mean_estimate([125.0, 126.0, 127.0, 126.5, 125.5, 126.0])
    assert inf.log_ratio_tost(ours, paper, 3.5, 126.0, testable=False).verdict == inf.CONSISTENT
    far = inf.mean_estimate([60.0, 61.0, 59.0, 60.0, 60.5])
    assert inf.log_ratio_tost(far, paper, 3.5, 126.0, testable=False).verdict == inf.DIFFERS


def t_ppf_09(df: float) -> float:
    from scipy.stats import t

    return float(t.ppf(0.95, df))


@settings(max_examples=200, deadline=None)
@given(
    values=st.lists(st.floats(1.0, 1000.0), min_size=5, max_size=30),
    paper=st.floats(1.0, 1000.0),
    plus_minus=st.floats(0.01, 200.0),
    share=st.floats(0.01, 0.9),
    testable=st.booleans(),
)
def test_the_log_ratio_tost_reads_what_its_intervals_show(
    values: list[float], paper: float, plus_minus: float, share: float, testable: bool
) -> None:
    """Whatever the data: reproduced only on a testable row with the 90% interval inside ±margin;
    consistent only on an untestable one with the 95% interval holding 0; differs only with the
    95% interval excluding 0; the interval in the quantity's units never reaches below -paper (the
    quantity stays positive)."""
    margin = share * paper
    judged = inf.log_ratio_tost(inf.mean_estimate(values), inf.paper_estimate(paper, plus_minus, 10), margin, paper, testable=testable)
    inner, wide = judged.interval, judged.wide
    assert wide.low >= -paper and inner.low >= -paper
    if judged.verdict == inf.REPRODUCED:
        assert testable and -margin <= inner.low and inner.high <= margin
    if judged.verdict == inf.CONSISTENT:
        assert not testable and wide.low <= 0 <= wide.high
    if judged.verdict == inf.DIFFERS:
        assert not wide.low <= 0 <= wide.high
    if not testable:
        assert judged.verdict in (inf.CONSISTENT, inf.DIFFERS)
