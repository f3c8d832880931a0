"""Cube stacking speed: seconds per trial with and without MCAP logging, env steps per second.

8 cubes, upstream preset (100 episodes x 50 steps per trial), mock provider, one core.
Targets: <= 0.5 s per trial with logging; logging overhead <= 25 %, measured as the median of
per-pair ratios of logged to unlogged CPU time (``time.process_time``) in the same process.
Logged and unlogged trials alternate (A B A B ...), so a machine whose load changes during the
run slows both alike.

``--vs REF`` then runs a whole cube LaGR-SEQ run of 10 trials (``lagrseq run cube-stacking
--trials 10 --jobs 1``, a fresh process each time) from this tree and from a worktree of REF,
alternating, and prints the paired CPU-time ratios (``benchmarks/paired.py``).
For scale: the released code needs about 0.4 s per LaGR-SEQ trial and about 39 s per Q-learning
trial (its permutation-ranking state index), measured on this kind of machine.

    python benchmarks/bench_cube.py [--trials 10] [--methods lagr-seq] [--vs f2d2ceb --pairs 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from paired import add_vs_argument, compare, worktree

from lagrseq import config as cfg
from lagrseq.running.runner import run_one

TARGET_OVERHEAD = 0.25


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=10, help="trials per measurement (default 10)")
    parser.add_argument("--methods", default="baseline,lagr,lagr-seq", help="comma-separated methods (default: all three)")
    add_vs_argument(parser)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    print(f"cube stacking, 8 cubes, upstream preset, {args.trials} trials per cell, one core")
    print(f"{'method':<10} {'log':<4} {'s/trial':>8} {'steps/s':>10} {'MB/trial':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for method in args.methods.split(","):
            config = cfg.load("cube-stacking", method, "upstream")
            run_one(config, 999, 1, "mock", Path(tmp) / "warm.mcap")  # imports, caches
            times: dict[bool, list[float]] = {False: [], True: []}
            steps = {False: 0, True: 0}
            size = 0
            for trial in range(args.trials):
                for log in (False, True):
                    path = Path(tmp) / f"{method}-{trial}.mcap"
                    started = time.process_time()
                    result = run_one(config, trial, 0, "mock", path, log=log)
                    times[log].append(time.process_time() - started)
                    steps[log] += result.steps
                    size += path.stat().st_size if log else 0
            for log in (False, True):
                print(
                    f"{method:<10} {'yes' if log else 'no':<4} {statistics.mean(times[log]):>8.3f} "
                    f"{steps[log] / sum(times[log]):>10.0f} {size / args.trials / 1e6 if log else 0:>9.3f}"
                )
            # the median of per-pair ratios: robust to a trial that a busy machine slowed down
            ratio = statistics.median(b / a for a, b in zip(times[False], times[True]))
            print(
                f"{method:<10} logging overhead {ratio - 1:+.0%} (target <= {TARGET_OVERHEAD:.0%}; "
                f"median of {args.trials} paired CPU-time ratios), "
                f"{statistics.mean(times[True]):.3f} s per logged trial (target <= 0.5 s)"
            )
    if args.vs:
        run_vs(args.vs, args.pairs)


def run_vs(ref: str, pairs: int) -> None:
    def command(scratch: Path) -> list[str]:
        return [
            sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr-seq",
            "--provider", "mock", "--trials", "10", "--jobs", "1", "--quiet", "--out", str(scratch),
        ]

    print(f"whole process, cube LaGR-SEQ run of 10 trials, here vs {ref} ({pairs} alternating pairs):")
    with worktree(ref) as tree:
        print(compare(command, tree, pairs).line("cube run of 10 trials", ref))


if __name__ == "__main__":
    main()
