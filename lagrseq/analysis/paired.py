"""Paired comparisons that keep their level on the frontier's differences (issue 35).

The frontier pairs an asking policy's trials with always's trials on the same seeds and compares
their steps to the first solved episode. Those per-pair differences are zero-inflated and
right-skewed: most pairs solve at the very same step, one or two in ten are hundreds or thousands
of steps late. A paired t bound on such differences covers the true mean slowdown in only about
76% of samples at n = 10 (``benchmarks/coverage.py --paired``), and when all n differences happen
to be 0 it prints a certain verdict. This module replaces it with two estimands:

* **the mean log ratio** ``mean(log(policy_i / always_i))`` of the times (a time's natural scale:
  a 10% margin is ``log(1.1)`` whatever the task's length), with a one-sided studentized
  (bootstrap-t) bound. A trial that never solved counts at its step cap, so the estimand is the
  restricted mean of the log time up to that horizon (the cap is stated with every verdict).
  Differences with no spread (all equal) give no bound and no verdict.
* **the tail share**: the share of pairs in which the policy is more than ``late`` (10%) later than
  always, with an exact one-sided Clopper-Pearson upper bound (``scipy.stats.binomtest``), judged
  against a stated tail margin.

The studentized bootstrap is written here because scipy's ``bootstrap`` has no one-sided
studentized method for a paired mean that treats resamples without spread conservatively: a
resample whose values are all equal has no standard error, and its t statistic is taken as
-inf or +inf (or 0 when its mean equals the sample's), never dropped, so a sample with one late
pair in ten gives no finite bound rather than an optimistic one. Its coverage at the n the suite
uses is simulated by ``benchmarks/coverage.py --paired`` and checked in
``tests/analysis/test_paired.py``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ALPHA = 0.05
"""The level of the exact tail bound (Clopper-Pearson holds it at every n)."""
BOUND_ALPHA = 0.025
"""The studentized bootstrap's one-sided level, calibrated (Loh 1987: the nominal level chosen by
simulation so the actual coverage meets the target). At the nominal 95% the bound covered 92.1% at
30 pairs on the arrangement-like generator (``benchmarks/coverage.py --paired``): under-sampled
late pairs make the mean's bound short. At the nominal 97.5% it covers at least 93% at 30 and 60
pairs on both skewed generators (and about 97.5% on normal differences, the price: a wider bound).
At 10 pairs no level holds on the image-like generator (a sample of 10 often holds no late pair)."""
RESAMPLES = 4000
MIN_PAIRS = 10
"""Pairs below which every paired verdict is inconclusive."""
LATE = 0.10
"""A pair is *late* when the policy's time exceeds always's by more than this share."""
TAIL_MARGIN = 0.20
"""The tail verdict: non-inferior when the upper bound of the late share lies below this, inferior
when its lower bound lies above it. 20% is the rate at which the measured misses occurred (1-2
late trials in 10); a policy must show it stays below that."""

NON_INFERIOR = "non-inferior"
INFERIOR = "inferior"
INCONCLUSIVE = "inconclusive"


@dataclass(frozen=True)
class BootstrapBound:
    """A one-sided bound of a mean from a studentized bootstrap; NaN where there is none."""

    estimate: float
    lower: float
    """The (1 - alpha) lower bound of the mean."""
    upper: float
    """The (1 - alpha) upper bound of the mean."""
    n: int
    reason: str = ""


def studentized_bounds(values: Sequence[float] | np.ndarray, rng: np.random.Generator, alpha: float = ALPHA, resamples: int = RESAMPLES) -> BootstrapBound:
    """One-sided (1 - alpha) lower and upper bounds of the mean of ``values`` by the studentized
    bootstrap: ``t*_b = (mean*_b - mean) / se*_b`` over ``resamples`` resamples; upper bound
    ``mean - q_alpha(t*) se``, lower bound ``mean - q_(1-alpha)(t*) se``. A resample without
    spread has t* = 0 where its mean equals the sample's, else +-inf (conservative: never
    dropped). Fewer than 2 values, or values without spread: no bounds (NaN) and a reason."""
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n < 2:
        return BootstrapBound(float(x.mean()) if n else math.nan, math.nan, math.nan, n, "fewer than 2 pairs")
    mean = float(x.mean())
    spread = float(x.std(ddof=1))
    if spread == 0.0:
        return BootstrapBound(mean, math.nan, math.nan, n, f"no spread: all {n} differences are {mean:.4g}")
    se = spread / math.sqrt(n)
    draws = x[rng.integers(0, n, size=(resamples, n))]
    means = draws.mean(axis=1)
    ses = draws.std(axis=1, ddof=1) / math.sqrt(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ses > 0, (means - mean) / ses, np.where(means == mean, 0.0, np.sign(means - mean) * np.inf))
    low_q = float(np.quantile(t, alpha, method="lower"))
    high_q = float(np.quantile(t, 1.0 - alpha, method="higher"))
    upper = mean - low_q * se if math.isfinite(low_q) else math.inf
    lower = mean - high_q * se if math.isfinite(high_q) else -math.inf
    return BootstrapBound(mean, lower, upper, n)


@dataclass(frozen=True)
class SlowdownVerdict:
    """A policy against always on a time (lower is better), on the mean log ratio."""

    verdict: str
    log_ratio: float
    """mean(log(policy / always)) over pairs: 0 is as fast, log(1.1) 10% slower."""
    lower: float
    upper: float
    """One-sided (1 - alpha) bounds of the mean log ratio."""
    margin: float
    """The non-inferiority margin on the log scale (log(1.1) for 10%)."""
    n: int
    cap: float
    """The step cap at which a trial that never solved is counted (the restricted-mean horizon)."""
    reason: str
    alpha: float = BOUND_ALPHA
    """The one-sided level of ``lower`` and ``upper``."""

    @property
    def ratio(self) -> float:
        """The geometric-mean time ratio exp(log_ratio)."""
        return math.exp(self.log_ratio) if math.isfinite(self.log_ratio) else math.nan


def log_ratios(policy: Sequence[float] | np.ndarray, other: Sequence[float] | np.ndarray, cap: float = math.inf) -> np.ndarray:
    """The per-pair log ratios ``log(policy_i / other_i)`` of two paired arms of times, each clipped
    to ``[1, cap]`` (a trial that never solved is at its cap); a pair with a non-finite value in
    either arm is dropped whole."""
    a = np.asarray(policy, dtype=float).ravel()
    b = np.asarray(other, dtype=float).ravel()
    if a.size != b.size:
        raise ValueError(f"paired arms must have the same length, got {a.size} and {b.size}")
    keep = np.isfinite(a) & np.isfinite(b)
    return np.log(np.clip(a[keep], 1.0, cap)) - np.log(np.clip(b[keep], 1.0, cap))


def slowdown(
    policy: Sequence[float] | np.ndarray,
    always: Sequence[float] | np.ndarray,
    rng: np.random.Generator,
    relative_margin: float = 0.10,
    cap: float = math.inf,
    alpha: float = BOUND_ALPHA,
    min_pairs: int = MIN_PAIRS,
) -> SlowdownVerdict:
    """Non-inferiority of ``policy``'s times against ``always``'s, paired by index: the mean of
    the per-pair log ratios, with studentized bootstrap bounds. ``non-inferior``: the upper bound
    lies below ``log(1 + relative_margin)``; ``inferior``: the lower bound lies above it; else
    ``inconclusive`` (also below ``min_pairs`` pairs and with no spread). Times are clipped to
    ``[1, cap]`` (a trial that never solved is at its cap: the restricted mean up to that horizon)."""
    if not (math.isfinite(relative_margin) and relative_margin >= 0):
        raise ValueError(f"the margin must be finite and >= 0, got {relative_margin}")
    margin = math.log1p(relative_margin)
    found = studentized_bounds(log_ratios(policy, always, cap), rng, alpha)
    n = found.n
    if found.reason:
        return SlowdownVerdict(INCONCLUSIVE, found.estimate, math.nan, math.nan, margin, n, cap, found.reason, alpha)
    if n < min_pairs:
        return SlowdownVerdict(INCONCLUSIVE, found.estimate, found.lower, found.upper, margin, n, cap, f"n = {n} < {min_pairs} pairs", alpha)
    if found.upper < margin:
        return SlowdownVerdict(NON_INFERIOR, found.estimate, found.lower, found.upper, margin, n, cap, "upper bound below the margin", alpha)
    if found.lower > margin:
        return SlowdownVerdict(INFERIOR, found.estimate, found.lower, found.upper, margin, n, cap, "lower bound above the margin", alpha)
    return SlowdownVerdict(INCONCLUSIVE, found.estimate, found.lower, found.upper, margin, n, cap, "the bounds straddle the margin", alpha)


EQUIVALENT = "equivalent"
DIFFERENT = "not equivalent"


@dataclass(frozen=True)
class EquivalenceVerdict:
    """Two arms' times (a policy against random at its query rate) on the mean log ratio, by two
    one-sided tests (TOST): ``equivalent`` when both one-sided (1 - alpha) bounds lie inside
    ``(-margin, +margin)``; ``not equivalent`` when one bound lies wholly outside it; else
    ``inconclusive``. Beside it, superiority: ``faster`` when the upper bound lies below 0."""

    verdict: str
    faster: bool
    """The policy is faster: the one-sided (1 - alpha) upper bound of the mean log ratio is below 0."""
    log_ratio: float
    lower: float
    upper: float
    margin: float
    """The equivalence margin on the log scale (log(1.1) for 10%): symmetric, +-margin."""
    n: int
    cap: float
    reason: str
    alpha: float = BOUND_ALPHA
    """Each one-sided bound's level: the interval shown is (1 - 2 alpha)."""

    @property
    def ratio(self) -> float:
        return math.exp(self.log_ratio) if math.isfinite(self.log_ratio) else math.nan


def equivalence(
    policy: Sequence[float] | np.ndarray,
    other: Sequence[float] | np.ndarray,
    rng: np.random.Generator,
    relative_margin: float = 0.10,
    cap: float = math.inf,
    alpha: float = BOUND_ALPHA,
    min_pairs: int = MIN_PAIRS,
) -> EquivalenceVerdict:
    """Whether ``policy``'s times equal ``other``'s within ``relative_margin`` (both ways, on the
    log scale: ``|mean(log(policy_i / other_i))| < log(1 + relative_margin)``), paired by index,
    with the studentized bootstrap bounds of :func:`slowdown` at level ``alpha`` each (so the
    TOST has level ``alpha``). Turns "no better than random at its rate" into a measured
    statement either way. Times are clipped to ``[1, cap]`` as in :func:`slowdown`; below
    ``min_pairs`` pairs, or without spread, the verdict is ``inconclusive`` and ``faster`` is
    False (all-equal differences give no bound: they are not taken as proof of equality)."""
    if not (math.isfinite(relative_margin) and relative_margin > 0):
        raise ValueError(f"the equivalence margin must be finite and > 0, got {relative_margin}")
    margin = math.log1p(relative_margin)
    found = studentized_bounds(log_ratios(policy, other, cap), rng, alpha)
    n = found.n
    if found.reason:
        return EquivalenceVerdict(INCONCLUSIVE, False, found.estimate, math.nan, math.nan, margin, n, cap, found.reason, alpha)
    if n < min_pairs:
        return EquivalenceVerdict(INCONCLUSIVE, False, found.estimate, found.lower, found.upper, margin, n, cap, f"n = {n} < {min_pairs} pairs", alpha)
    faster = found.upper < 0.0
    if -margin < found.lower and found.upper < margin:
        return EquivalenceVerdict(EQUIVALENT, faster, found.estimate, found.lower, found.upper, margin, n, cap, "both bounds inside the margin", alpha)
    if found.lower > margin or found.upper < -margin:
        return EquivalenceVerdict(DIFFERENT, faster, found.estimate, found.lower, found.upper, margin, n, cap, "a bound wholly outside the margin", alpha)
    return EquivalenceVerdict(INCONCLUSIVE, faster, found.estimate, found.lower, found.upper, margin, n, cap, "a bound crosses the margin", alpha)


@dataclass(frozen=True)
class TailVerdict:
    """The share of pairs in which the policy is more than ``late`` later than always."""

    verdict: str
    late_pairs: int
    n: int
    lower: float
    upper: float
    """Exact (Clopper-Pearson) one-sided (1 - alpha) bounds of the late share."""
    late: float
    margin: float
    reason: str

    @property
    def share(self) -> float:
        return self.late_pairs / self.n if self.n else math.nan


def tail(
    policy: Sequence[float] | np.ndarray,
    always: Sequence[float] | np.ndarray,
    late: float = LATE,
    margin: float = TAIL_MARGIN,
    alpha: float = ALPHA,
    min_pairs: int = MIN_PAIRS,
) -> TailVerdict:
    """The tail-risk estimand: pairs with ``policy_i > (1 + late) * always_i``, its exact one-sided
    bounds, and a verdict against ``margin`` (see :data:`TAIL_MARGIN`)."""
    from scipy.stats import binomtest

    a = np.asarray(policy, dtype=float).ravel()
    b = np.asarray(always, dtype=float).ravel()
    if a.size != b.size:
        raise ValueError(f"paired arms must have the same length, got {a.size} and {b.size}")
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    n = int(a.size)
    k = int(np.sum(a > (1.0 + late) * b))
    if n == 0:
        return TailVerdict(INCONCLUSIVE, 0, 0, math.nan, math.nan, late, margin, "no pairs")
    interval = binomtest(k, n).proportion_ci(confidence_level=1.0 - 2.0 * alpha, method="exact")
    lower, upper = float(interval.low), float(interval.high)
    if n < min_pairs:
        return TailVerdict(INCONCLUSIVE, k, n, lower, upper, late, margin, f"n = {n} < {min_pairs} pairs")
    if upper < margin:
        return TailVerdict(NON_INFERIOR, k, n, lower, upper, late, margin, "upper bound below the tail margin")
    if lower > margin:
        return TailVerdict(INFERIOR, k, n, lower, upper, late, margin, "lower bound above the tail margin")
    return TailVerdict(INCONCLUSIVE, k, n, lower, upper, late, margin, "the bounds straddle the tail margin")


def pairs_for_power(values: Sequence[float] | np.ndarray, true_mean: float, margin: float, power: float = 0.80, alpha: float = ALPHA) -> int:
    """Pairs a one-sided test of ``mean < margin`` needs for ``power`` when the differences have
    the spread of ``values`` and their true mean is ``true_mean`` (the normal approximation
    ``n = ((z_(1-alpha) + z_power) sd / (margin - true_mean))^2``; a planning figure, not a bound)."""
    from scipy.stats import norm

    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 2 or margin <= true_mean:
        return -1
    sd = float(x.std(ddof=1))
    if sd == 0.0:
        return MIN_PAIRS
    z = float(norm.ppf(1.0 - alpha) + norm.ppf(power))
    return max(MIN_PAIRS, math.ceil((z * sd / (margin - true_mean)) ** 2))
