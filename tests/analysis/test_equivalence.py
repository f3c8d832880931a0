"""Equivalence to random at the matched rate: two one-sided tests on the mean
per-pair log ratio of steps to the first solve, with superiority beside it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lagrseq.analysis import paired


def _pairs(rng: np.random.Generator, n: int, log_ratio: float, spread: float = 0.03) -> tuple[np.ndarray, np.ndarray]:
    other = rng.uniform(50, 500, n)
    return other * np.exp(rng.normal(log_ratio, spread, n)), other


def test_the_same_speed_is_equivalent_and_not_faster() -> None:
    rng = np.random.default_rng(1)
    policy, other = _pairs(rng, 30, 0.0)
    e = paired.equivalence(policy, other, rng)
    assert e.verdict == paired.EQUIVALENT and not e.faster
    assert -e.margin < e.lower < e.log_ratio < e.upper < e.margin and e.margin == pytest.approx(math.log(1.1))


def test_half_the_time_is_faster_and_not_equivalent_and_twice_is_not_equivalent() -> None:
    rng = np.random.default_rng(2)
    e = paired.equivalence(*_pairs(rng, 20, math.log(0.5)), rng)
    assert e.verdict == paired.DIFFERENT and e.faster and e.ratio == pytest.approx(0.5, rel=0.05)
    e = paired.equivalence(*_pairs(rng, 20, math.log(2.0)), rng)
    assert e.verdict == paired.DIFFERENT and not e.faster


def test_a_bound_across_the_margin_is_inconclusive() -> None:
    rng = np.random.default_rng(3)
    # 5% faster on average with a wide spread: the interval reaches past both 0 and -10%
    e = paired.equivalence(*_pairs(rng, 10, math.log(0.95), spread=0.3), rng)
    assert e.verdict == paired.INCONCLUSIVE and e.reason == "a bound crosses the margin"


def test_no_spread_and_too_few_pairs_give_no_verdict() -> None:
    rng = np.random.default_rng(4)
    same = np.array([100.0] * 12)
    e = paired.equivalence(same, same, rng)  # every pair identical: not taken as proof of equality
    assert e.verdict == paired.INCONCLUSIVE and not e.faster and "no spread" in e.reason and math.isnan(e.upper)
    e = paired.equivalence(*_pairs(rng, 9, 0.0), rng)
    assert e.verdict == paired.INCONCLUSIVE and "9 < 10" in e.reason
    with pytest.raises(ValueError, match="same length"):
        paired.equivalence([1.0, 2.0], [1.0], rng)
    with pytest.raises(ValueError, match="margin"):
        paired.equivalence([1.0], [1.0], rng, relative_margin=0.0)


def test_the_tost_keeps_its_level_at_the_margin() -> None:
    """At a true log ratio exactly on the margin, "equivalent" is a false claim: it must come at
    most about 5% of the time (simulated, 300 experiments of 30 skewed pairs)."""
    rng = np.random.default_rng(5)
    margin = math.log(1.1)
    claims = 0
    for _ in range(300):
        other = rng.uniform(50, 500, 30)
        d = margin + rng.standard_exponential(30) * 0.05 - 0.05  # mean exactly at the margin, skewed
        claims += paired.equivalence(other * np.exp(d), other, rng, cap=math.inf).verdict == paired.EQUIVALENT
    assert claims / 300 <= 0.09  # nominal 5%; 0.09 is about 3 binomial s.e. above it
