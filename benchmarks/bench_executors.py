"""Executors: speedup of 2 workers over 1, and the per-task overhead of Dask against the pool.

Sweeps of 8 trials (mock provider, logged to MCAP in a scratch directory):

- image completion, LaGR-SEQ, upstream preset, ``run.max_steps`` steps per trial (needs torch);
- cube stacking, LaGR-SEQ, upstream preset (100 episodes per trial).

Each sweep runs on the local process pool and on a Dask LocalCluster, with 1 and with 2 workers;
the speedup is time(1 worker) / time(2 workers) of the same executor, measured in this run. The
per-task overhead runs ``--tiny`` trials of one cube episode each on 2 workers of either executor
and prints the seconds per task and their ratio (Dask / pool). Pools and clusters are started
before the clock starts (one warm-up task each), so start-up is not counted.

On a machine shared with other work, the speedups are noisy: the 1- and 2-worker sweeps alternate
(``--repeats``) so a change of load slows both alike, and the median is printed.

    python benchmarks/bench_executors.py [--image-steps 2000] [--repeats 1] [--tiny 32]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import tempfile
import time
from pathlib import Path

from lagrseq import config as cfg
from lagrseq.running import runner
from lagrseq.running.executors import TrialExecutor, make_executor


def sweep(executor: TrialExecutor, config: cfg.ExperimentConfig, trials: int, scratch: Path) -> float:
    directory = Path(tempfile.mkdtemp(dir=scratch))
    started = time.perf_counter()
    runner.run_trials(config, trials, 0, "mock", directory, pool=executor)
    return time.perf_counter() - started


def warm(executor: TrialExecutor, scratch: Path) -> None:
    tiny = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ["run.episodes=1"])
    sweep(executor, tiny, executor.workers, scratch)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=8, help="trials per sweep (default 8)")
    parser.add_argument("--image-steps", type=int, default=2000, help="environment steps per image trial (default 2000)")
    parser.add_argument("--repeats", type=int, default=1, help="alternating 1/2-worker measurements (default 1)")
    parser.add_argument("--tiny", type=int, default=32, help="one-episode tasks for the overhead (default 32)")
    args = parser.parse_args()
    sweeps = {"cube": cfg.load("cube-stacking", "lagr-seq", "upstream")}
    if importlib.util.find_spec("torch") is not None:
        sweeps = {"image": cfg.load("image-completion", "lagr-seq", "upstream", None, [f"run.max_steps={args.image_steps}"]), **sweeps}
    else:
        print("image sweep skipped: torch is not installed (pip install 'lagrseq[dqn]')")
    print(f"{os.cpu_count()} cores (shared machines make these ratios noisy); {args.trials} trials per sweep, mock provider, logged")
    with tempfile.TemporaryDirectory(prefix="bench-executors-") as tmp:
        scratch = Path(tmp)
        executors = {(kind, n): make_executor(kind, n) for kind in ("local", "dask") for n in (1, 2)}
        try:
            for executor in executors.values():
                warm(executor, scratch)
            print(f"{'sweep':<6} {'executor':<8} {'1 worker s':>11} {'2 workers s':>12} {'speedup':>8}")
            for name, config in sweeps.items():
                for kind in ("local", "dask"):
                    one: list[float] = []
                    two: list[float] = []
                    for _ in range(args.repeats):
                        one.append(sweep(executors[(kind, 1)], config, args.trials, scratch))
                        two.append(sweep(executors[(kind, 2)], config, args.trials, scratch))
                    a, b = statistics.median(one), statistics.median(two)
                    print(f"{name:<6} {kind:<8} {a:>11.2f} {b:>12.2f} {a / b:>7.2f}x")
            tiny = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ["run.episodes=1"])
            per_task = {}
            for kind in ("local", "dask"):
                per_task[kind] = sweep(executors[(kind, 2)], tiny, args.tiny, scratch) / args.tiny
            print(
                f"per-task overhead, {args.tiny} one-episode trials on 2 workers: pool {per_task['local'] * 1000:.1f} ms, "
                f"dask {per_task['dask'] * 1000:.1f} ms per task (dask / pool = {per_task['dask'] / per_task['local']:.2f})"
            )
        finally:
            for executor in executors.values():
                executor.close()


if __name__ == "__main__":
    main()
