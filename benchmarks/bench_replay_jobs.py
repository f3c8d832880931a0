"""``lagrseq replay --jobs 1`` against ``--jobs N`` on the same logs, paired (issue 35, item 6):
where do worker processes pay for themselves?

    PYTHONPATH=. python benchmarks/bench_replay_jobs.py --runs /tmp/q/runs
    PYTHONPATH=. python benchmarks/bench_replay_jobs.py --runs /tmp/q/runs --jobs 2 --pairs 3 --subset 40

Each run is ``python -m lagrseq replay RUNS --out SCRATCH --jobs J`` in a fresh process (its
imports and its worker processes counted: user + system CPU of the process and of every process
it waited for, from ``os.wait4``; ``benchmarks/paired.py``). Pairs alternate which goes first.
``--subset K``: also the same on the first K run folders alone (few logs, where starting the
workers weighs most). Prints per pair and the medians of the ratios jobs N / jobs 1
(above 1: the workers cost more).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

from paired import HERE, cpu_seconds


def series(runs: list[Path], jobs: int, pairs: int) -> None:
    logs = sum(1 for folder in runs for _ in folder.rglob("*.mcap"))
    print(f"{len(runs)} folders, {logs} logs; --jobs 1 against --jobs {jobs}, {pairs} alternating pairs", flush=True)
    cpu: dict[int, list[float]] = {1: [], jobs: []}
    wall: dict[int, list[float]] = {1: [], jobs: []}
    for i in range(pairs):
        for j in ((1, jobs) if i % 2 == 0 else (jobs, 1)):
            with tempfile.TemporaryDirectory(prefix="lagrseq-replay-jobs-") as scratch:
                command = [sys.executable, "-m", "lagrseq", "replay", *map(str, runs), "--out", scratch, "--jobs", str(j)]
                seconds, took = cpu_seconds(command, HERE)
            cpu[j].append(seconds)
            wall[j].append(took)
        print(
            f"  pair {i + 1}: --jobs 1 {cpu[1][-1]:.2f} s CPU ({wall[1][-1]:.1f} s wall), "
            f"--jobs {jobs} {cpu[jobs][-1]:.2f} s CPU ({wall[jobs][-1]:.1f} s wall)",
            flush=True,
        )
    ratio_cpu = [b / a for a, b in zip(cpu[1], cpu[jobs], strict=True)]
    ratio_wall = [b / a for a, b in zip(wall[1], wall[jobs], strict=True)]
    print(
        f"  --jobs {jobs} / --jobs 1: CPU median {statistics.median(ratio_cpu):.2f}x "
        f"(pairs {', '.join(f'{r:.2f}' for r in ratio_cpu)}), wall median {statistics.median(ratio_wall):.2f}x "
        f"(pairs {', '.join(f'{r:.2f}' for r in ratio_wall)}); load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, required=True, help="a folder of run logs (e.g. a reproduce --quick's OUT/runs)")
    parser.add_argument("--jobs", type=int, default=2, help="the worker count compared with 1 (default 2)")
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--subset", type=int, default=0, help="also on the first K run folders alone (0: not)")
    args = parser.parse_args()
    if not args.runs.is_dir():
        parser.exit(2, f"--runs {args.runs}: not a folder; give the runs folder of a reproduce (OUT/runs)\n")
    series([args.runs.resolve()], args.jobs, args.pairs)
    if args.subset:
        series(sorted({path.parent for path in args.runs.resolve().rglob("*.mcap")})[: args.subset], args.jobs, args.pairs)


if __name__ == "__main__":
    main()
