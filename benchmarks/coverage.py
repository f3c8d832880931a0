"""Simulated coverage of the intervals the report uses, at the trial counts the suite runs.

    PYTHONPATH=. python benchmarks/coverage.py                    # n = 2, 3, 5, 10; 4000 experiments each
    PYTHONPATH=. python benchmarks/coverage.py --n 2,5 --experiments 20000
    PYTHONPATH=. python benchmarks/coverage.py --paired --n 3,10,20   # the frontier's paired bound

For each n, draws ``--experiments`` samples of n normal values (mean 10, sd 3) and prints how often
the nominal 95% interval of the mean covers the true mean: Student's t interval (what every table
of a mean and every verdict uses, :func:`lagrseq.analysis.inference.t_interval`), the delta-method
interval of a ratio of two means (the query reduction, :func:`inference.ratio_interval`, two arms of
n values with means 100 and 200 and a 10% coefficient of variation), and, for comparison, the
percentile bootstrap (:func:`lagrseq.analysis.stats.bootstrap_ci`, 2000 resamples) that the tables
used before. A figure to print, not a test: the test suite holds the t interval to >= 93% at n = 5
(tests/analysis/test_inference.py).

``--paired`` prints instead the one-sided coverage of the frontier's paired non-inferiority bound
(:func:`inference.paired_noninferiority`, nominal 95%): how often the bound on a policy's slowdown
against always lies above the true mean slowdown, at each n, for per-pair differences that are
normal and for differences shaped like the measured ones (steps to the first solve: most pairs
differ by exactly 0, a few by tens of steps, so the differences are zero-inflated and right-skewed).
"""

from __future__ import annotations

import argparse

import numpy as np

from lagrseq.analysis import inference, stats


def coverage(n: int, experiments: int, seed: int) -> tuple[float, float, float]:
    rng = np.random.default_rng(seed + n)
    samples = rng.normal(10.0, 3.0, size=(experiments, n))
    t_hits = sum(iv.low <= 10.0 <= iv.high for iv in (inference.t_interval(row, 0.95) for row in samples))
    boot = np.random.default_rng(seed + 1000 + n)
    boot_hits = 0
    if n >= 2:
        boot_hits = sum(lo <= 10.0 <= hi for lo, hi in (stats.bootstrap_ci(row, boot, resamples=2000) for row in samples))
    a = rng.normal(100.0, 10.0, size=(experiments, n))
    b = rng.normal(200.0, 20.0, size=(experiments, n))
    ratio_hits = sum(iv.low <= 0.5 <= iv.high for iv in (inference.ratio_interval(x, y, 0.95) for x, y in zip(a, b, strict=True)))
    return t_hits / experiments, ratio_hits / experiments, boot_hits / experiments


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
    print(f"nominal 95% intervals, {args.experiments} simulated experiments per n (normal data)")
    print(f"{'n':>4}  {'t interval':>10}  {'ratio (delta, t)':>16}  {'percentile bootstrap':>20}")
    for n in _sizes(args.n, "an interval needs at least 2 trials"):
        t, ratio, boot = coverage(n, args.experiments, args.seed)
        print(f"{n:>4}  {t:>10.1%}  {ratio:>16.1%}  {boot:>20.1%}")


if __name__ == "__main__":
    main()
