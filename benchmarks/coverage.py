"""Simulated coverage of every interval kind the report uses, at the trial counts the suite runs.

    PYTHONPATH=. python benchmarks/coverage.py                    # n = 2, 3, 5, 10; 4000 experiments each
    PYTHONPATH=. python benchmarks/coverage.py --n 2,5 --experiments 20000
    PYTHONPATH=. python benchmarks/coverage.py --paired --experiments 2000   # the frontier's bounds at the margin

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

``--paired`` prints instead the frontier's false non-inferior rate with the truth at the margin:
for each n (default 10, 30, 100, 300: :data:`lagrseq.analysis.paired.MIN_PAIRS` and the sizes the
suite and a decisive run use) and each law of a family of zero-inflated, right-skewed laws of the
per-pair log ratio (:func:`family`: late share 0.02-0.3, tie share among the others 0-0.95, late
sizes from log 1.5 up to log cap, the remaining pairs at the value that puts the mean exactly at
``log(1.1)``), the share of experiments in which the betting upper bound of
:func:`lagrseq.analysis.paired.upper_bounds` lies below the margin (a false "non-inferior"), its
worst case over the family per n, and the same for the tail's exact bound with the true late
share at the tail margin. The argument (docs/frontier.md) says neither exceeds 5% at any n.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

import numpy as np

from lagrseq.analysis import inference, paired, stats

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


CAP = 5001.0
"""The step cap of the simulated pairs (the object arrangement's trial length): log ratios lie in
``[-log CAP, log CAP]``."""
LATE_SHARES = (0.02, 0.05, 0.10, 0.20, 0.30)
TIE_SHARES = (0.0, 0.5, 0.8, 0.95)
LATE_SIZES = (math.log(1.5), math.log(10.0), math.log(100.0), math.log(CAP))


@dataclass(frozen=True)
class Law:
    """A three-point law of the per-pair log ratio with its mean at ``mean``: a share ``late`` of
    pairs at ``size``, a share ``ties`` of the others at 0, the rest at ``rest``."""

    late: float
    ties: float
    size: float
    rest: float

    def draw(self, rng: np.random.Generator, experiments: int, n: int) -> np.ndarray:
        u = rng.random((experiments, n))
        tie = rng.random((experiments, n)) < self.ties
        return np.where(u < self.late, self.size, np.where(tie, 0.0, self.rest))


def family(mean: float, span: float) -> list[Law]:
    """Every law of the grid whose remaining pairs can carry the rest of ``mean`` inside the range."""
    laws = []
    for late in LATE_SHARES:
        for ties in TIE_SHARES:
            for size in LATE_SIZES:
                others = (1.0 - late) * (1.0 - ties)
                rest = (mean - late * size) / others
                if abs(rest) <= span:
                    laws.append(Law(late, ties, size, rest))
    return laws


def false_non_inferior(n: int, experiments: int, seed: int) -> list[tuple[Law, float]]:
    """Per law of the family with its mean at the margin log(1.1): the share of ``experiments``
    in which the betting upper bound falls below the margin."""
    span, margin = math.log(CAP), math.log1p(0.10)
    rows = []
    for k, law in enumerate(family(margin, span)):
        x = law.draw(np.random.default_rng(seed + 7919 * n + k), experiments, n)
        rows.append((law, float(np.mean(paired.upper_bounds(x, span) < margin))))
    return rows


def tail_false_non_inferior(n: int) -> float:
    """P(the exact upper bound of the late share < the tail margin) when the true share is the
    margin: exact, from the binomial law."""
    from scipy.stats import binom

    k = np.arange(n + 1)
    uppers = np.array([paired.clopper_pearson(int(i), n)[1] for i in k])
    return float(binom.pmf(k, n, paired.TAIL_MARGIN)[uppers < paired.TAIL_MARGIN].sum())


def print_paired(sizes: list[int], experiments: int, seed: int) -> None:
    margin = math.log1p(0.10)
    laws = family(margin, math.log(CAP))
    print(
        f"false non-inferior at the margin (true mean log ratio = log 1.1), one-sided level {paired.ALPHA:.0%}, "
        f"cap {CAP:.0f} steps, {len(laws)} laws (late share {LATE_SHARES[0]}-{LATE_SHARES[-1]}, tie share "
        f"{TIE_SHARES[0]}-{TIE_SHARES[-1]}, late sizes log 1.5 to log cap), {experiments} experiments per law and n"
    )
    print(f"{'n':>5}  {'worst P(false NI)':>17}  {'median':>7}  {'tail at 10%':>11}  worst law")
    for n in sizes:
        rows = false_non_inferior(n, experiments, seed)
        worst_law, worst = max(rows, key=lambda r: r[1])
        median = float(np.median([r for _, r in rows]))
        law = (
            f"late {worst_law.late:.2f} at x{math.exp(worst_law.size):.4g}, ties {worst_law.ties:.2f}, "
            f"rest {worst_law.rest:+.3f}"
        )
        mark = "" if n >= paired.MIN_PAIRS else "  (provisional: below MIN_PAIRS)"
        print(f"{n:>5}  {worst:>17.2%}  {median:>7.2%}  {tail_false_non_inferior(n):>11.2%}  {law}{mark}")
    print(f"MIN_PAIRS = {paired.MIN_PAIRS}: below it the frontier marks every verdict provisional")


def _sizes(spec: str, why: str) -> list[int]:
    """The sample sizes of ``--n`` (comma-separated), each at least 2."""
    sizes = [int(text) for text in spec.split(",")]
    for n in sizes:
        if n < 2:
            raise SystemExit(f"--n {n}: {why}")
    return sizes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", default=None, help="trial counts, comma-separated (default 2,3,5,10; with --paired 10,30,100,300)")
    parser.add_argument("--experiments", type=int, default=4000, help="simulated experiments per n (default 4000)")
    parser.add_argument("--seed", type=int, default=20231, help="generator seed (default 20231)")
    parser.add_argument("--paired", action="store_true", help="the frontier's paired one-sided bounds instead")
    args = parser.parse_args()
    args.n_given = args.n is not None
    args.n = args.n or "2,3,5,10"
    if args.paired:
        print_paired(_sizes(args.n if args.n_given else "10,30,100,300", "a bound needs at least 2 pairs"), args.experiments, args.seed)
        return
    print(f"coverage of nominal 95% intervals (90% where marked), {args.experiments} simulated experiments per n")
    widths = [max(len(k), 6) for k in KINDS]
    print(f"{'n':>4}  " + "  ".join(f"{k:>{w}}" for k, w in zip(KINDS, widths, strict=True)))
    for n in _sizes(args.n, "an interval needs at least 2 trials"):
        found = coverage(n, args.experiments, args.seed)
        print(f"{n:>4}  " + "  ".join(f"{found[k]:>{w}.1%}" for k, w in zip(KINDS, widths, strict=True)))


if __name__ == "__main__":
    main()
