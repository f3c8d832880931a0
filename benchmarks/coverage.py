"""Simulated coverage of every interval kind the report uses, at the trial counts the suite runs.

    PYTHONPATH=. python benchmarks/coverage.py                    # n = 2, 3, 5, 10; 4000 experiments each
    PYTHONPATH=. python benchmarks/coverage.py --n 2,5 --experiments 20000
    PYTHONPATH=. python benchmarks/coverage.py --paired --n 3,10,20   # the frontier's paired bound

For each n (trials per arm), draws ``--experiments`` simulated experiments and prints how often each
nominal 95% interval covers the true value. The kinds (:mod:`lagrseq.analysis.inference`), each
where the scoreboard and the tables use it:

* ``log t, counts``: the t interval of a mean on the log scale (:meth:`Estimate.log_interval`), for
  queries per run and the performance ratios: lognormal values with a coefficient of variation of
  0.5 (skewed, like queries on a recorded store) and, beside it, normal values (cv 0.1, like Table 2).
* ``reduction``: the query reduction 1 - mean(SEQ) / mean(LaGR), the ratio's delta-method interval
  on the log scale turned around (:func:`ratio_estimate`): two lognormal arms (means 100 and 200).
* ``Welch vs paper``: the interval of lagrseq's mean minus the paper's that the TOST reads: n of
  lagrseq's trials against a paper sample of 10 runs reported as mean ± s.e. (:func:`tost`,
  :func:`contrast`), normal data with unequal spreads (sd 3 and 6); at 95% and, for the TOST, 90%.
* ``slope``: a trend row's least-squares slope over three groups (tau 0, 0.5, 1 or 5, 8, 11
  cubes) with Welch-Satterthwaite degrees of freedom (:func:`contrast`, :func:`slope_weights`),
  normal data with spreads 2, 3 and 8 (Table 2's are that uneven).
* ``t`` (the audits) and the percentile bootstrap (:func:`lagrseq.analysis.stats.bootstrap_ci`,
  2000 resamples; used before, shown for comparison) on normal data.

A figure to print, not a test: the test suite holds the t interval to >= 93% at n = 5 and the
log-scale interval to >= 92% at n = 5 and 10 (tests/analysis/test_inference.py).

``--paired`` prints instead the one-sided coverage of the frontier's paired non-inferiority bound
(:func:`inference.paired_noninferiority`, nominal 95%): how often the bound on a policy's slowdown
against always lies above the true mean slowdown, at each n, for per-pair differences that are
normal and for differences shaped like the measured ones (steps to the first solve: most pairs
differ by exactly 0, a few by tens of steps, so the differences are zero-inflated and right-skewed).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from lagrseq.analysis import inference, stats

KINDS = ("t", "log t, normal", "log t, skewed", "reduction", "Welch vs paper", "(90%, TOST)", "slope", "bootstrap (before)")
SKEW_SIGMA = math.sqrt(math.log(1 + 0.5**2))
"""The lognormal sigma of a coefficient of variation of 0.5."""


def _covers(iv: inference.Interval, true: float) -> bool:
    return bool(iv.low <= true <= iv.high)


def coverage(n: int, experiments: int, seed: int) -> dict[str, float]:
    """The share of ``experiments`` in which each kind's nominal 95% interval covers the truth."""
    rng = np.random.default_rng(seed + n)
    hits = dict.fromkeys(KINDS, 0)
    skew_mean = math.exp(SKEW_SIGMA**2 / 2)
    weights = inference.slope_weights([0.0, 0.5, 1.0])
    true_slope = sum(w * m for w, m in zip(weights, (126.0, 133.0, 140.0), strict=True))
    boot = np.random.default_rng(seed + 1000 + n)
    for _ in range(experiments):
        normal = rng.normal(10.0, 3.0, n)
        hits["t"] += _covers(inference.t_interval(normal, 0.95), 10.0)
        hits["log t, normal"] += _covers(inference.mean_estimate(rng.normal(100.0, 10.0, n)).log_interval(0.95), 100.0)
        hits["log t, skewed"] += _covers(inference.mean_estimate(100.0 * rng.lognormal(0.0, SKEW_SIGMA, n)).log_interval(0.95), 100.0 * skew_mean)
        seq = inference.mean_estimate(100.0 * rng.lognormal(0.0, SKEW_SIGMA, n))
        lagr = inference.mean_estimate(200.0 * rng.lognormal(0.0, SKEW_SIGMA, n))
        hits["reduction"] += _covers(inference.ratio_estimate(seq, lagr).log_interval(0.95), 0.5)
        ours = inference.mean_estimate(rng.normal(100.0, 3.0, n))
        paper_runs = rng.normal(95.0, 6.0, 10)
        paper = inference.paper_estimate(float(paper_runs.mean()), float(paper_runs.std(ddof=1)) / math.sqrt(10), 10)
        difference = inference.contrast([ours, paper], [1.0, -1.0])
        hits["Welch vs paper"] += _covers(difference.interval(0.95), 5.0)
        hits["(90%, TOST)"] += _covers(difference.interval(0.90), 5.0)
        groups = [inference.mean_estimate(rng.normal(m, sd, n)) for m, sd in ((126.0, 2.0), (133.0, 3.0), (140.0, 8.0))]
        hits["slope"] += _covers(inference.contrast(groups, weights).interval(0.95), true_slope)
        if n >= 2:
            low, high = stats.bootstrap_ci(normal, boot, resamples=2000)
            hits["bootstrap (before)"] += low <= 10.0 <= high
    return {k: v / experiments for k, v in hits.items()}


def paired_coverage(n: int, experiments: int, seed: int) -> tuple[float, float]:
    """One-sided coverage of the paired bound on the slowdown (lower is better: the bound is an
    upper bound of mean(policy - always)): normal differences (mean 2, sd 5) and zero-inflated ones
    (70% exactly 0, else exponential with mean 10: true mean 3). Each pair also shares a trial
    effect (sd 50) that the paired test must cancel."""
    rng = np.random.default_rng(seed + 7 * n)
    hits = [0, 0]
    for _ in range(experiments):
        trial = rng.normal(40.0, 50.0, n)
        normal = rng.normal(2.0, 5.0, n)
        skewed = np.where(rng.random(n) < 0.7, 0.0, rng.exponential(10.0, n))
        for k, (d, true) in enumerate(((normal, 2.0), (skewed, 3.0))):
            result = inference.paired_noninferiority(trial + d, trial, 1.0, higher_is_better=False)
            hits[k] += -result.bound >= true  # the bound on the slowdown lies above the truth
    return hits[0] / experiments, hits[1] / experiments


def _sizes(spec: str, why: str) -> list[int]:
    """The sample sizes of ``--n`` (comma-separated), each at least 2."""
    sizes = [int(text) for text in spec.split(",")]
    for n in sizes:
        if n < 2:
            raise SystemExit(f"--n {n}: {why}")
    return sizes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", default="2,3,5,10", help="trial counts, comma-separated (default 2,3,5,10)")
    parser.add_argument("--experiments", type=int, default=4000, help="simulated experiments per n (default 4000)")
    parser.add_argument("--seed", type=int, default=20231, help="generator seed (default 20231)")
    parser.add_argument("--paired", action="store_true", help="the frontier's paired one-sided bound instead")
    args = parser.parse_args()
    if args.paired:
        print(f"one-sided nominal 95% paired bound on the slowdown, {args.experiments} simulated experiments per n")
        print(f"{'n':>4}  {'normal differences':>18}  {'zero-inflated, skewed':>21}")
        for n in _sizes(args.n, "a bound needs at least 2 pairs"):
            normal, skewed = paired_coverage(n, args.experiments, args.seed)
            print(f"{n:>4}  {normal:>18.1%}  {skewed:>21.1%}")
        return
    print(f"coverage of nominal 95% intervals (90% where marked), {args.experiments} simulated experiments per n")
    widths = [max(len(k), 6) for k in KINDS]
    print(f"{'n':>4}  " + "  ".join(f"{k:>{w}}" for k, w in zip(KINDS, widths, strict=True)))
    for n in _sizes(args.n, "an interval needs at least 2 trials"):
        found = coverage(n, args.experiments, args.seed)
        print(f"{n:>4}  " + "  ".join(f"{found[k]:>{w}.1%}" for k, w in zip(KINDS, widths, strict=True)))


if __name__ == "__main__":
    main()
