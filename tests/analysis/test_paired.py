"""Paired bounds that keep their level on zero-inflated, skewed differences (issue 35)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.analysis import paired


def _measured_like(rng: np.random.Generator, n: int) -> np.ndarray:
    """Log ratios shaped like the measured misses: 80% of pairs exactly as fast as always, 20%
    late by a factor of about e^4 (image: 6,494 steps late against about 97), 10% jittered."""
    u = rng.random(n)
    d = np.zeros(n)
    late = u < 0.2
    jitter = (u >= 0.2) & (u < 0.3)
    d[late] = rng.normal(4.2, 0.6, int(late.sum()))
    d[jitter] = rng.normal(0.0, 0.1, int(jitter.sum()))
    return d


@pytest.mark.parametrize("n", [10, 30])
def test_the_studentized_upper_bound_covers_the_mean_of_skewed_differences(n: int) -> None:
    truth = 0.2 * 4.2  # the generator's mean
    rng = np.random.default_rng(n)
    experiments = 300
    hits = sum(
        paired.studentized_bounds(_measured_like(rng, n), rng, resamples=1000).upper >= truth
        for _ in range(experiments)
    )
    # nominal 95%; at 300 experiments the binomial s.e. is about 1.3 points: 0.90 is a 4-s.e. floor
    assert hits / experiments >= 0.90


def test_no_spread_gives_no_bound_and_no_verdict() -> None:
    rng = np.random.default_rng(0)
    same = np.full(30, 120.0)
    verdict = paired.slowdown(same, same, rng)
    assert verdict.verdict == paired.INCONCLUSIVE and "no spread" in verdict.reason
    assert math.isnan(verdict.upper)


def test_a_policy_twice_as_slow_is_inferior_and_one_as_fast_is_non_inferior() -> None:
    rng = np.random.default_rng(1)
    always = rng.uniform(80, 120, 30)
    slow = always * np.exp(rng.normal(math.log(2.0), 0.1, 30))
    assert paired.slowdown(slow, always, rng).verdict == paired.INFERIOR
    fast = always * np.exp(rng.normal(0.0, 0.02, 30))
    found = paired.slowdown(fast, always, rng)
    assert found.verdict == paired.NON_INFERIOR and found.upper < math.log(1.1)
    assert paired.slowdown(fast[:5], always[:5], rng).verdict == paired.INCONCLUSIVE  # below 10 pairs


def test_a_trial_that_never_solved_counts_at_its_cap() -> None:
    rng = np.random.default_rng(2)
    always = np.full(10, 100.0) + np.arange(10)
    policy = always.copy()
    policy[0] = math.inf  # never solved
    found = paired.slowdown(policy, always, rng, cap=2000.0)
    assert found.n == 9  # a non-finite time is dropped, as the pair's other arm would be
    policy[0] = 2000.0  # the logs count it at the trial's length
    capped = paired.slowdown(policy, always, rng, cap=2000.0)
    assert capped.n == 10 and capped.cap == 2000.0
    assert capped.log_ratio == pytest.approx(math.log(2000.0 / 100.0) / 10)


def test_the_tail_share_has_exact_clopper_pearson_bounds() -> None:
    always = np.full(30, 100.0)
    none_late = paired.tail(always * 1.05, always)
    assert none_late.late_pairs == 0 and none_late.upper == pytest.approx(1 - 0.05 ** (1 / 30), rel=1e-6)
    assert none_late.verdict == paired.NON_INFERIOR  # 9.5% < 20%
    ten = paired.tail(np.full(10, 100.0), np.full(10, 100.0))
    assert ten.upper == pytest.approx(1 - 0.05 ** (1 / 10), rel=1e-6) and ten.verdict == paired.INCONCLUSIVE  # 25.9% > 20%
    late = always.copy()
    late[:15] = 500.0
    assert paired.tail(late, always).verdict == paired.INFERIOR


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-50, 50, allow_nan=False), min_size=2, max_size=40))
def test_bounds_bracket_the_estimate(values: list[float]) -> None:
    found = paired.studentized_bounds(values, np.random.default_rng(0), resamples=300)
    if found.reason:
        assert math.isnan(found.lower) and math.isnan(found.upper)
    else:
        assert found.lower <= found.estimate + 1e-9 and found.estimate <= found.upper + 1e-9


def test_pairs_for_power_grows_as_the_margin_shrinks() -> None:
    d = np.random.default_rng(3).normal(0.0, 1.0, 50)
    assert paired.pairs_for_power(d, 0.0, 0.5) > paired.pairs_for_power(d, 0.0, 1.0) >= paired.MIN_PAIRS
    assert paired.pairs_for_power(d, 1.0, 0.5) == -1


def test_the_calibrated_bound_covers_the_arrangement_like_generator_at_30_pairs() -> None:
    """The frontier's level (issue 35): at the nominal 95% the bound covered 92.1% at 30 pairs on
    the arrangement-like generator of benchmarks/coverage.py; at the calibrated nominal 97.5% it
    covers about 94% (4,000 experiments: ``python benchmarks/coverage.py --paired``). Here 400
    experiments against a floor 2.5 binomial s.e. under 94%, and the nominal 95% bound of the same
    resamples is never above it."""
    import importlib.util
    import sys
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("coverage_bench", Path(__file__).parents[2] / "benchmarks" / "coverage.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = bench  # its dataclasses look their module up
    try:
        spec.loader.exec_module(bench)
    finally:
        sys.modules.pop(spec.name, None)
    shape = next(s for s in bench.SHAPES if s.name == "arrangement-like")
    truth = bench._truth(shape, 1, draws=400_000)[0]
    rng, boot = np.random.default_rng(30), np.random.default_rng(31)
    hits = 0
    experiments = 400
    for _ in range(experiments):
        policy, always = shape.draw(rng, 30)
        d = np.log(policy) - np.log(always)
        state = boot.bit_generator.state
        calibrated = paired.studentized_bounds(d, boot, alpha=paired.BOUND_ALPHA, resamples=1000)
        boot.bit_generator.state = state
        nominal = paired.studentized_bounds(d, boot, alpha=0.05, resamples=1000)
        assert calibrated.upper >= nominal.upper
        hits += calibrated.upper >= truth
    assert hits / experiments >= 0.94 - 2.5 * math.sqrt(0.94 * 0.06 / experiments)
    assert paired.slowdown(np.full(30, 100.0), np.full(30, 100.0) + np.arange(30) % 3, np.random.default_rng(0)).alpha == paired.BOUND_ALPHA
