"""Cube stacking speed: seconds per trial with and without MCAP logging, env steps per second.

8 cubes, upstream preset (100 episodes x 50 steps per trial), mock provider, one core.
Targets: <= 0.5 s per trial with logging; logging overhead <= 20 %, measured as the median of
per-pair ratios of logged to unlogged CPU time (``time.process_time``) in the same process.
Logged and unlogged trials alternate (A B A B ...), so a machine whose load changes during the
run slows both alike.

``--vs REF`` (``--vs main``: against main) then measures the logging overhead again, in
``--pairs`` fresh processes on this tree's lagrseq and as many on REF's (a git worktree),
alternating, and prints each tree's median overhead, its range over the processes, and their
ratio of CPU seconds per logged trial; then it runs a whole cube LaGR-SEQ run of 10 trials
(``lagrseq run cube-stacking --trials 10 --jobs 1``, a fresh process each time) from each tree,
alternating, and prints the paired CPU-time ratios (``benchmarks/paired.py``).
For scale: the released code needs about 0.4 s per LaGR-SEQ trial and about 39 s per Q-learning
trial (its permutation-ranking state index), measured on this kind of machine.

    python benchmarks/bench_cube.py [--trials 10] [--methods lagr-seq] [--vs main --pairs 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from paired import HERE, add_vs_argument, compare, worktree

from lagrseq import config as cfg
from lagrseq.running.runner import run_one

TARGET_OVERHEAD = 0.20


def measure(methods: list[str], trials: int) -> dict[str, dict[str, float]]:
    """Per method: CPU seconds per logged and unlogged trial, and the logging overhead (the
    median of per-pair ratios of logged to unlogged CPU time, minus 1); prints the table."""
    print(f"{'method':<10} {'log':<4} {'s/trial':>8} {'steps/s':>10} {'MB/trial':>9}")
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for method in methods:
            config = cfg.load("cube-stacking", method, "upstream")
            run_one(config, 999, 1, "mock", Path(tmp) / "warm.mcap")  # imports, caches
            times: dict[bool, list[float]] = {False: [], True: []}
            steps = {False: 0, True: 0}
            size = 0
            for trial in range(trials):
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
                    f"{steps[log] / sum(times[log]):>10.0f} {size / trials / 1e6 if log else 0:>9.3f}"
                )
            # the median of per-pair ratios: robust to a trial that a busy machine slowed down
            ratio = statistics.median(b / a for a, b in zip(times[False], times[True]))
            print(
                f"{method:<10} logging overhead {ratio - 1:+.0%} (target <= {TARGET_OVERHEAD:.0%}; "
                f"median of {trials} paired CPU-time ratios), "
                f"{statistics.mean(times[True]):.3f} s per logged trial (target <= 0.5 s)"
            )
            out[method] = {"overhead": ratio - 1, "logged": statistics.mean(times[True]),
                           "unlogged": statistics.mean(times[False])}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=10, help="trials per measurement (default 10)")
    parser.add_argument("--methods", default="baseline,lagr,lagr-seq", help="comma-separated methods (default: all three)")
    parser.add_argument("--json", action="store_true", help="print the measurement as one JSON line at the end")
    add_vs_argument(parser)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    print(f"cube stacking, 8 cubes, upstream preset, {args.trials} trials per cell, one core")
    result = measure(args.methods.split(","), args.trials)
    if args.json:
        print(json.dumps(result))
    if args.vs:
        run_vs(args.vs, args.pairs, args.methods, args.trials)


def overhead_vs(tree: Path, ref: str, pairs: int, methods: str, trials: int) -> None:
    """The logging overhead measured by this script in fresh processes, on this tree's lagrseq
    and on REF's, alternating; prints each method's median overhead of each tree (and its range)
    and the ratio of their CPU seconds per logged trial (REF / this tree, above 1: this tree is
    faster)."""
    runs: dict[str, list[dict[str, dict[str, float]]]] = {"here": [], ref: []}
    for pair in range(pairs):
        for name, path in (("here", HERE), (ref, tree)) if pair % 2 == 0 else ((ref, tree), ("here", HERE)):
            command = [sys.executable, __file__, "--json", "--trials", str(trials), "--methods", methods]
            env = {**os.environ, "PYTHONPATH": str(path)}
            done = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
            runs[name].append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"logging overhead, this tree vs {ref} ({pairs} alternating processes each, {trials} trial pairs each):")
    for method in methods.split(","):
        here = [run[method] for run in runs["here"]]
        theirs = [run[method] for run in runs[ref]]
        ratio = statistics.median(t["logged"] for t in theirs) / statistics.median(h["logged"] for h in here)
        print(
            f"{method:<10} overhead here {_spread([h['overhead'] for h in here])}, "
            f"{ref} {_spread([t['overhead'] for t in theirs])}; s per logged trial "
            f"{ref} / here = {ratio:.2f}"
        )


def _spread(overheads: list[float]) -> str:
    """The median overhead of a tree's processes and their range: ``+24% (+22..+27%)``."""
    return f"{statistics.median(overheads):+.0%} ({min(overheads):+.0%}..{max(overheads):+.0%})"


def run_vs(ref: str, pairs: int, methods: str, trials: int) -> None:
    def command(scratch: Path) -> list[str]:
        return [
            sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr-seq",
            "--provider", "mock", "--trials", "10", "--jobs", "1", "--quiet", "--out", str(scratch),
        ]

    with worktree(ref) as tree:
        overhead_vs(tree, ref, pairs, methods, trials)
        print(f"whole process, cube LaGR-SEQ run of 10 trials, here vs {ref} ({pairs} alternating pairs):")
        print(compare(command, tree, pairs).line("cube run of 10 trials", ref))


if __name__ == "__main__":
    main()
