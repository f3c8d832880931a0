"""Pairs each frontier estimand needs for 80% power, by simulation of the frontier's own bounds.

    PYTHONPATH=. python benchmarks/power.py                       # laws of ties and late pairs
    PYTHONPATH=. python benchmarks/power.py --logs fr             # every asking point of a frontier's logs

* **mean log ratio, show non-inferior**: the smallest n (on a grid) at which the betting upper
  bound of the mean per-pair log ratio (:func:`lagrseq.analysis.paired.upper_bounds`, level 95%)
  falls below the margin ``log(1.1)`` in at least 80% of simulated experiments. Default: laws in
  which a share of pairs is late by a factor and the rest are ties (the policy as fast as always
  there), at the step cap given by ``--cap``; with ``--logs``: each point's measured log ratios
  against always, resampled (the empirical law; only where its mean lies below the margin);
* **mean log ratio, show inferior**: the same for the lower bound above the margin (laws whose
  mean lies above it);
* **tail, show non-inferior**: the smallest n at which the exact one-sided 95% Clopper-Pearson
  upper bound of the share of pairs more than 10% late falls below the 10% tail margin with
  probability 0.8 (exact binomial power), at true late shares 0 to 0.05.

A planning figure: the laws are stated, and the power is simulated with the bound the frontier uses.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy.stats import binom

from lagrseq.analysis import paired

POWER = 0.80
GRID = (10, 20, 30, 50, 75, 100, 150, 200, 250, 300, 400, 500, 600, 800, 1000, 1500, 2000, 3000, 5000)
"""Pair counts tried, smallest first."""
MARGIN = math.log1p(0.10)

Sampler = Callable[[np.random.Generator, int, int], np.ndarray]


def mean_pairs(draw: Sampler, span: float, experiments: int, seed: int, inferior: bool = False) -> int:
    """The smallest n of :data:`GRID` at which the upper bound lies below the margin (``inferior``:
    the lower bound above it) in at least :data:`POWER` of ``experiments``; -1 where none does."""
    rng = np.random.default_rng(seed)
    for n in GRID:
        x = draw(rng, experiments, n)
        if inferior:
            hits = -paired.upper_bounds(-x, span) > MARGIN
        else:
            hits = paired.upper_bounds(x, span) < MARGIN
        if float(np.mean(hits)) >= POWER:
            return n
    return -1


def late_law(share: float, factor: float) -> Sampler:
    """A share of pairs late by ``factor``, the rest ties."""
    size = math.log(factor)

    def draw(rng: np.random.Generator, experiments: int, n: int) -> np.ndarray:
        return np.where(rng.random((experiments, n)) < share, size, 0.0)

    return draw


def empirical_law(values: np.ndarray) -> Sampler:
    def draw(rng: np.random.Generator, experiments: int, n: int) -> np.ndarray:
        return values[rng.integers(0, len(values), size=(experiments, n))]

    return draw


def tail_pairs(share: float, margin: float = paired.TAIL_MARGIN) -> int:
    """Smallest n at which the exact upper bound of a late share lies below ``margin`` with
    probability :data:`POWER` when the true share is ``share``; -1 where none up to 5000 does."""
    if share >= margin:
        return -1
    for n in range(2, 5000):
        k = np.arange(n + 1)
        ok = np.array([paired.clopper_pearson(int(i), n)[1] < margin for i in k])
        if float(binom.pmf(k, n, share)[ok].sum()) >= POWER:
            return n
    return -1


def _n(value: int) -> str:
    return f"more than {GRID[-1]}" if value < 0 else str(value)


def from_laws(cap: float, experiments: int, seed: int) -> list[list[str]]:
    span = math.log(cap)
    rows = []
    for share in (0.0, 0.01, 0.02, 0.05):
        for factor in (2.0, 10.0, cap):
            if share == 0.0 and factor != 2.0:
                continue
            law = late_law(share, factor)
            mean = share * math.log(factor)
            name = "all ties" if share == 0.0 else f"{share:.0%} of pairs x{factor:.4g} late, rest ties"
            ni = _n(mean_pairs(law, span, experiments, seed)) if mean < MARGIN else "n/a (mean at or above margin)"
            inf = _n(mean_pairs(law, span, experiments, seed, inferior=True)) if mean > MARGIN else "n/a (mean below margin)"
            rows.append([name, f"{mean:.3f}", ni, inf])
    return rows


def from_logs(roots: Sequence[Path], experiments: int, seed: int) -> list[list[str]]:
    from lagrseq.analysis.frontier import _panel_key, capped_times, horizon, paired_order, points_of
    from lagrseq.analysis.loading import load

    runs = [r for r in load(roots).runs if r.key.kind == "trial"]
    panels: dict[tuple[str, str, str, int, str, str], list] = {}
    for run in runs:
        panels.setdefault(_panel_key(run), []).append(run)
    out = []
    for key, group in sorted(panels.items()):
        points = points_of(group, None)
        always = next((p for p in points if p.policy == "always" and not p.knobs), None)
        cap = horizon(*points)
        if always is None or not math.isfinite(cap):
            continue
        for p in points:
            order = paired_order(p, always)
            if p is always or p.policy in ("never", "oracle") or order is None:
                continue
            x = paired.log_ratios(capped_times(p, cap)[order[0]], capped_times(always, cap)[order[1]], cap)
            mean = float(x.mean())
            law = empirical_law(x)
            ni = _n(mean_pairs(law, math.log(cap), experiments, seed)) if mean < MARGIN else "n/a (mean at or above margin)"
            inf = _n(mean_pairs(law, math.log(cap), experiments, seed, inferior=True)) if mean > MARGIN else "n/a (mean below margin)"
            name = f"{key[0]} seed {key[3]} ({key[4]}{', ' + key[5] if key[5] else ''}): {p.label}, {len(x)} pairs measured"
            out.append([name, f"{mean:.3f}", ni, inf])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", type=Path, nargs="*", default=None, help="frontier run directories (default: the stated laws)")
    parser.add_argument("--cap", type=float, default=5001.0, help="step cap of the laws (default 5001)")
    parser.add_argument("--experiments", type=int, default=400, help="simulated experiments per n (default 400)")
    parser.add_argument("--seed", type=int, default=20231, help="generator seed (default 20231)")
    args = parser.parse_args()
    rows = from_logs(args.logs, args.experiments, args.seed) if args.logs else from_laws(args.cap, args.experiments, args.seed)
    print(
        f"pairs for {POWER:.0%} power, betting bounds at one-sided {paired.ALPHA}, margin 10% on the mean log ratio"
        + ("" if args.logs else f", cap {args.cap:g} steps") + f", {args.experiments} experiments per n"
    )
    header = ("law of the log ratio", "true mean", "non-inferior on the mean", "inferior on the mean")
    print("| " + " | ".join(header) + " |")
    print("| " + " | ".join("---" for _ in header) + " |")
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()
    print(f"the tail alone: pairs for the exact upper bound of the late share to fall below {paired.TAIL_MARGIN:.0%} with {POWER:.0%} power")
    shares = (0.0, 0.01, 0.02, 0.05)
    print("| true late share | " + " | ".join(f"{s:.2f}" for s in shares) + " |")
    print("| --- | " + " | ".join("---" for _ in shares) + " |")
    print("| pairs | " + " | ".join(_n(tail_pairs(s)) for s in shares) + " |")


if __name__ == "__main__":
    main()
