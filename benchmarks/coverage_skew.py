"""Coverage of the scoreboard's and the tables' methods at each table's measured skew.

    PYTHONPATH=. python benchmarks/coverage_skew.py                     # 4000 experiments per cell
    PYTHONPATH=. python benchmarks/coverage_skew.py --experiments 10000
    PYTHONPATH=. python benchmarks/coverage_skew.py --report reports/reference

The skew of each table is its per-trial values' coefficient of variation (cv = sd / mean): read from
the committed report's CSVs (``--report``: Table 2's queries per run, the stack-size table's
ratios; cells with at least 5 trials, the largest cv of the table), and for Table 3 the range the
full-length table on the authors' answers measures (cv 0.75 to 1.2, :data:`TABLE3_CVS`), whose
quick report has 2 trials a cell. For each table, cv and n (the trials the suites run) the script
simulates ``--experiments`` experiments with log-normal and with gamma values of that cv, and prints
how often each method's interval covers the truth:

* ``mean: log t`` (the delta-method interval of the mean on the log scale, used before) and ``mean:
  Cox`` (:func:`lagrseq.analysis.inference.positive_mean_interval`, used now): the 95% interval of
  a cell's mean;
* ``vs paper: Welch`` (the raw-scale difference with Welch-Satterthwaite df, used before) and ``vs
  paper: log ratio`` (:func:`lagrseq.analysis.inference.log_ratio` with Hsu's df, used now): the
  95% and 90% intervals that a cell's test reads, against a paper arm of 10 runs of the same skew
  given as mean ± s.e. (the paper's mean is 1.3 times lagrseq's, so the truth is not 0);
* ``reduction: log ratio``: a reduction's test (the ratio SEQ / LaGR of two arms of the cell's
  skew against the paper's ratio of two arms of 10 runs, given as two means ± s.e.), 95%.

Every method used now must cover at least 93% at nominal 95% (and at least 88% at nominal 90%) in
every cell; the last line says whether it does. A figure to print, not a test: the test suite holds
the Cox interval and the log-ratio test at cv 1.2 (tests/analysis/test_inference.py).
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lagrseq.analysis import inference

TABLE3_CVS = (0.75, 1.0, 1.2)
"""Table 3's skew on the authors' answers at full length (30 trials a cell)."""
PAPER_RUNS = 10
"""Runs behind each of the paper's values (Tables 2 and 3 say so; the appendix is assumed 10)."""
FLOOR_95, FLOOR_90 = 0.93, 0.88
MIN_TRIALS = 5

Draw = Callable[[np.random.Generator, float, int], np.ndarray]


def lognormal(rng: np.random.Generator, cv: float, n: int) -> np.ndarray:
    """Log-normal values with mean 1 and coefficient of variation ``cv``."""
    sigma = math.sqrt(math.log1p(cv * cv))
    return rng.lognormal(-sigma * sigma / 2.0, sigma, n)


def gamma(rng: np.random.Generator, cv: float, n: int) -> np.ndarray:
    """Gamma values with mean 1 and coefficient of variation ``cv``."""
    shape = 1.0 / (cv * cv)
    return rng.gamma(shape, 1.0 / shape, n)


def _measured(report: Path, name: str, mean: str, std: str, keep: Callable[[dict[str, str]], bool]) -> float | None:
    """The largest cv of a committed table's cells with at least :data:`MIN_TRIALS` trials."""
    path = report / "tables" / f"{name}.csv"
    if not path.is_file():
        return None
    cvs = [
        float(row[std]) / float(row[mean])
        for row in csv.DictReader(path.open(encoding="utf-8"))
        if keep(row) and row.get("n") and int(float(row["n"])) >= MIN_TRIALS and float(row[mean]) > 0
    ]
    return max(cvs) if cvs else None


def tables(report: Path) -> list[tuple[str, float, tuple[int, ...]]]:
    """(table, cv, trial counts) to simulate."""
    out: list[tuple[str, float, tuple[int, ...]]] = []
    table2 = _measured(report, "table2", "mean", "std", lambda row: True)
    if table2 is not None:
        out.append(("Table 2 (measured)", table2, (10,)))
    out += [("Table 3 (full length)", cv, (5, 10, 30)) for cv in TABLE3_CVS]
    stack = _measured(report, "appendix-stack-size", "ratio_mean", "ratio_std", lambda row: row.get("main") == "True")
    if stack is not None:
        out.append(("stack-size ratios (measured)", stack, (10,)))
    return out


def _covers(low: float, high: float, truth: float) -> bool:
    return bool(low <= truth <= high)


def _paper(values: np.ndarray) -> inference.Estimate:
    return inference.paper_estimate(float(values.mean()), float(values.std(ddof=1)) / math.sqrt(values.size), values.size)


def cell(draw: Draw, cv: float, n: int, experiments: int, seed: int) -> dict[str, float]:
    """The share of experiments in which each method covers the truth."""
    rng = np.random.default_rng(seed)
    hits = dict.fromkeys(("mean: log t", "mean: Cox", "vs paper: Welch 95%", "vs paper: log ratio 95%",
                          "vs paper: log ratio 90%", "reduction: log ratio 95%"), 0)
    for _ in range(experiments):
        x = draw(rng, cv, n)
        ours = inference.mean_estimate(x)
        shown = ours.log_interval(0.95)
        hits["mean: log t"] += _covers(shown.low, shown.high, 1.0)
        cox = inference.positive_mean_interval(x)
        hits["mean: Cox"] += _covers(cox.low, cox.high, 1.0)
        paper = _paper(1.3 * draw(rng, cv, PAPER_RUNS))
        welch = inference.contrast([ours, paper], [1.0, -1.0]).interval(0.95)
        hits["vs paper: Welch 95%"] += _covers(welch.low, welch.high, -0.3)
        d = inference.log_ratio(ours, paper)
        hits["vs paper: log ratio 95%"] += _covers(*d.interval(0.95), math.log(1 / 1.3))
        hits["vs paper: log ratio 90%"] += _covers(*d.interval(0.90), math.log(1 / 1.3))
        seq, lagr = inference.mean_estimate(0.5 * draw(rng, cv, n)), ours
        paper_ratio = inference.ratio_estimate(_paper(0.4 * draw(rng, cv, PAPER_RUNS)), _paper(draw(rng, cv, PAPER_RUNS)))
        r = inference.log_ratio(inference.ratio_estimate(seq, lagr), paper_ratio)
        hits["reduction: log ratio 95%"] += _covers(*r.interval(0.95), math.log(0.5 / 0.4))
    return {k: v / experiments for k, v in hits.items()}


USED = {"mean: Cox": FLOOR_95, "vs paper: log ratio 95%": FLOOR_95, "vs paper: log ratio 90%": FLOOR_90, "reduction: log ratio 95%": FLOOR_95}
"""The methods the scoreboard and the tables use now, with the coverage each must reach."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiments", type=int, default=4000, help="simulated experiments per cell (default 4000)")
    parser.add_argument("--report", type=Path, default=Path("reports/reference"), help="the committed report whose CSVs give the skew")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    header = None
    worst: dict[str, float] = {}
    for k, (table, cv, sizes) in enumerate(tables(args.report)):
        for n in sizes:
            for j, (name, draw) in enumerate((("log-normal", lognormal), ("gamma", gamma))):
                found = cell(draw, cv, n, args.experiments, args.seed + 1000 * k + 10 * n + j)
                if header is None:
                    header = ("table", "cv", "n", "values", *found)
                    print("| " + " | ".join(header) + " |")
                    print("|" + "|".join(" --- " for _ in header) + "|")
                print(f"| {table} | {cv:.3g} | {n} | {name} | " + " | ".join(f"{100 * v:.1f}%" for v in found.values()) + " |")
                for method in USED:
                    worst[method] = min(worst.get(method, 1.0), found[method])
    print()
    for method, floor in USED.items():
        verdict = "holds" if worst.get(method, 0.0) >= floor else "FAILS"
        print(f"{method} (used): lowest coverage {100 * worst.get(method, math.nan):.1f}% against a floor of {100 * floor:.0f}%: {verdict}")


if __name__ == "__main__":
    main()
