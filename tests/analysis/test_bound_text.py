"""A frontier verdict's bounds are printed whatever their size: a log-ratio bound past what a
float's exponential can hold prints as a number, never an OverflowError that ends ``lagrseq
frontier`` after all its runs."""

from __future__ import annotations

import math

from lagrseq.analysis import paired
from lagrseq.analysis.frontier import Verdict


def _verdict(lower: float, upper: float, log_ratio: float) -> Verdict:
    slowdown = paired.SlowdownVerdict(
        verdict=paired.INFERIOR, log_ratio=log_ratio, lower=lower, upper=upper, margin=math.log(1.1),
        n=3, cap=1000.0, reason="n < 10 pairs",
    )
    return Verdict(slowdown, None, None, None, None, False, "")


def test_a_bound_past_any_float_prints_without_overflow() -> None:
    text = _verdict(lower=-1.0, upper=1000.0, log_ratio=800.0).always_text
    assert "n = 3 pairs" in text and "bounds [0.36, " in text


def test_an_ordinary_bound_prints_rounded_outward() -> None:
    text = _verdict(lower=math.log(0.951), upper=math.log(1.051), log_ratio=0.0).always_text
    assert "ratio 1, 95% bounds [0.95, 1.06], margin 1.10, n = 3 pairs" in text
