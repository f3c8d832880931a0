"""Paired comparisons of times to the first solve that hold their level for every distribution.

The frontier pairs an asking policy's trials with always's trials on the same seeds and compares
their steps to the first solved episode. Both times of a pair lie in ``[1, cap]`` (a trial that
never solved counts at the step cap ``cap``), so the per-pair log ratio ``log(policy_i /
always_i)`` lies in ``[-log cap, log cap]``. Two estimands are judged on it:

* **the mean log ratio** (the restricted mean up to the cap; a 10% margin is ``log(1.1)``
  whatever the task's length), with one-sided bounds from a **betting test** (Waudby-Smith and
  Ramdas, "Estimating means of bounded random variables by betting", JRSS-B 86(1), 2024): for a
  candidate mean ``m`` the capital ``K(m) = sum_j w_j prod_i (1 + c_j (m - x_i) / (L - m))``,
  ``L = log cap``, is a product of factors of mean 1 under the truth ``m = mu`` (a non-negative
  martingale), so by Markov's inequality ``P(K(mu) >= 1 / alpha) <= alpha`` for every
  distribution on ``[-L, L]`` and every n. The upper bound is the largest ``m`` not rejected.
  The bets ``c_j`` and weights ``w_j`` (:data:`BETS`) are fixed before the data, so each factor
  falls as ``x_i`` rises: a slower pair never lowers the upper bound (monotone), all-equal pairs
  of any value are treated alike (no ``== 0`` rule), and ties are ordinary values 0.
* **the tail share**: the share of pairs in which the policy is more than ``late`` (10%) later
  than always, with an exact one-sided Clopper-Pearson bound, judged against a tail margin fixed
  in advance (:data:`TAIL_MARGIN`) and shown at 5%, 10% and 20% side by side. A pair in which
  neither arm solved by the cap is *censored*: counted apart, and the tail verdict is computed
  with the censored pairs counted as late and as on time; a verdict only where both agree.

``benchmarks/coverage.py --paired`` simulates the false non-inferior rate at the margin over a
family of zero-inflated, right-skewed generators; docs/frontier.md gives the argument.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ALPHA = 0.05
"""One-sided level of every bound here (the betting bound and Clopper-Pearson hold it at every n)."""
BETS = ((1.0, 0.5), (0.5, 0.25), (0.25, 0.125), (0.125, 0.0625), (0.0625, 0.03125), (0.03125, 0.03125))
"""(bet c, weight w) of the betting test's mixture: a bet of ``c / (L - m)`` per pair, the whole
stake (c = 1) down to 1/32 of it, weights halving (they sum to 1). Fixed before any data: the
mixture of non-negative martingales is one, and a fixed bet keeps the bound monotone."""
BISECTIONS = 50
"""Halvings of ``[-L, L]`` when the bound is searched (resolution ``2 L / 2^50``; the bound is
the grid point above the largest mean not rejected: rounded outward)."""
MIN_PAIRS = 10
"""Pairs below which every verdict is shown as ``provisional``: the smallest n at which
``benchmarks/coverage.py --paired`` checks the false non-inferior rate over its family."""
LATE = 0.10
"""A pair is *late* when the policy's time exceeds always's by more than this share."""
TAIL_MARGIN = 0.10
"""The tail verdict's margin, fixed before any table: non-inferior when the exact upper bound of
the late share lies below 10%, inferior when its lower bound lies above it. The same 10% as the
mean's margin: a user who accepts a policy at most 10% slower on the geometric mean accepts at
most one trial in ten being more than 10% late."""
TAIL_MARGINS = (0.05, 0.10, 0.20)
"""The tail verdict is shown at each of these margins side by side (the verdict is at 10%)."""

NON_INFERIOR = "non-inferior"
INFERIOR = "inferior"
INCONCLUSIVE = "inconclusive"
PROVISIONAL = "provisional"
"""Prefixed to a verdict below :data:`MIN_PAIRS` pairs."""
ORDER = {NON_INFERIOR: 0, INCONCLUSIVE: 1, INFERIOR: 2}
"""Verdicts from best to worst for the policy (a slower sample never moves down this order)."""


def _log_capital(x: np.ndarray, m: np.ndarray, span: float) -> np.ndarray:
    """log K(m) per row of ``x`` (experiments x pairs) at the row's candidate ``m``."""
    scale = (m[:, None] - x) / (span - m[:, None])
    terms = []
    with np.errstate(divide="ignore"):
        for bet, weight in BETS:
            terms.append(math.log(weight) + np.log1p(np.maximum(bet * scale, -1.0)).sum(axis=1))
    return np.logaddexp.reduce(np.stack(terms), axis=0)


def upper_bounds(x: np.ndarray, span: float, alpha: float = ALPHA) -> np.ndarray:
    """The one-sided (1 - alpha) betting upper bound of the mean of each row of ``x`` (values in
    ``[-span, span]``): the smallest point of a dyadic grid above every mean the test keeps."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    low = np.full(x.shape[0], -span)
    high = np.full(x.shape[0], span)
    threshold = math.log(1.0 / alpha)
    for _ in range(BISECTIONS):
        mid = 0.5 * (low + high)
        kept = _log_capital(x, mid, span) < threshold
        low = np.where(kept, mid, low)
        high = np.where(kept, high, mid)
    return high


@dataclass(frozen=True)
class Bounds:
    """One-sided (1 - alpha) bounds of the mean log ratio and what the sample held."""

    mean: float
    lower: float
    upper: float
    n: int
    ties: int
    """Pairs with equal (capped) times: log ratio 0."""
    censored: int
    """Pairs in which neither arm solved by the cap (both at the cap: log ratio 0)."""
    span: float
    """``log cap``: the range of a log ratio is ``[-span, span]``."""


def log_ratios(policy: Sequence[float] | np.ndarray, other: Sequence[float] | np.ndarray, cap: float) -> np.ndarray:
    """The per-pair log ratios ``log(policy_i / other_i)``, each time clipped to ``[1, cap]`` (a
    trial that never solved is at its cap); a pair with a non-finite value is dropped whole."""
    a, b = _pairs(policy, other)
    return np.log(np.clip(a, 1.0, cap)) - np.log(np.clip(b, 1.0, cap))


def _pairs(policy: Sequence[float] | np.ndarray, other: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(policy, dtype=float).ravel()
    b = np.asarray(other, dtype=float).ravel()
    if a.size != b.size:
        raise ValueError(f"paired arms must have the same length, got {a.size} and {b.size}")
    keep = np.isfinite(a) & np.isfinite(b)
    return a[keep], b[keep]


def _span(cap: float) -> float:
    if not (math.isfinite(cap) and cap > 1.0):
        raise ValueError(f"the step cap must be finite and > 1 (the log ratio's range is [-log cap, log cap]), got {cap}")
    return math.log(cap)


def bounds(policy: Sequence[float] | np.ndarray, other: Sequence[float] | np.ndarray, cap: float, alpha: float = ALPHA) -> Bounds:
    """The mean log ratio of ``policy``'s times against ``other``'s (paired by index, clipped to
    ``[1, cap]``) with its one-sided (1 - alpha) betting bounds (lower: the upper bound of the
    negated ratios, negated). No pairs: NaN bounds."""
    span = _span(cap)
    a, b = _pairs(policy, other)
    a, b = np.clip(a, 1.0, cap), np.clip(b, 1.0, cap)
    x = np.log(a) - np.log(b)
    n = int(x.size)
    if n == 0:
        return Bounds(math.nan, math.nan, math.nan, 0, 0, 0, span)
    upper = float(upper_bounds(x[None, :], span, alpha)[0])
    lower = -float(upper_bounds(-x[None, :], span, alpha)[0])
    censored = int(np.sum((a >= cap) & (b >= cap)))
    return Bounds(float(x.mean()), lower, upper, n, int(np.sum(a == b)), censored, span)


def provisional(verdict: str, n: int, min_pairs: int = MIN_PAIRS) -> str:
    """``verdict``, marked ``provisional`` below ``min_pairs`` pairs."""
    return f"{PROVISIONAL} {verdict}" if n < min_pairs else verdict


@dataclass(frozen=True)
class SlowdownVerdict:
    """A policy against always on a time (lower is better), on the mean log ratio."""

    verdict: str
    """``non-inferior``, ``inferior`` or ``inconclusive``, prefixed ``provisional`` below
    :data:`MIN_PAIRS` pairs."""
    log_ratio: float
    """mean(log(policy / always)) over pairs: 0 is as fast, log(1.1) 10% slower."""
    lower: float
    upper: float
    """One-sided (1 - alpha) betting bounds of the mean log ratio."""
    margin: float
    """The non-inferiority margin on the log scale (log(1.1) for 10%)."""
    n: int
    cap: float
    """The step cap at which a trial that never solved is counted (the restricted-mean horizon)."""
    reason: str
    alpha: float = ALPHA
    ties: int = 0
    censored: int = 0

    @property
    def ratio(self) -> float:
        """The geometric-mean time ratio exp(log_ratio)."""
        return _exp(self.log_ratio)

    @property
    def settled(self) -> str:
        """The verdict without the ``provisional`` mark."""
        return self.verdict.removeprefix(f"{PROVISIONAL} ")


def _exp(value: float) -> float:
    """exp of a log ratio or bound (at most log cap in size); NaN stays NaN, never an overflow."""
    if math.isnan(value):
        return math.nan
    return math.exp(max(min(value, 700.0), -700.0))


def slowdown(
    policy: Sequence[float] | np.ndarray,
    always: Sequence[float] | np.ndarray,
    cap: float,
    relative_margin: float = 0.10,
    alpha: float = ALPHA,
    min_pairs: int = MIN_PAIRS,
) -> SlowdownVerdict:
    """Non-inferiority of ``policy``'s times against ``always``'s, paired by index, on the mean
    log ratio: ``non-inferior`` when the upper betting bound lies below ``log(1 +
    relative_margin)``, ``inferior`` when the lower one lies above it, else ``inconclusive``;
    ``provisional`` below ``min_pairs`` pairs."""
    if not (math.isfinite(relative_margin) and relative_margin >= 0):
        raise ValueError(f"the margin must be finite and >= 0, got {relative_margin}")
    margin = math.log1p(relative_margin)
    found = bounds(policy, always, cap, alpha)
    if found.n == 0:
        return SlowdownVerdict(INCONCLUSIVE, math.nan, math.nan, math.nan, margin, 0, cap, "no pairs", alpha)
    if found.upper < margin:
        verdict, reason = NON_INFERIOR, "upper bound below the margin"
    elif found.lower > margin:
        verdict, reason = INFERIOR, "lower bound above the margin"
    else:
        verdict, reason = INCONCLUSIVE, "the bounds straddle the margin"
    return SlowdownVerdict(
        provisional(verdict, found.n, min_pairs), found.mean, found.lower, found.upper, margin, found.n, cap,
        reason, alpha, found.ties, found.censored,
    )


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
    alpha: float = ALPHA
    """Each one-sided bound's level: the interval shown is (1 - 2 alpha)."""

    @property
    def ratio(self) -> float:
        return _exp(self.log_ratio)


def equivalence(
    policy: Sequence[float] | np.ndarray,
    other: Sequence[float] | np.ndarray,
    cap: float,
    relative_margin: float = 0.10,
    alpha: float = ALPHA,
    min_pairs: int = MIN_PAIRS,
) -> EquivalenceVerdict:
    """Whether ``policy``'s times equal ``other``'s within ``relative_margin`` both ways on the
    mean log ratio, paired by index, with the betting bounds of :func:`slowdown` at level
    ``alpha`` each (so the TOST has level ``alpha``); ``provisional`` below ``min_pairs``."""
    if not (math.isfinite(relative_margin) and relative_margin > 0):
        raise ValueError(f"the equivalence margin must be finite and > 0, got {relative_margin}")
    margin = math.log1p(relative_margin)
    found = bounds(policy, other, cap, alpha)
    if found.n == 0:
        return EquivalenceVerdict(INCONCLUSIVE, False, math.nan, math.nan, math.nan, margin, 0, cap, "no pairs", alpha)
    faster = found.upper < 0.0
    if -margin < found.lower and found.upper < margin:
        verdict, reason = EQUIVALENT, "both bounds inside the margin"
    elif found.lower > margin or found.upper < -margin:
        verdict, reason = DIFFERENT, "a bound wholly outside the margin"
    else:
        verdict, reason = INCONCLUSIVE, "a bound crosses the margin"
    return EquivalenceVerdict(
        provisional(verdict, found.n, min_pairs), faster, found.mean, found.lower, found.upper, margin, found.n, cap, reason, alpha
    )


@dataclass(frozen=True)
class TailVerdict:
    """The share of pairs in which the policy is more than ``late`` later than always."""

    verdict: str
    """At :data:`TAIL_MARGIN`: a verdict only where counting the censored pairs as late and as
    on time agree; ``provisional`` below :data:`MIN_PAIRS`."""
    late_pairs: int
    """Pairs late with the censored pairs counted on time."""
    n: int
    lower: float
    upper: float
    """Exact one-sided (1 - alpha) bounds of the late share, censored pairs on time."""
    late: float
    margin: float
    reason: str
    censored: int = 0
    """Pairs in which neither arm solved by the cap (counted apart)."""
    upper_if_late: float = math.nan
    """The exact upper bound with the censored pairs counted as late."""
    lower_if_late: float = math.nan
    at_margins: tuple[tuple[float, str], ...] = ()
    """(margin, verdict) at each of :data:`TAIL_MARGINS`."""

    @property
    def share(self) -> float:
        return self.late_pairs / self.n if self.n else math.nan

    @property
    def settled(self) -> str:
        return self.verdict.removeprefix(f"{PROVISIONAL} ")


def clopper_pearson(k: int, n: int, alpha: float = ALPHA) -> tuple[float, float]:
    """Exact one-sided (1 - alpha) lower and upper bounds of a share of k in n."""
    from scipy.stats import beta

    lower = 0.0 if k == 0 else float(beta.ppf(alpha, k, n - k + 1))
    upper = 1.0 if k == n else float(beta.ppf(1.0 - alpha, k + 1, n - k))
    return lower, upper


def _tail_verdict(on_time: tuple[float, float], as_late: tuple[float, float], margin: float) -> str:
    """A verdict at ``margin`` from the bounds with the censored pairs on time and as late: the
    same verdict from both, else inconclusive."""
    said = []
    for lower, upper in (on_time, as_late):
        said.append(NON_INFERIOR if upper < margin else INFERIOR if lower > margin else INCONCLUSIVE)
    return said[0] if said[0] == said[1] else INCONCLUSIVE


def tail(
    policy: Sequence[float] | np.ndarray,
    always: Sequence[float] | np.ndarray,
    cap: float,
    late: float = LATE,
    margin: float = TAIL_MARGIN,
    alpha: float = ALPHA,
    min_pairs: int = MIN_PAIRS,
) -> TailVerdict:
    """The tail-risk estimand: pairs with ``policy_i > (1 + late) * always_i`` (times clipped to
    ``[1, cap]``), censored pairs (both at the cap) counted apart, exact bounds with the censored
    pairs on time and as late, and verdicts at ``margin`` and at each of :data:`TAIL_MARGINS`."""
    a, b = _pairs(policy, always)
    a, b = np.clip(a, 1.0, cap), np.clip(b, 1.0, cap)
    n = int(a.size)
    if n == 0:
        return TailVerdict(INCONCLUSIVE, 0, 0, math.nan, math.nan, late, margin, "no pairs")
    censored = int(np.sum((a >= cap) & (b >= cap)))
    k = int(np.sum(a > (1.0 + late) * b))
    on_time = clopper_pearson(k, n, alpha)
    as_late = clopper_pearson(k + censored, n, alpha)
    margins = tuple((m, provisional(_tail_verdict(on_time, as_late, m), n, min_pairs)) for m in TAIL_MARGINS)
    verdict = _tail_verdict(on_time, as_late, margin)
    reason = {
        NON_INFERIOR: "upper bound below the tail margin",
        INFERIOR: "lower bound above the tail margin",
    }.get(verdict, "the bounds straddle the tail margin, or the censored pairs decide it")
    return TailVerdict(
        provisional(verdict, n, min_pairs), k, n, on_time[0], on_time[1], late, margin, reason,
        censored, as_late[1], as_late[0], margins,
    )
