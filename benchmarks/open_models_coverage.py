"""Simulated coverage of the open-model screens' interval over prompts, at the sizes the screens use.

    PYTHONPATH=. python benchmarks/open_models_coverage.py                       # 1000 screens per case
    PYTHONPATH=. python benchmarks/open_models_coverage.py --experiments 4000 --resamples 2000

:func:`lagrseq.study.screen.accuracy_over_prompts` gives a screen of distinct prompts a cluster
bootstrap interval (prompts resampled, percentile), widened to the exact interval where that is
wider (Clopper-Pearson with one answer per prompt, else at the clustered sample's effective size,
Korn and Graubard), and the exact interval over prompts when every prompt is all right or all
wrong. This prints how often its nominal 95% interval covers the true
share of right answers over the population of prompts, for

- one answer per prompt (the new prompt sets at tau = 0): m prompts, each right with probability p;
- 10 answers per prompt (tau > 0): each prompt's P(right) drawn from a Beta with mean p and
  intra-prompt correlation 0.5 (answers to one prompt are alike), answers binomial given it;

and, beside it, the coverage of a Wilson interval over all answers as if they were independent
(what the page used before), which under-covers once answers cluster. A figure to print, not a
test.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lagrseq.study import screen


def one_case(m: int, answers: int, p: float, rho: float, experiments: int, resamples: int, seed: int) -> tuple[float, float, float]:
    """(coverage of the interval over prompts, coverage of Wilson over answers, mean width)."""
    rng = np.random.default_rng([seed, m, answers, int(p * 1000)])
    hits = wilson_hits = 0
    widths = []
    for e in range(experiments):
        if rho > 0:
            a, b = p * (1 - rho) / rho, (1 - p) * (1 - rho) / rho
            rates = rng.beta(a, b, size=m)
        else:
            rates = np.full(m, p)
        right = rng.binomial(answers, rates)
        s = screen.Screen("cube-stacking", f"sim{e}", 0.0, 8, "relabelled 8-cube sets")
        for i, k in enumerate(right):
            s.prompts[f"p{i}"] = (answers, int(k))
            s.prompt_bins[f"p{i}"] = 1 + i % 7
        acc = screen.accuracy_over_prompts(s, resamples=resamples)
        assert acc.low is not None and acc.high is not None
        hits += acc.low <= p <= acc.high
        widths.append(acc.high - acc.low)
        low, high = screen.wilson(int(right.sum()), m * answers)
        wilson_hits += low <= p <= high
    return hits / experiments, wilson_hits / experiments, float(np.mean(widths))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--experiments", type=int, default=1000)
    parser.add_argument("--resamples", type=int, default=1000, help="bootstrap resamples per interval (the report uses 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--clustered-only", action="store_true", help="only the rows of 10 answers per prompt")
    args = parser.parse_args()
    print(f"nominal 95%; {args.experiments} simulated screens per row, {args.resamples} bootstrap resamples each")
    print(f"{'prompts':>7} {'answers/prompt':>14} {'p':>5} {'clustering':>10} {'over prompts':>12} {'Wilson/answers':>14} {'mean width':>10} {'s':>5}")
    cases = ((8, 10, 0.5), (50, 10, 0.5)) if args.clustered_only else ((50, 1, 0.0), (60, 1, 0.0), (8, 10, 0.5), (50, 10, 0.5))
    for m, answers, rho in cases:
        for p in (0.02, 0.1, 0.3):
            started = time.perf_counter()
            cover, wilson_cover, width = one_case(m, answers, p, rho, args.experiments, args.resamples, args.seed)
            print(f"{m:>7} {answers:>14} {p:>5.2f} {rho:>10.1f} {cover:>12.3f} {wilson_cover:>14.3f} {width:>10.3f} {time.perf_counter() - started:>5.1f}")


if __name__ == "__main__":
    main()
