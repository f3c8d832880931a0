"""Statistics as pure functions over per-trial values.

The paper reports mean +- standard error for query counts and ratios, and mean +- one standard
deviation bands for learning curves. Both use the sample standard deviation (``ddof=1``).
Confidence intervals are percentile bootstraps of the mean drawn from a generator the caller
passes in; :func:`generator` makes one from a fixed seed and the statistic's name, so a table's
numbers do not depend on which other statistics were computed before it.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from lagrseq.analysis.interval import CONFIDENCE, Interval

BOOTSTRAP_SEED = 20230821
"""Seed of every bootstrap (the date of the authors' released code)."""
RESAMPLES = 10_000


def generator(key: str, seed: int = BOOTSTRAP_SEED) -> np.random.Generator:
    """The bootstrap generator of one statistic, fixed by ``seed`` and the statistic's ``key``."""
    sequence = np.random.SeedSequence(seed, spawn_key=(zlib.crc32(key.encode()),))
    return np.random.Generator(np.random.PCG64(sequence))


def mean_std_se(values: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """Mean, sample standard deviation and standard error of the mean."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(x.mean())
    if x.size < 2:
        return mean, math.nan, math.nan
    std = float(x.std(ddof=1))
    return mean, std, std / math.sqrt(x.size)


def bootstrap_ci(
    values: Sequence[float] | np.ndarray,
    rng: np.random.Generator,
    resamples: int = RESAMPLES,
    confidence: float = CONFIDENCE,
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean: ``resamples`` resamples of the trials with
    replacement, drawn from ``rng``."""
    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return math.nan, math.nan
    means = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    low, high = percentile_interval(means, confidence)
    return float(low), float(high)


def percentile_interval(draws: np.ndarray, confidence: float = CONFIDENCE, axis: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The central ``confidence`` percentile interval of bootstrap ``draws`` (along ``axis``:
    one bound per point of a curve): the ``(1 - confidence) / 2`` quantile and its mirror."""
    tail = (1.0 - confidence) / 2.0
    low, high = np.quantile(draws, [tail, 1.0 - tail], axis=axis)
    return low, high


def summarize_t(values: Sequence[float] | np.ndarray, confidence: float = CONFIDENCE, positive: bool = False) -> Interval:
    """Mean, spread and Student's t interval of per-trial values: the interval every table of a
    mean reports (it keeps its nominal coverage at the 2 to 10 trials of a reproduction, where the
    percentile bootstrap under-covers; :mod:`lagrseq.analysis.inference`). ``positive``: the
    values are counts or ratios (never below 0) and the interval is taken on the log scale
    (:meth:`lagrseq.analysis.inference.Estimate.log_interval`), so it never leaves (0, inf)."""
    from lagrseq.analysis.inference import mean_estimate, t_interval

    x = np.asarray(values, dtype=float)
    mean, std, se = mean_std_se(x)
    interval = mean_estimate(x).log_interval(confidence) if positive else t_interval(x, confidence)
    return Interval(int(x.size), mean, interval.low, interval.high, confidence, std, se)


@dataclass(frozen=True)
class CurveStats:
    """A curve over trials: one value per point. ``n`` counts the trials with a value there."""

    x: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    se: np.ndarray
    n: np.ndarray


def curve(x: np.ndarray, matrix: np.ndarray) -> CurveStats:
    """Pointwise mean, sample standard deviation and standard error of ``matrix`` (trials x
    points); NaN marks a trial without a value at a point (a shorter trial)."""
    values = np.asarray(matrix, dtype=float)
    if values.ndim != 2 or values.shape[1] != len(x):
        raise ValueError(f"matrix of shape {values.shape} does not fit {len(x)} points")
    present = ~np.isnan(values)
    n = present.sum(axis=0)
    total = np.where(present, values, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
        squares = np.where(present, (values - mean) ** 2, 0.0).sum(axis=0)
        std = np.where(n > 1, np.sqrt(squares / np.maximum(n - 1, 1)), np.nan)
        se = np.where(n > 1, std / np.sqrt(np.maximum(n, 1)), np.nan)
    return CurveStats(np.asarray(x), mean, std, se, n)


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last ``window`` values at each position (fewer at the start)."""
    x = np.asarray(values, dtype=float)
    if window <= 1 or x.size == 0:
        return x.copy()
    sums = np.cumsum(np.concatenate([[0.0], x]))
    ends = np.arange(1, x.size + 1)
    starts = np.maximum(ends - window, 0)
    return (sums[ends] - sums[starts]) / (ends - starts)


BEFORE_FIRST_EPISODE = 0.0
"""What a trial contributes to a return-vs-steps curve before it has finished an episode: 0, the
return of the episodes it has finished (none). Every point then averages every trial of the run;
dropping the trials without a finished episode would average only those that already succeeded."""


def step_curve(
    end_steps: np.ndarray,
    returns: np.ndarray,
    grid: np.ndarray,
    window: int,
    before: float = BEFORE_FIRST_EPISODE,
) -> np.ndarray:
    """Return vs environment steps, as the released grid code logs it: at each step of ``grid``,
    the mean of the last ``window`` episode returns finished by then; ``before`` (default
    :data:`BEFORE_FIRST_EPISODE`) until the first episode ends. ``end_steps`` are the trial's step
    counts at each episode end, in order; give only finished episodes (an episode cut short by the
    trial's step budget is not one: counted as a whole it would pull the last point down)."""
    ends = np.asarray(end_steps, dtype=float)
    averaged = moving_average(np.asarray(returns, dtype=float), window)
    finished = np.searchsorted(ends, np.asarray(grid, dtype=float), side="right")
    out = np.full(len(grid), float(before))
    has = finished > 0
    out[has] = averaged[finished[has] - 1]
    return out


def finished_episodes(
    global_steps: np.ndarray,
    solved: np.ndarray,
    max_steps: int,
    lengths: np.ndarray | None = None,
    horizon: int | None = None,
) -> np.ndarray:
    """Which episodes of one trial (in order) finished on their own: all but a last episode that
    the trial's step budget ``max_steps`` (0: none) cut off, i.e. one that ends at the budget
    unsolved and, where the episode ``horizon`` and the episodes' ``lengths`` are known, shorter
    than the horizon (one that reached its horizon exactly at the budget ended on its own)."""
    steps = np.asarray(global_steps, dtype=float)
    keep = np.ones(steps.size, dtype=bool)
    if not (max_steps > 0 and steps.size and steps[-1] >= max_steps and not bool(np.asarray(solved)[-1])):
        return keep
    if horizon is not None and lengths is not None and int(np.asarray(lengths)[-1]) >= horizon:
        return keep
    keep[-1] = False
    return keep


def paired_ratios(numerator: Mapping[int, float], denominator: Mapping[int, float]) -> np.ndarray:
    """Per-trial ratios numerator / denominator over the trial indices both have, in trial order
    (trial k of two runs with one seed share their environment seed). A trial whose denominator
    is 0 (a baseline that earned no return, e.g. one short episode) has no ratio and is left
    out, so the ``n`` a table shows counts only the ratios that exist."""
    trials = sorted(set(numerator) & set(denominator))
    return np.array([numerator[t] / denominator[t] for t in trials if denominator[t] != 0], dtype=float)


# --------------------------------------------------------------------------------------------
# rliable's statistics (Agarwal et al., 2021) in numpy: interquartile mean, stratified bootstrap,
# probability of improvement, performance profiles. A *stratum* is one task (or one setting):
# the per-trial scores of one policy there. Bootstraps resample trials within each stratum.
# --------------------------------------------------------------------------------------------
Strata = Sequence[Sequence[float] | np.ndarray]


def _strata(strata: Strata) -> list[np.ndarray]:
    out = [np.asarray(s, dtype=float).ravel() for s in strata]
    if not out or any(s.size == 0 for s in out):
        raise ValueError("every stratum needs at least one score")
    return out


def iqm(values: Sequence[float] | np.ndarray) -> float:
    """Interquartile mean: the mean of the scores left after cutting ``floor(n / 4)`` from each
    end of the sorted scores (``scipy.stats.trim_mean(x, 0.25)``, as rliable computes it)."""
    x = np.sort(np.asarray(values, dtype=float).ravel())
    if x.size == 0:
        return math.nan
    cut = int(0.25 * x.size)
    return float(x[cut : x.size - cut].mean())


def stratified_bootstrap_ci(
    strata: Strata,
    statistic: Callable[[list[np.ndarray]], float],
    rng: np.random.Generator,
    resamples: int = RESAMPLES,
    confidence: float = CONFIDENCE,
) -> tuple[float, float]:
    """Percentile interval of ``statistic(strata)`` over ``resamples`` stratified bootstrap
    resamples: each stratum's scores are drawn with replacement within that stratum. NaN when
    every stratum has fewer than 2 scores (there is nothing to resample)."""
    groups = _strata(strata)
    if all(g.size < 2 for g in groups):
        return math.nan, math.nan
    picks = [rng.integers(0, g.size, size=(resamples, g.size)) for g in groups]
    values = np.array([statistic([g[p[i]] for g, p in zip(groups, picks, strict=True)]) for i in range(resamples)])
    low, high = percentile_interval(values, confidence)
    return float(low), float(high)


def iqm_ci(
    strata: Strata, rng: np.random.Generator, resamples: int = RESAMPLES, confidence: float = CONFIDENCE
) -> tuple[float, float, float]:
    """IQM of every score of every stratum, with its stratified bootstrap interval."""
    groups = _strata(strata)
    value = iqm(np.concatenate(groups))
    if all(g.size < 2 for g in groups):
        return value, math.nan, math.nan
    # vectorised: every resample at once, sorted per row, the middle half averaged
    drawn = np.sort(np.concatenate([g[rng.integers(0, g.size, size=(resamples, g.size))] for g in groups], axis=1), axis=1)
    cut = int(0.25 * drawn.shape[1])
    values = drawn[:, cut : drawn.shape[1] - cut].mean(axis=1)
    low, high = percentile_interval(values, confidence)
    return value, float(low), float(high)


def _improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 over every pair of a score of X and a score of Y (the
    Mann-Whitney U statistic divided by the number of pairs)."""
    greater = (x[:, None] > y[None, :]).sum()
    ties = (x[:, None] == y[None, :]).sum()
    return float((greater + 0.5 * ties) / (x.size * y.size))


def probability_of_improvement(x: Strata, y: Strata) -> float:
    """P(X > Y): the chance that a trial of X scores above a trial of Y in the same stratum
    (ties count half), averaged over the strata."""
    xs, ys = _strata(x), _strata(y)
    if len(xs) != len(ys):
        raise ValueError(f"{len(xs)} strata against {len(ys)}")
    return float(np.mean([_improvement(a, b) for a, b in zip(xs, ys, strict=True)]))


def probability_of_improvement_ci(
    x: Strata, y: Strata, rng: np.random.Generator, resamples: int = RESAMPLES, confidence: float = CONFIDENCE
) -> tuple[float, float, float]:
    """P(X > Y) with a stratified bootstrap interval (X and Y resampled independently)."""
    xs, ys = _strata(x), _strata(y)
    value = probability_of_improvement(xs, ys)
    if len(xs) != len(ys) or all(g.size < 2 for g in [*xs, *ys]):
        return value, math.nan, math.nan
    # vectorised per stratum: (resamples, n) against (resamples, m)
    total = np.zeros(resamples)
    for a, b in zip(xs, ys, strict=True):
        ra = a[rng.integers(0, a.size, size=(resamples, a.size))]
        rb = b[rng.integers(0, b.size, size=(resamples, b.size))]
        greater = (ra[:, :, None] > rb[:, None, :]).sum(axis=(1, 2))
        ties = (ra[:, :, None] == rb[:, None, :]).sum(axis=(1, 2))
        total += (greater + 0.5 * ties) / (a.size * b.size)
    values = total / len(xs)
    low, high = percentile_interval(values, confidence)
    return value, float(low), float(high)


def performance_profile(scores: Sequence[float] | np.ndarray, thresholds: Sequence[float] | np.ndarray) -> np.ndarray:
    """The fraction of scores above each threshold tau (rliable's run-score distribution)."""
    x = np.asarray(scores, dtype=float).ravel()
    taus = np.asarray(thresholds, dtype=float)
    if x.size == 0:
        return np.full(taus.shape, math.nan)
    return (x[None, :] > taus[:, None]).mean(axis=1)


def performance_profile_ci(
    strata: Strata,
    thresholds: Sequence[float] | np.ndarray,
    rng: np.random.Generator,
    resamples: int = 2000,
    confidence: float = CONFIDENCE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The performance profile of every score of every stratum, with pointwise stratified
    bootstrap intervals: (profile, low, high), one value per threshold."""
    groups = _strata(strata)
    taus = np.asarray(thresholds, dtype=float)
    profile = performance_profile(np.concatenate(groups), taus)
    if all(g.size < 2 for g in groups):
        nan = np.full(taus.shape, math.nan)
        return profile, nan, nan
    picks = [rng.integers(0, g.size, size=(resamples, g.size)) for g in groups]
    curves = np.array(
        [performance_profile(np.concatenate([g[p[i]] for g, p in zip(groups, picks, strict=True)]), taus) for i in range(resamples)]
    )
    low, high = percentile_interval(curves, confidence, axis=0)
    return profile, low, high
