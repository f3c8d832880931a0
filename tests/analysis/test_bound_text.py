"""A frontier verdict's bound is printed whatever its size: a log-ratio bound past the largest
float (a wide bootstrap interval of a few trials) shows as ``inf``, never an OverflowError that
ends ``lagrseq frontier`` after all its runs."""

from __future__ import annotations

import math

from lagrseq.analysis import paired
from lagrseq.analysis.frontier import Verdict


def _verdict(upper: float, log_ratio: float) -> Verdict:
    slowdown = paired.SlowdownVerdict(
        paired.INFERIOR, log_ratio, -1.0, upper, math.log(1.1), 3, 1000.0, "n < 10 pairs",
    )
    return Verdict(slowdown, None, None, None, None, False, "")


def test_a_bound_past_any_float_prints_as_inf() -> None:
    text = _verdict(upper=1000.0, log_ratio=800.0).always_text
    assert "ratio inf, bound inf >= 1.1, n = 3 pairs" in text


def test_an_ordinary_bound_prints_as_before() -> None:
    text = _verdict(upper=math.log(1.05), log_ratio=0.0).always_text
    assert "ratio 1, bound 1.05 < 1.1, n = 3 pairs" in text
