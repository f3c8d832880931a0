"""Equivalence to random at the matched rate: two one-sided betting bounds on the mean per-pair
log ratio of steps to the first solve, with superiority beside it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lagrseq.analysis import paired

CAP = 1000.0


def _pairs(rng: np.random.Generator, n: int, log_ratio: float, spread: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    other = rng.uniform(50, 500, n)
    return other * np.exp(rng.normal(log_ratio, spread, n)), other


def test_the_same_speed_is_equivalent_and_not_faster() -> None:
    policy, other = _pairs(np.random.default_rng(1), 600, 0.0)
    e = paired.equivalence(policy, other, CAP)
    assert e.verdict == paired.EQUIVALENT and not e.faster
    assert -e.margin < e.lower < e.log_ratio < e.upper < e.margin and e.margin == pytest.approx(math.log(1.1))


def test_half_the_time_is_faster_and_not_equivalent_and_twice_is_not_equivalent() -> None:
    rng = np.random.default_rng(2)
    e = paired.equivalence(*_pairs(rng, 300, math.log(0.5)), CAP)
    assert e.verdict == paired.DIFFERENT and e.faster and e.ratio == pytest.approx(0.5, rel=0.05)
    e = paired.equivalence(*_pairs(rng, 300, math.log(2.0)), CAP)
    assert e.verdict == paired.DIFFERENT and not e.faster


def test_identical_pairs_and_few_pairs_are_no_proof_of_equality() -> None:
    same = np.full(30, 100.0)
    e = paired.equivalence(same, same, CAP)  # finite bounds, too wide at 30 pairs to claim equality
    assert e.verdict == paired.INCONCLUSIVE and not e.faster and math.isfinite(e.upper)
    assert e.reason == "a bound crosses the margin"
    assert paired.equivalence(same[:9], same[:9], CAP).verdict == f"{paired.PROVISIONAL} {paired.INCONCLUSIVE}"
    with pytest.raises(ValueError, match="same length"):
        paired.equivalence([1.0, 2.0], [1.0], CAP)
    with pytest.raises(ValueError, match="margin"):
        paired.equivalence([1.0], [1.0], CAP, relative_margin=0.0)
