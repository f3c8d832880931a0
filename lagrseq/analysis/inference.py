"""Inference for small numbers of trials: t-intervals, equivalence and non-inferiority verdicts, Holm.

A reproduction is judged on 3 to 20 trials per cell. Percentile-bootstrap intervals under-cover
there (nominal 95% covers about 76% of normal means at n = 3 and 84% at n = 5); Student's t
interval has its nominal coverage for normal data at every n >= 2, so every verdict here is built
on it (Welch's version for a difference of two means). The t distribution is ``scipy.stats.t``.

Verdicts are three-way and never read from overlapping intervals:

* :func:`equivalence` compares trials with a published value and a stated margin (two one-sided
  tests, TOST): ``reproduced`` when the (1 - 2 alpha) interval lies inside ``value +- margin``,
  ``differs`` when the (1 - alpha) interval lies entirely outside that band, else
  ``inconclusive``; fewer than ``min_n`` trials gives no verdict either way.
* :func:`tost` is the same verdict against a paper value that has its own uncertainty (the
  paper's ± and n, :func:`paper_estimate`): a two-sample Welch TOST on the difference, with
  Welch-Satterthwaite degrees of freedom; :func:`above` judges a directional claim (a trend's
  slope, :func:`contrast` with :func:`slope_weights`) against a threshold. Fewer than
  :data:`MIN_N_REPRODUCED` trials is :data:`NO_VERDICT` in every one of them.
* :class:`Estimate` carries a value with its standard error and degrees of freedom;
  :meth:`Estimate.log_interval` is the interval of a positive quantity (a count's mean, a ratio)
  on the log scale, which never leaves (0, inf).
* :func:`noninferiority` compares a treatment with a control on an outcome and a margin (one-sided
  Welch test at level alpha): ``non-inferior``, ``inferior`` or ``inconclusive``; fewer than
  ``min_n`` trials in either arm is always ``inconclusive``.
* :func:`paired_noninferiority` is the same verdict where the design pairs the arms (trial ``i``
  of both ran on the same seeds: common random numbers): a one-sided t test on the per-pair
  differences, so what the pairs share (the environment's draws) cancels instead of swamping the
  margin. Use it only where every pair is matched by construction; else :func:`noninferiority`.
* :func:`holm` adjusts a family of p-values (Holm's step-down), so marks over many comparisons
  keep the family-wise error at alpha.
* :func:`log_ratio_tost` is :func:`tost` on the log scale for a positive quantity (a count, a
  ratio): Cox's term for a skewed arm's spread in each arm's variance (:func:`log_variance`) and
  the smaller arm's degrees of freedom (:func:`hsu_df`); :func:`min_half_width` is the narrowest
  interval a test against a paper value can reach, and :func:`judge_untestable` the two-valued
  verdict (:data:`CONSISTENT` or ``differs``) of a row whose margin is narrower.
* :func:`positive_mean_interval` is the modified Cox interval of a positive quantity's mean;
  :func:`jonckheere` and :func:`direction` test a trend's direction on per-trial values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import t as _t

from lagrseq.analysis.interval import Interval

REPRODUCED = "reproduced"
DIFFERS = "differs"
INCONCLUSIVE = "inconclusive"
FITTED = "fitted"
NO_VERDICT = "no verdict"
"""Not a verdict: what a row says where none may be given (fewer than :data:`MIN_N_REPRODUCED`
trials, a fallback decided a trial, no paper value)."""
NON_INFERIOR = "non-inferior"
INFERIOR = "inferior"

ALPHA = 0.05
MIN_N_REPRODUCED = 5
"""No verdict (reproduced or differs) on fewer trials than this: below it a t interval is honest
but so wide (t(0.975, 3) = 3.18) that a verdict would rest on one or two trials."""
MIN_N_INTERVAL = 3
"""No interval is shown on fewer trials than this: at n = 2 (t(0.975, 1) = 12.7) a 95% interval
of a count spans orders of magnitude and says nothing."""
MIN_N_NONINFERIORITY = 10
"""No policy is called non-inferior (or inferior) on fewer evaluation trials than this."""
RELATIVE_MARGIN = 0.10
"""The default equivalence margin: 10% of the paper's value, or the paper's own +- if larger."""


# -- Student's t distribution (scipy.stats) --------------------------------------------------------


def t_cdf(t: float, df: float) -> float:
    """P(T <= t) for Student's t with ``df`` degrees of freedom (df > 0): ``scipy.stats.t``."""
    if not df > 0:
        raise ValueError(f"degrees of freedom must be positive, got {df}")
    return float(_t.cdf(t, df))


def t_ppf(p: float, df: float) -> float:
    """The ``p`` quantile of Student's t with ``df`` degrees of freedom (0 < p < 1)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability must lie strictly between 0 and 1, got {p}")
    if not df > 0:
        raise ValueError(f"degrees of freedom must be positive, got {df}")
    return float(_t.ppf(p, df))


# -- intervals ------------------------------------------------------------------------------------


def _finite(values: Sequence[float] | np.ndarray) -> np.ndarray:
    x = np.asarray(values, dtype=float).ravel()
    return x[np.isfinite(x)]


def t_interval(values: Sequence[float] | np.ndarray, level: float = 0.95) -> Interval:
    """Student's t interval of the mean of the finite ``values``."""
    x = _finite(values)
    n = int(x.size)
    if n == 0:
        return Interval(0, math.nan, math.nan, math.nan, level)
    mean = float(x.mean())
    if n < 2:
        return Interval(n, mean, math.nan, math.nan, level)
    se = float(x.std(ddof=1)) / math.sqrt(n)
    half = t_ppf(0.5 + level / 2.0, n - 1) * se
    return Interval(n, mean, mean - half, mean + half, level)


def _welch(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Difference of means, its standard error and Welch-Satterthwaite degrees of freedom."""
    vx, vy = float(x.var(ddof=1)) / x.size, float(y.var(ddof=1)) / y.size
    se = math.sqrt(vx + vy)
    diff = float(x.mean() - y.mean())
    if se == 0.0:
        return diff, 0.0, float(x.size + y.size - 2)
    return diff, se, satterthwaite((vx, vy), (x.size - 1, y.size - 1))


def welch_interval(
    x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, level: float = 0.95
) -> Interval:
    """Welch's interval of ``mean(x) - mean(y)``; ``n`` is the smaller arm's count."""
    a, b = _finite(x), _finite(y)
    n = int(min(a.size, b.size))
    if a.size == 0 or b.size == 0:
        return Interval(n, math.nan, math.nan, math.nan, level)
    if a.size < 2 or b.size < 2:
        return Interval(n, float(a.mean() - b.mean()), math.nan, math.nan, level)
    diff, se, df = _welch(a, b)
    half = t_ppf(0.5 + level / 2.0, df) * se if se > 0 else 0.0
    return Interval(n, diff, diff - half, diff + half, level)


def _relative_variance(x: np.ndarray) -> float:
    """The variance of the mean of ``x`` (a nonzero mean) relative to its square; through the
    coefficient of variation where the square under- or overflows (a mean near 1e-160)."""
    mean = float(x.mean())
    try:
        return float(x.var(ddof=1)) / x.size / mean**2
    except (ZeroDivisionError, OverflowError):
        cv = float(x.std(ddof=1)) / mean
        return cv * cv / x.size


def ratio_interval(
    x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, level: float = 0.95
) -> Interval:
    """Interval of ``mean(x) / mean(y)`` for two independent arms (e.g. queries with and without
    SEQ): the delta method's standard error, ``r * sqrt(se_x^2 / mean_x^2 + se_y^2 / mean_y^2)``,
    with Welch-Satterthwaite degrees of freedom of the two relative variances and Student's t
    quantile. ``n`` is the smaller arm's count; NaN bounds with fewer than 2 values per arm, a
    zero denominator or a ratio that overflows."""
    a, b = _finite(x), _finite(y)
    n = int(min(a.size, b.size))
    if a.size == 0 or b.size == 0 or float(b.mean()) == 0.0:
        return Interval(n, math.nan, math.nan, math.nan, level)
    ratio = float(a.mean()) / float(b.mean())
    if a.size < 2 or b.size < 2 or float(a.mean()) == 0.0 or not math.isfinite(ratio):
        return Interval(n, ratio, math.nan, math.nan, level)
    rx, ry = _relative_variance(a), _relative_variance(b)
    if rx + ry == 0.0:
        return Interval(n, ratio, ratio, ratio, level)
    se = abs(ratio) * math.sqrt(rx + ry)
    half = t_ppf(0.5 + level / 2.0, satterthwaite((rx, ry), (a.size - 1, b.size - 1))) * se
    return Interval(n, ratio, ratio - half, ratio + half, level)


# -- estimates with a standard error: lagrseq's and the paper's -----------------------------------


@dataclass(frozen=True)
class Estimate:
    """A mean-like number with its standard error and Student-t degrees of freedom: lagrseq's
    mean over ``n`` trials, a paper value with its reported ``±`` (:func:`paper_estimate`), a
    ratio of two means or a contrast of several (``n``: the smallest arm's count). ``se`` is NaN
    with fewer than 2 values (no interval); 0 with no spread (an exact value)."""

    value: float
    se: float
    df: float
    n: int

    def interval(self, level: float = 0.95) -> Interval:
        """The t interval ``value ± t(df) se`` (no range: a difference or a slope)."""
        if math.isnan(self.se) or math.isnan(self.value):
            return Interval(self.n, self.value, math.nan, math.nan, level)
        half = t_ppf(0.5 + level / 2.0, self.df) * self.se if self.se > 0 else 0.0
        return Interval(self.n, self.value, self.value - half, self.value + half, level)

    def log_interval(self, level: float = 0.95) -> Interval:
        """The interval of a positive quantity (a count's mean, a ratio) on the log scale:
        ``value * exp(± t(df) se / value)`` (the delta method for ``log(value)``), so it never
        leaves (0, inf); a value of 0 with no spread is [0, 0]; NaN bounds for a value <= 0 with
        spread (no log scale) or without a standard error."""
        if math.isnan(self.se) or math.isnan(self.value):
            return Interval(self.n, self.value, math.nan, math.nan, level)
        if self.se == 0.0:
            return Interval(self.n, self.value, self.value, self.value, level)
        if self.value <= 0.0:
            return Interval(self.n, self.value, math.nan, math.nan, level)
        half = t_ppf(0.5 + level / 2.0, self.df) * self.se / self.value
        return Interval(self.n, self.value, self.value * math.exp(-half), self.value * math.exp(half), level)


def satterthwaite(variances: Sequence[float], dfs: Sequence[float]) -> float:
    """Welch-Satterthwaite degrees of freedom of a sum of independent variance terms (each a
    squared standard error with its own degrees of freedom); a term with variance 0 adds none,
    and no variance at all gives the sum of the degrees of freedom. Where the squares under- or
    overflow (spreads near 1e-150 or 1e150), the same ratio with each variance taken relative to
    the largest; an infinite variance gives the smallest degrees of freedom (its interval is
    infinite at any)."""
    total = float(sum(variances))
    if total == 0.0:
        return float(sum(dfs))
    terms = [(v, d) for v, d in zip(variances, dfs, strict=True) if v > 0]
    if not terms:  # no positive variance (NaN ones only): as if none
        return float(sum(dfs))
    denominator = sum(v * v / d for v, d in terms)
    if 0.0 < denominator < math.inf and total * total < math.inf:
        return total * total / denominator
    top = max(v for v, _ in terms)
    if not top < math.inf:
        return float(min(dfs))
    return (total / top) ** 2 / sum((v / top) ** 2 / d for v, d in terms)


def mean_estimate(values: Sequence[float] | np.ndarray) -> Estimate:
    """The mean of the finite ``values``, its standard error and ``n - 1`` degrees of freedom."""
    x = _finite(values)
    n = int(x.size)
    if n == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    if n < 2:
        return Estimate(float(x.mean()), math.nan, math.nan, n)
    return Estimate(float(x.mean()), float(x.std(ddof=1)) / math.sqrt(n), float(n - 1), n)


def paper_estimate(value: float, plus_minus: float, n: int, spread: str = "se") -> Estimate:
    """A paper's ``value ± plus_minus`` over ``n`` runs as an estimate: ``spread`` says what the
    ± is, ``se`` (a standard error: as it stands) or ``sd`` (a standard deviation: divided by
    sqrt(n)); ``n - 1`` degrees of freedom."""
    if n < 2:
        raise ValueError(f"a paper value needs n >= 2 runs for a standard error, got {n}")
    if spread not in ("se", "sd"):
        raise ValueError(f"the paper's ± is a standard error (se) or a standard deviation (sd), got {spread!r}")
    se = abs(plus_minus) if spread == "se" else abs(plus_minus) / math.sqrt(n)
    return Estimate(float(value), se, float(n - 1), n)


def ratio_estimate(top: Estimate, bottom: Estimate) -> Estimate:
    """``top / bottom`` of two independent estimates (e.g. queries with and without SEQ): the delta
    method's standard error ``|r| sqrt(se_t^2 / t^2 + se_b^2 / b^2)`` with Welch-Satterthwaite
    degrees of freedom of the two relative variances (NaN with a zero denominator)."""
    n = min(top.n, bottom.n)
    if bottom.value == 0.0 or math.isnan(bottom.value) or math.isnan(top.value):
        return Estimate(math.nan, math.nan, math.nan, n)
    ratio = top.value / bottom.value
    if math.isnan(top.se) or math.isnan(bottom.se) or top.value == 0.0:
        return Estimate(ratio, math.nan, math.nan, n)
    rt, rb = (top.se / top.value) ** 2, (bottom.se / bottom.value) ** 2
    return Estimate(ratio, abs(ratio) * math.sqrt(rt + rb), satterthwaite((rt, rb), (top.df, bottom.df)), n)


def contrast(estimates: Sequence[Estimate], weights: Sequence[float]) -> Estimate:
    """``sum(w_i * value_i)`` of independent estimates (a slope, a difference of rows), its
    standard error ``sqrt(sum(w_i^2 se_i^2))`` and Welch-Satterthwaite degrees of freedom."""
    if len(estimates) != len(weights) or not estimates:
        raise ValueError(f"a contrast needs one weight per estimate, got {len(estimates)} and {len(weights)}")
    n = min(e.n for e in estimates)
    value = float(sum(w * e.value for e, w in zip(estimates, weights, strict=True)))
    if any(math.isnan(e.se) for e, w in zip(estimates, weights, strict=True) if w != 0.0):
        return Estimate(value, math.nan, math.nan, n)
    variances = [w * w * e.se * e.se for e, w in zip(estimates, weights, strict=True)]
    return Estimate(value, math.sqrt(sum(variances)), satterthwaite(variances, [e.df for e in estimates]), n)


def slope_weights(xs: Sequence[float]) -> list[float]:
    """Least-squares slope weights of means at ``xs``: ``(x_i - mean(x)) / sum((x - mean(x))^2)``
    (with two points, the difference over the distance; three equally spaced points, the last
    minus the first over the range)."""
    x = np.asarray(xs, dtype=float)
    centred = x - x.mean()
    spread = float((centred**2).sum())
    if x.size < 2 or spread == 0.0:
        raise ValueError(f"a slope needs at least two distinct x values, got {list(xs)}")
    return [float(c / spread) for c in centred]


# -- verdicts -------------------------------------------------------------------------------------


def margin_for(paper_value: float, paper_pm: float | None = None, relative: float = RELATIVE_MARGIN) -> float:
    """The equivalence margin around a published value: the larger of ``relative`` times its size
    and the paper's own +- (its reported spread), when it gives one."""
    margin = relative * abs(paper_value)
    if paper_pm is not None and math.isfinite(paper_pm):
        margin = max(margin, abs(paper_pm))
    return margin


@dataclass(frozen=True)
class Equivalence:
    """The verdict of trials against a published value: ``interval`` is the (1 - 2 alpha) interval
    the TOST reads, ``wide`` the (1 - alpha) interval that ``differs`` reads."""

    verdict: str
    target: float
    margin: float
    interval: Interval
    wide: Interval
    reason: str


def equivalence(
    values: Sequence[float] | np.ndarray,
    target: float,
    margin: float,
    alpha: float = ALPHA,
    min_n: int = MIN_N_REPRODUCED,
) -> Equivalence:
    """Three-way verdict of the mean of ``values`` against ``target +- margin`` (see the module)."""
    return judge(t_interval(values, 1.0 - 2.0 * alpha), t_interval(values, 1.0 - alpha), target, margin, min_n)


def judge(inner: Interval, wide: Interval, target: float, margin: float, min_n: int = MIN_N_REPRODUCED) -> Equivalence:
    """The three-way verdict from intervals already computed: ``inner`` at (1 - 2 alpha), which
    must lie inside ``target +- margin`` for ``reproduced``, and ``wide`` at (1 - alpha), which
    must exclude that band for ``differs`` (:func:`equivalence` for a mean; any other estimate
    with an interval, such as :func:`ratio_interval`, is judged the same way). Fewer than
    ``min_n`` trials is :data:`NO_VERDICT` either way."""
    if not (math.isfinite(target) and math.isfinite(margin) and margin >= 0):
        raise ValueError(f"target and margin must be finite (margin >= 0), got {target}, {margin}")
    low_band, high_band = target - margin, target + margin
    if inner.n < min_n:
        return Equivalence(NO_VERDICT, target, margin, inner, wide, f"n = {inner.n} < {min_n}: no verdict below {min_n} trials")
    if math.isnan(inner.low) or math.isnan(wide.low):
        return Equivalence(INCONCLUSIVE, target, margin, inner, wide, f"n = {inner.n}: no interval")
    if wide.high < low_band or wide.low > high_band:
        return Equivalence(DIFFERS, target, margin, inner, wide, "the interval excludes the margin band")
    if low_band <= inner.low and inner.high <= high_band:
        return Equivalence(REPRODUCED, target, margin, inner, wide, "the interval lies inside the margin")
    return Equivalence(INCONCLUSIVE, target, margin, inner, wide, "the interval overlaps the margin's edge")


def tost(ours: Estimate, paper: Estimate, margin: float, alpha: float = ALPHA, min_n: int = MIN_N_REPRODUCED) -> Equivalence:
    """Two-sample Welch TOST of lagrseq's estimate against the paper's (its value, its ± as a
    standard error, its n: :func:`paper_estimate`): the difference ``ours - paper``, its standard
    error ``sqrt(se_ours^2 + se_paper^2)`` and Welch-Satterthwaite degrees of freedom.
    ``reproduced`` when its (1 - 2 alpha) interval lies inside ``± margin``, ``differs`` when its
    (1 - alpha) interval lies outside, else ``inconclusive``; fewer than ``min_n`` of lagrseq's
    trials is :data:`NO_VERDICT`. ``interval``/``wide`` of the result are the difference's."""
    difference = contrast([ours, paper], [1.0, -1.0])
    inner, wide = difference.interval(1.0 - 2.0 * alpha), difference.interval(1.0 - alpha)
    inner = Interval(ours.n, inner.mean, inner.low, inner.high, inner.level)
    return judge(inner, wide, 0.0, margin, min_n)


@dataclass(frozen=True)
class Directional:
    """The verdict on a directional claim (a trend the paper states): lagrseq's ``estimate`` (a
    slope or a contrast) against ``threshold``; ``inner``/``wide`` its (1 - 2 alpha) and
    (1 - alpha) intervals."""

    verdict: str
    estimate: Estimate
    threshold: float
    inner: Interval
    wide: Interval
    reason: str


def above(estimate: Estimate, threshold: float, alpha: float = ALPHA, min_n: int = MIN_N_REPRODUCED) -> Directional:
    """Whether ``estimate`` lies above ``threshold``: ``reproduced`` when its one-sided (1 - alpha)
    lower bound (the (1 - 2 alpha) interval's low end) lies above it, ``differs`` when its
    (1 - alpha) interval lies entirely below it, else ``inconclusive``; fewer than ``min_n``
    trials in an arm is :data:`NO_VERDICT`. For "rises" the threshold is a smallest rise worth
    the name; for "holds" (does not fall) minus a largest fall that still holds."""
    inner, wide = estimate.interval(1.0 - 2.0 * alpha), estimate.interval(1.0 - alpha)
    if estimate.n < min_n:
        return Directional(NO_VERDICT, estimate, threshold, inner, wide, f"n = {estimate.n} < {min_n}: no verdict below {min_n} trials")
    if math.isnan(inner.low) or math.isnan(wide.high):
        return Directional(INCONCLUSIVE, estimate, threshold, inner, wide, "no interval")
    if inner.low > threshold:
        return Directional(REPRODUCED, estimate, threshold, inner, wide, "the lower bound lies above the threshold")
    if wide.high < threshold:
        return Directional(DIFFERS, estimate, threshold, inner, wide, "the interval lies below the threshold")
    return Directional(INCONCLUSIVE, estimate, threshold, inner, wide, "the interval straddles the threshold")


@dataclass(frozen=True)
class NonInferiority:
    """Treatment against control on one outcome. ``bound`` is the one-sided (1 - alpha) lower bound
    of the treatment's advantage (oriented so that larger is better); ``p`` the one-sided p-value
    of inferiority by more than the margin."""

    verdict: str
    difference: float
    bound: float
    margin: float
    p: float
    n_treatment: int
    n_control: int
    reason: str
    test: str = "Welch"
    """``Welch`` (two independent arms) or ``paired t`` (per-pair differences)."""


def noninferiority(
    treatment: Sequence[float] | np.ndarray,
    control: Sequence[float] | np.ndarray,
    margin: float,
    higher_is_better: bool = True,
    alpha: float = ALPHA,
    min_n: int = MIN_N_NONINFERIORITY,
) -> NonInferiority:
    """One-sided Welch test that the treatment is worse than the control by less than ``margin``.

    ``non-inferior``: the (1 - alpha) lower bound of the advantage lies above ``-margin``;
    ``inferior``: its (1 - alpha) upper bound lies below ``-margin``; else ``inconclusive``.
    """
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"the margin must be finite and >= 0, got {margin}")
    sign = 1.0 if higher_is_better else -1.0
    a, b = sign * _finite(treatment), sign * _finite(control)
    na, nb = int(a.size), int(b.size)
    if na < 2 or nb < 2:
        diff = float(a.mean() - b.mean()) if na and nb else math.nan
        return NonInferiority(INCONCLUSIVE, diff, math.nan, margin, math.nan, na, nb, "fewer than 2 trials in an arm")
    diff, se, df = _welch(a, b)
    verdict, bound, p, reason = _judge_margin(diff, se, df, margin, alpha, min(na, nb), min_n, "trials")
    return NonInferiority(verdict, diff, bound, margin, p, na, nb, reason)


def _judge_margin(
    diff: float, se: float, df: float, margin: float, alpha: float, n: int, min_n: int, unit: str
) -> tuple[str, float, float, str]:
    """(verdict, lower bound, p, reason) of a one-sided test that ``diff`` (larger is better) lies
    above ``-margin``, from its standard error and t degrees of freedom (no spread: the bound is
    ``diff`` itself, an exact verdict); fewer than ``min_n`` of ``unit`` is inconclusive."""
    if se == 0.0:
        bound = upper = diff
        p = 0.0 if diff > -margin else 1.0
    else:
        q = t_ppf(1.0 - alpha, df)
        bound, upper = diff - q * se, diff + q * se
        p = 1.0 - t_cdf((diff + margin) / se, df)
    if n < min_n:
        return INCONCLUSIVE, bound, p, f"n = {n} < {min_n} {unit}"
    if bound > -margin:
        return NON_INFERIOR, bound, p, "lower bound above -margin"
    if upper < -margin:
        return INFERIOR, bound, p, "upper bound below -margin"
    return INCONCLUSIVE, bound, p, "the bound straddles -margin"


def paired_noninferiority(
    treatment: Sequence[float] | np.ndarray,
    control: Sequence[float] | np.ndarray,
    margin: float,
    higher_is_better: bool = True,
    alpha: float = ALPHA,
    min_n: int = MIN_N_NONINFERIORITY,
) -> NonInferiority:
    """:func:`noninferiority` for paired arms: ``treatment[i]`` and ``control[i]`` are one pair
    (the same seeds). A one-sided t test on the differences ``d_i`` (oriented so that larger is
    better) with ``n - 1`` degrees of freedom: ``non-inferior`` when the (1 - alpha) lower bound of
    mean(d) lies above ``-margin``, ``inferior`` when its (1 - alpha) upper bound lies below it,
    else ``inconclusive``; fewer than ``min_n`` pairs is always ``inconclusive``. A pair with a
    non-finite value in either arm is dropped whole. Differences that are all equal have no
    spread: the bound is their value (an exact verdict, p 0 or 1)."""
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"the margin must be finite and >= 0, got {margin}")
    a = np.asarray(treatment, dtype=float).ravel()
    b = np.asarray(control, dtype=float).ravel()
    if a.size != b.size:
        raise ValueError(f"paired arms must have the same length, got {a.size} and {b.size}")
    keep = np.isfinite(a) & np.isfinite(b)
    sign = 1.0 if higher_is_better else -1.0
    d = sign * (a[keep] - b[keep])
    n = int(d.size)
    if n < 2:
        diff = float(d.mean()) if n else math.nan
        return NonInferiority(INCONCLUSIVE, diff, math.nan, margin, math.nan, n, n, "fewer than 2 pairs", "paired t")
    diff = float(d.mean())
    se = float(d.std(ddof=1)) / math.sqrt(n)
    verdict, bound, p, reason = _judge_margin(diff, se, n - 1, margin, alpha, n, min_n, "pairs")
    return NonInferiority(verdict, diff, bound, margin, p, n, n, reason, "paired t")


def holm(pvalues: Sequence[float] | np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (NaN stays NaN and does not count as a comparison)."""
    p = np.asarray(pvalues, dtype=float)
    out = np.full(p.shape, math.nan)
    valid = np.flatnonzero(np.isfinite(p))
    m = valid.size
    if m == 0:
        return out
    order = valid[np.argsort(p[valid], kind="stable")]
    running = 0.0
    for rank, index in enumerate(order):
        running = max(running, min(1.0, (m - rank) * float(p[index])))
        out[index] = running
    return out


# -- tests on the log scale, testability, monotone trends -----------------------------------------

CONSISTENT = "consistent with the paper (interval holds 0), not testable to the margin"
"""The verdict of a row whose scale cannot reach ``reproduced`` (:func:`min_half_width` is wider
than its margin) and whose 95% interval of ``lagrseq - paper`` holds 0."""


def hsu_df(*estimates: Estimate) -> float:
    """The conservative degrees of freedom of a difference of independent estimates: the smallest
    of theirs (Hsu's rule; Welch-Satterthwaite under-covers against a skewed arm known only by its
    mean and standard error, ``benchmarks/coverage_skew.py``)."""
    return float(min(e.df for e in estimates))


@dataclass(frozen=True)
class LogRatio:
    """``log(ours / paper)`` of two positive estimates: its value, its standard error (per arm
    :func:`log_variance`) and :func:`hsu_df` degrees of freedom."""

    value: float
    se: float
    df: float
    n: int

    def interval(self, level: float) -> tuple[float, float]:
        """The t interval of the log ratio at ``level``."""
        if math.isnan(self.se) or math.isnan(self.value) or not self.df > 0:
            return math.nan, math.nan
        half = t_ppf(0.5 + level / 2.0, self.df) * self.se
        return self.value - half, self.value + half


def log_variance(e: Estimate) -> float:
    """The variance of ``log(e.value)`` for a positive mean of skewed values: the delta method's
    ``(se / value)^2`` plus Cox's term for the uncertainty of the spread, ``s^4 / (2 df)`` with
    ``s^2 = log(1 + cv^2)`` and ``cv = se sqrt(n) / value`` (the values' coefficient of variation);
    without it a 95% interval of the log ratio covers 92% against a skewed arm of 10 runs
    (``benchmarks/coverage_skew.py``)."""
    relative = e.se / e.value
    s2 = math.log1p(relative * relative * max(e.n, 1))
    return relative * relative + (s2 * s2 / (2.0 * e.df) if e.df > 0 else 0.0)


def log_ratio(ours: Estimate, paper: Estimate) -> LogRatio:
    """:class:`LogRatio` of lagrseq's estimate over the paper's (NaN where either is not positive)."""
    if not (ours.value > 0 and paper.value > 0) or math.isnan(ours.se) or math.isnan(paper.se):
        return LogRatio(math.nan, math.nan, math.nan, ours.n)
    se = math.sqrt(log_variance(ours) + log_variance(paper))
    return LogRatio(math.log(ours.value / paper.value), se, hsu_df(ours, paper), ours.n)


def log_ratio_tost(
    ours: Estimate, paper: Estimate, margin: float, scale: float, alpha: float = ALPHA, min_n: int = MIN_N_REPRODUCED,
    testable: bool = True,
) -> Equivalence:
    """The TOST of a positive quantity on the log scale: the interval of ``log(ours / paper)``
    (:func:`log_ratio`), shown in the quantity's units as ``scale * (exp(d) - 1)`` (``scale``: the
    paper's value, so the interval is ``lagrseq - paper`` at the paper's value; a negative
    ``scale`` turns it around, as for a reduction ``1 - ratio`` in points: ``-100 * ratio``), and
    judged against ``± margin`` in those units (:func:`judge`, or :func:`judge_untestable`)."""
    d = log_ratio(ours, paper)

    def shown(level: float) -> Interval:
        low, high = d.interval(level)
        ends = sorted((scale * math.expm1(low), scale * math.expm1(high))) if not math.isnan(low) else [math.nan, math.nan]
        return Interval(ours.n, scale * math.expm1(d.value) if not math.isnan(d.value) else math.nan, ends[0], ends[1], level)

    inner, wide = shown(1.0 - 2.0 * alpha), shown(1.0 - alpha)
    return judge(inner, wide, 0.0, margin, min_n) if testable else judge_untestable(inner, wide, 0.0, margin, min_n)


def judge_untestable(inner: Interval, wide: Interval, target: float, margin: float, min_n: int = MIN_N_REPRODUCED) -> Equivalence:
    """The two-valued verdict of a row that cannot reach ``reproduced`` at the paper's precision:
    :data:`CONSISTENT` where the (1 - alpha) interval holds ``target``, else :data:`DIFFERS`
    (beyond the margin, or at least from the paper's value); fewer than ``min_n`` trials is
    :data:`NO_VERDICT`."""
    if wide.n < min_n or inner.n < min_n:
        return Equivalence(NO_VERDICT, target, margin, inner, wide, f"n = {inner.n} < {min_n}: no verdict below {min_n} trials")
    if math.isnan(wide.low):
        return Equivalence(INCONCLUSIVE, target, margin, inner, wide, f"n = {inner.n}: no interval")
    if wide.low <= target <= wide.high:
        return Equivalence(CONSISTENT, target, margin, inner, wide, "the test's 95% interval of lagrseq - paper, the paper's own ± included, holds 0; that ± is too wide to test the margin")
    beyond = wide.high < target - margin or wide.low > target + margin
    why = "the 95% interval excludes the margin band" if beyond else "the 95% interval excludes the paper's value (not beyond its margin)"
    return Equivalence(DIFFERS, target, margin, inner, wide, why)


def min_half_width(paper: Estimate, n: int, alpha: float = ALPHA, log: bool = False) -> float:
    """The smallest half-width of the (1 - 2 alpha) interval of ``lagrseq - paper`` that ``n`` of
    lagrseq's trials could reach, however small their spread: on the log scale (``log``, the
    interval of :func:`log_ratio` with :func:`hsu_df`) ``t(df) * sqrt(log_variance(paper))``; on the raw scale the
    smallest ``t(df(s)) * sqrt(s^2 + se_p^2)`` over lagrseq's standard error ``s >= 0``
    (Welch-Satterthwaite df). A row whose margin is narrower cannot read ``reproduced``."""
    level = 1.0 - alpha
    if n < 2 or math.isnan(paper.se):
        return math.inf
    if log:
        if not paper.value > 0:
            return math.inf
        return t_ppf(level, min(float(n - 1), paper.df)) * math.sqrt(log_variance(paper))
    if paper.se == 0.0:
        return 0.0
    best = math.inf
    for k in range(0, 401):
        s = paper.se * k / 100.0
        variances = [s * s, paper.se * paper.se]
        df = satterthwaite(variances, [float(n - 1), paper.df])
        best = min(best, t_ppf(level, df) * math.sqrt(sum(variances)))
    return best


@dataclass(frozen=True)
class Monotone:
    """Jonckheere-Terpstra's test of ordered groups: the statistic ``J`` (pairs of values, one from
    an earlier group and one from a later, where the later is larger; ties count half), its
    permutation p-values for a rise and for a fall, and the adjacent steps' Welch 95% intervals."""

    statistic: float
    p_rise: float
    p_fall: float
    steps: tuple[Interval, ...]
    n: int


def _pairs_below(values: np.ndarray) -> np.ndarray:
    """``C[a, b]``: 1 where value a < value b, 0.5 where equal, else 0."""
    x = values[:, None]
    return (x < values[None, :]).astype(float) + 0.5 * (x == values[None, :])


def jonckheere(groups: Sequence[Sequence[float] | np.ndarray], rng: np.random.Generator, resamples: int = 10_000) -> Monotone:
    """Jonckheere-Terpstra's test that the groups (in order) rise, by ``resamples`` random
    relabellings of the pooled values drawn from ``rng`` (ties count half): ``p_rise`` is the share
    of relabellings whose statistic is at least the observed one (with the observed counted),
    ``p_fall`` the same for at most. ``steps``: Welch's 95% interval of each adjacent step."""
    clean = [_finite(g) for g in groups]
    if len(clean) < 2 or any(g.size == 0 for g in clean):
        raise ValueError("a monotone test needs at least two non-empty groups")
    pooled = np.concatenate(clean)
    labels = np.concatenate([np.full(g.size, i) for i, g in enumerate(clean)])
    below = _pairs_below(pooled)
    k = len(clean)
    upper = np.triu(np.ones((k, k)), 1)

    def statistic(assigned: np.ndarray) -> np.ndarray:
        onehot = (assigned[..., None] == np.arange(k)).astype(float)
        between = np.einsum("...ai,ab,...bj->...ij", onehot, below, onehot)
        return np.asarray((between * upper).sum(axis=(-2, -1)))

    observed = float(statistic(labels))
    shuffled = np.argsort(rng.random((resamples, pooled.size)), axis=1)
    simulated = np.concatenate([statistic(labels[shuffled[i : i + 500]]) for i in range(0, resamples, 500)])
    eps = 1e-9
    p_rise = (1.0 + float(np.sum(simulated >= observed - eps))) / (resamples + 1.0)
    p_fall = (1.0 + float(np.sum(simulated <= observed + eps))) / (resamples + 1.0)
    steps = tuple(welch_interval(b, a) for a, b in zip(clean, clean[1:]))
    return Monotone(observed, p_rise, p_fall, steps, int(min(g.size for g in clean)))


def direction(test: Monotone, alpha: float = ALPHA, min_n: int = MIN_N_REPRODUCED) -> tuple[str, str]:
    """(verdict, reason) on a claimed rise: ``reproduced`` when Jonckheere-Terpstra's rise is
    significant (p < alpha) and no adjacent step falls significantly (its 95% interval below 0),
    ``differs`` when the fall is significant, else ``inconclusive``; fewer than ``min_n`` trials
    in a group is :data:`NO_VERDICT`."""
    if test.n < min_n:
        return NO_VERDICT, f"n = {test.n} < {min_n}: no verdict below {min_n} trials"
    falling = [i for i, s in enumerate(test.steps) if s.high < 0]
    if test.p_rise < alpha and not falling:
        return REPRODUCED, f"Jonckheere-Terpstra p = {test.p_rise:.3g} for a rise; no step falls"
    if test.p_fall < alpha:
        return DIFFERS, f"Jonckheere-Terpstra p = {test.p_fall:.3g} for a fall"
    if test.p_rise < alpha:
        return INCONCLUSIVE, f"Jonckheere-Terpstra p = {test.p_rise:.3g} for a rise, but step {falling[0] + 1} falls"
    return INCONCLUSIVE, f"no monotone trend shown (Jonckheere-Terpstra p = {test.p_rise:.3g} for a rise)"


def positive_mean_interval(values: Sequence[float] | np.ndarray, level: float = 0.95, min_n: int = MIN_N_INTERVAL) -> Interval:
    """The interval of the mean of a positive quantity's per-trial values (queries per run, a
    ratio of returns): the modified Cox interval, ``exp(m + s^2 / 2 ± t(n - 1) sqrt(s^2 / n +
    s^4 / (2 (n - 1))))`` with ``m``, ``s^2`` the mean and variance of the logs; it covers at least
    93% at nominal 95% at the skew the tables measure (coefficient of variation up to 1.2, log-normal
    or gamma, n >= 3; ``benchmarks/coverage_skew.py``), where the delta-method log interval of the
    mean (:meth:`Estimate.log_interval`) falls to 89%. With a value of 0 (no log) it is that log
    interval; no interval below ``min_n`` values. ``mean``: the sample mean."""
    x = _finite(values)
    n = int(x.size)
    estimate = mean_estimate(x)
    if n < max(2, min_n):
        return Interval(n, estimate.value, math.nan, math.nan, level)
    if bool(np.any(x <= 0)):
        return estimate.log_interval(level)
    logs = np.log(x)
    m, s2 = float(logs.mean()), float(logs.var(ddof=1))
    half = t_ppf(0.5 + level / 2.0, n - 1) * math.sqrt(s2 / n + s2 * s2 / (2.0 * (n - 1)))
    centre = m + s2 / 2.0
    return Interval(n, estimate.value, math.exp(centre - half), math.exp(centre + half), level)
