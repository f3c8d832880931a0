"""Cube stacking speed: seconds per trial with and without MCAP logging, env steps per second.

8 cubes, upstream preset (100 episodes x 50 steps per trial), mock provider, one core.
Targets (issue 2): <= 0.5 s per trial with logging; logging overhead <= 30 %.
For scale: the released code needs about 0.4 s per LaGR-SEQ trial and about 39 s per Q-learning
trial (its permutation-ranking state index), measured on this kind of machine.

    python benchmarks/bench_cube.py [--trials 10]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from lagrseq import config as cfg
from lagrseq.runner import run_one


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=10, help="trials per measurement (default 10)")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    print(f"cube stacking, 8 cubes, upstream preset, {args.trials} trials per cell, one core")
    print(f"{'method':<10} {'log':<4} {'s/trial':>8} {'steps/s':>10} {'MB/trial':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for method in ("baseline", "lagr", "lagr-seq"):
            config = cfg.load("cube-stacking", method, "upstream")
            run_one(config, 999, 1, "mock", Path(tmp) / "warm.mcap")  # imports, caches
            seconds: dict[bool, float] = {}
            for log in (False, True):
                times, steps, size = [], 0, 0
                for trial in range(args.trials):
                    path = Path(tmp) / f"{method}-{trial}.mcap"
                    started = time.perf_counter()
                    result = run_one(config, trial, 0, "mock", path, log=log)
                    times.append(time.perf_counter() - started)
                    steps += result.steps
                    size += path.stat().st_size if log else 0
                seconds[log] = statistics.mean(times)
                print(
                    f"{method:<10} {'yes' if log else 'no':<4} {seconds[log]:>8.3f} "
                    f"{steps / sum(times):>10.0f} {size / args.trials / 1e6:>9.3f}"
                )
            overhead = seconds[True] / seconds[False] - 1
            print(f"{method:<10} logging overhead {overhead:+.0%} (target <= 30%), "
                  f"{seconds[True]:.3f} s per logged trial (target <= 0.5 s)")


if __name__ == "__main__":
    main()
