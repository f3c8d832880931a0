"""A mean with its two-sided interval: the one type every table, figure and test of
:mod:`lagrseq.analysis` carries an estimate in (:mod:`lagrseq.analysis.stats` makes them from
bootstraps and t intervals, :mod:`lagrseq.analysis.inference` from its tests)."""

from __future__ import annotations

import math
from dataclasses import dataclass

CONFIDENCE = 0.95


@dataclass(frozen=True)
class Interval:
    """A mean (or a difference of means) over ``n`` values with a two-sided interval at ``level``;
    for a mean of per-trial values (:func:`lagrseq.analysis.stats.summarize_t`), also their sample
    standard deviation ``std`` and the standard error ``se``. With fewer than two values the bounds,
    ``std`` and ``se`` are NaN."""

    n: int
    mean: float
    low: float
    high: float
    level: float = CONFIDENCE
    std: float = math.nan
    se: float = math.nan

    @property
    def ci_low(self) -> float:
        """``low``, under the name of the tables' CSV column."""
        return self.low

    @property
    def ci_high(self) -> float:
        """``high``, under the name of the tables' CSV column."""
        return self.high

    def __str__(self) -> str:
        if math.isnan(self.low):
            return f"{self.mean:.4g} (n = {self.n})"
        return f"{self.mean:.4g} [{self.low:.4g}, {self.high:.4g}] (n = {self.n})"
