"""Pairs each frontier estimand needs for 80% power at the measured variance (issue 35).

    PYTHONPATH=. python benchmarks/power.py                       # the differences docs/frontier.md lists
    PYTHONPATH=. python benchmarks/power.py --logs fr-arr         # every asking point of a frontier's logs

For each asking policy against always, on steps to the first solve:

* **mean log ratio, show non-inferior**: pairs for the studentized bound of the mean per-pair log
  ratio to fall below the margin ``log(1.1)`` with probability 0.8 when the true mean is 0 (the
  policy as fast as always) and the spread is the measured one
  (:func:`lagrseq.analysis.paired.pairs_for_power`, the normal approximation);
* **mean log ratio, show inferior**: pairs for its lower bound to clear the margin when the true
  mean is the measured one (only where the measured mean lies above the margin);
* **tail, show non-inferior**: pairs for the exact one-sided 95% Clopper-Pearson upper bound of the
  share of pairs more than 10% late to fall below 20% with probability 0.8, when the true late
  share is the measured one (exact binomial power; "never" where the measured share is at or
  above 20%), and the same when the true share is 0;
* **tail, show inferior**: pairs for the exact lower bound to clear 20% with probability 0.8 at
  the measured share (where it lies above 20%);
* **beats matched random**: pairs for the upper bound of the mean log ratio against the matched
  random run to fall below 0 at the measured mean and spread (with ``--logs``, where the random
  run is there);
* **queries**: pairs for the one-sided 95% bound of the query ratio (policy's mean queries over
  always's, delta method on the log of the ratio of paired means) to fall below 0.2 (80% fewer)
  at the measured ratio and per-trial spread (with ``--logs``).

A planning figure, not a bound: the normal approximation is optimistic where the differences are
as skewed as the measured ones (``benchmarks/coverage.py --paired``).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.stats import beta, binom, norm

from lagrseq.analysis import paired

POWER = 0.80
MAX_N = 100_000

# What docs/frontier.md lists (seed 1, 10 pairs, the authors' answers with misses refused):
# always's steps to the first solve on the object arrangement, and the per-pair differences of
# thompson (query cost 0.5) and of random at its matched rate (p 0.038), episode regime.
ARRANGEMENT_ALWAYS = (43, 195, 241, 39, 145, 74, 36, 164, 165, 67)
ARRANGEMENT_THOMPSON = (1, 0, 238, 46, 4, 12, 0, 1, 22, 2)
ARRANGEMENT_RANDOM = (2, 155, 252, 194, 446, 20, 1, 7, 0, 256)
# Image completion: thompson's differences; always's per-trial times are not on the page: the two
# late pairs against about 97 steps (issue 35), the others against always's mean, 992 steps.
IMAGE_THOMPSON = (6494, 3, 6465, 1, 1, 0, 4, 1, 5, 2)
IMAGE_ALWAYS = (97, 992, 97, 992, 992, 992, 992, 992, 992, 992)


def tail_pairs(share: float, margin: float = paired.TAIL_MARGIN, upper: bool = True, alpha: float = paired.ALPHA) -> int:
    """Smallest n at which the exact one-sided (1 - alpha) Clopper-Pearson bound of a late share
    lies beyond ``margin`` (``upper``: the upper bound below it; else the lower bound above it)
    with probability ``POWER`` when the true share is ``share``; -1 where no n does."""
    if (upper and share >= margin) or (not upper and share <= margin):
        return -1
    for n in range(paired.MIN_PAIRS, MAX_N):
        k = np.arange(n + 1)
        if upper:
            bound = np.where(k == n, 1.0, beta.ppf(1.0 - alpha, k + 1, n - k))
            power = float(binom.pmf(k, n, share)[bound < margin].sum())
        else:
            bound = np.where(k == 0, 0.0, beta.ppf(alpha, k, n - k + 1))
            power = float(binom.pmf(k, n, share)[bound > margin].sum())
        if power >= POWER:
            return n
    return -1


def query_pairs(policy: np.ndarray, always: np.ndarray, target: float = 0.2, alpha: float = paired.ALPHA) -> int:
    """Pairs for the one-sided bound of mean(policy) / mean(always) to fall below ``target`` with
    probability ``POWER`` (delta method on the log ratio of paired means, measured spread)."""
    ratio = float(policy.mean() / always.mean())
    if ratio >= target or len(policy) < 2:
        return -1
    cp, ca = policy.std(ddof=1) / policy.mean() if policy.mean() else 0.0, always.std(ddof=1) / always.mean()
    rho = float(np.corrcoef(policy, always)[0, 1]) if policy.std() and always.std() else 0.0
    s = math.sqrt(max(cp**2 + ca**2 - 2 * rho * cp * ca, 1e-12))
    z = float(norm.ppf(1 - alpha) + norm.ppf(POWER))
    return max(paired.MIN_PAIRS, math.ceil((z * s / (math.log(target) - math.log(ratio))) ** 2))


def _n(value: int) -> str:
    if value < 0:
        return "never"
    return f"{value} (the minimum)" if value == paired.MIN_PAIRS else str(value)


def rows(name: str, policy: np.ndarray, always: np.ndarray, random: np.ndarray | None = None,
         queries: tuple[np.ndarray, np.ndarray] | None = None) -> list[str]:
    """The estimands' pairs for one policy against always (and its matched random)."""
    d = np.log(policy) - np.log(always)
    margin = math.log1p(paired.LATE)
    late = float(np.mean(policy > (1 + paired.LATE) * always))
    cells = [
        name, str(len(d)), f"{d.mean():+.3f} (sd {d.std(ddof=1):.3f})",
        _n(paired.pairs_for_power(d, 0.0, margin, POWER, alpha=paired.BOUND_ALPHA)),
        _n(paired.pairs_for_power(-d, -float(d.mean()), -margin, POWER, alpha=paired.BOUND_ALPHA)) if d.mean() > margin else "n/a (mean below margin)",
        f"{late:.2f}", _n(tail_pairs(late)), _n(tail_pairs(0.0)), _n(tail_pairs(late, upper=False)),
    ]
    if random is not None:
        r = np.log(policy) - np.log(random)
        cells.append(f"{r.mean():+.3f}: {_n(paired.pairs_for_power(r, float(r.mean()), 0.0, POWER, alpha=paired.BOUND_ALPHA))}")
    else:
        cells.append("n/a")
    cells.append(_n(query_pairs(*queries)) if queries is not None else "n/a")
    return cells


HEADER = (
    "policy vs always", "pairs measured", "mean log ratio (sd)", "NI on the mean, true 0", "inferior on the mean",
    "late share", "tail NI at that share", "tail NI, true 0", "tail inferior", "beats random (its mean: n)",
    "queries <= 20% of always's",
)


def from_docs() -> list[list[str]]:
    always = np.array(ARRANGEMENT_ALWAYS, dtype=float)
    arrangement = rows(
        "object arrangement: thompson (cost 0.5)", always + np.array(ARRANGEMENT_THOMPSON), always,
        random=always + np.array(ARRANGEMENT_RANDOM),
    )
    image_always = np.array(IMAGE_ALWAYS, dtype=float)
    image = rows("image completion: thompson (cost 0.5)", image_always + np.array(IMAGE_THOMPSON), image_always)
    return [arrangement, image]


def from_logs(roots: Sequence[Path]) -> list[list[str]]:
    from lagrseq.analysis.frontier import _panel_key, judge, paired_order, points_of
    from lagrseq.analysis.loading import load

    runs = [r for r in load(roots).runs if r.key.kind == "trial"]
    panels: dict[tuple[str, str, str, int, str, str], list] = {}
    for run in runs:
        panels.setdefault(_panel_key(run), []).append(run)
    out = []
    for key, group in sorted(panels.items()):
        points = points_of(group, None)
        verdicts = judge(points)
        always = next((p for p in points if p.policy == "always" and not p.knobs), None)
        if always is None:
            continue
        for p in points:
            order = paired_order(p, always)
            if p is always or p.policy in ("never", "oracle") or order is None:
                continue
            matched = verdicts[id(p)].matched
            random = None
            if matched is not None and (o := paired_order(p, matched)) is not None:
                random = matched.steps_to_solve[o[1]]
            name = f"{key[0]} ({key[4]}{', ' + key[5] if key[5] else ''}): {p.label}"
            out.append(rows(
                name, p.steps_to_solve[order[0]], always.steps_to_solve[order[1]], random,
                (p.queries[order[0]], always.queries[order[1]]),
            ))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", type=Path, nargs="*", default=None, help="frontier run directories (default: the differences docs/frontier.md lists)")
    args = parser.parse_args()
    table = from_logs(args.logs) if args.logs else from_docs()
    print(f"pairs for {POWER:.0%} power, one-sided alpha {paired.BOUND_ALPHA} on the mean (calibrated), {paired.ALPHA} on the tail, margin {paired.LATE:.0%} on the mean log ratio, tail margin {paired.TAIL_MARGIN:.0%}")
    print("| " + " | ".join(HEADER) + " |")
    print("| " + " | ".join("---" for _ in HEADER) + " |")
    for row in table:
        print("| " + " | ".join(row) + " |")
    print()
    print(f"the tail alone: pairs for the exact upper bound of the late share to fall below {paired.TAIL_MARGIN:.0%} with {POWER:.0%} power")
    shares = (0.0, 0.02, 0.05, 0.10, 0.15)
    print("| true late share | " + " | ".join(f"{s:.2f}" for s in shares) + " |")
    print("| --- | " + " | ".join("---" for _ in shares) + " |")
    print("| pairs | " + " | ".join(_n(tail_pairs(s)) for s in shares) + " |")


if __name__ == "__main__":
    main()
