"""Simulated coverage of the intervals the report uses, at the trial counts the suite runs.

    PYTHONPATH=. python benchmarks/coverage.py                    # n = 2, 3, 5, 10; 4000 experiments each
    PYTHONPATH=. python benchmarks/coverage.py --n 2,5 --experiments 20000

For each n, draws ``--experiments`` samples of n normal values (mean 10, sd 3) and prints how often
the nominal 95% interval of the mean covers the true mean: Student's t interval (what every table
of a mean and every verdict uses, :func:`lagrseq.analysis.inference.t_interval`), the delta-method
interval of a ratio of two means (the query reduction, :func:`inference.ratio_interval`, two arms of
n values with means 100 and 200 and a 10% coefficient of variation), and, for comparison, the
percentile bootstrap (:func:`lagrseq.analysis.stats.bootstrap_ci`, 2000 resamples) that the tables
used before. A figure to print, not a test: the test suite holds the t interval to >= 93% at n = 5
(tests/analysis/test_inference.py).
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", default="2,3,5,10", help="trial counts, comma-separated (default 2,3,5,10)")
    parser.add_argument("--experiments", type=int, default=4000, help="simulated experiments per n (default 4000)")
    parser.add_argument("--seed", type=int, default=20231, help="generator seed (default 20231)")
    args = parser.parse_args()
    print(f"nominal 95% intervals, {args.experiments} simulated experiments per n (normal data)")
    print(f"{'n':>4}  {'t interval':>10}  {'ratio (delta, t)':>16}  {'percentile bootstrap':>20}")
    for text in args.n.split(","):
        n = int(text)
        if n < 2:
            raise SystemExit(f"--n {text}: an interval needs at least 2 trials")
        t, ratio, boot = coverage(n, args.experiments, args.seed)
        print(f"{n:>4}  {t:>10.1%}  {ratio:>16.1%}  {boot:>20.1%}")


if __name__ == "__main__":
    main()
