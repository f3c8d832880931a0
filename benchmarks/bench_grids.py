"""Speed of the grid tasks: environment steps per second and seconds per trial, on one core.

    PYTHONPATH=. python benchmarks/bench_grids.py                 # both tasks, both methods
    PYTHONPATH=. python benchmarks/bench_grids.py --preset upstream --trials 2

Each trial runs the full step budget of the released code (image completion 10 000 steps,
object arrangement 5 000) with the mock provider and writes its MCAP log, as `lagrseq run` does.
Targets: an image trial in <= 30 s and an arrangement trial in <= 15 s. For scale, the
released Keras code fits each of 64 (image) or 16 (arrangement) samples separately at every step:
about 17-21 s per image step and 5 s per arrangement step once training starts.

``--vs REF`` runs instead, from this tree and from a git worktree of REF in alternating fresh
processes (``benchmarks/paired.py``), and prints paired CPU-time ratios for:
1. start-up: ``lagrseq run TASK --method lagr-seq --set run.max_steps=1`` (imports, building the
   DQN agents and their optimisers, one step, the log);
2. a run of ``--vs-trials`` trials of ``--vs-steps`` steps each (``lagrseq run TASK --method
   lagr-seq --jobs N`` with ``--vs-jobs``, default 1), whole process including its workers; with
   ``--vs-steps 0`` each trial has its preset's own length (image 10 000 steps, arrangement
   5 000), the issue's workload. The trials of one process run in lockstep (seed-batched DQN).

    PYTHONPATH=. python benchmarks/bench_grids.py --vs main --pairs 3   # this tree against main
    PYTHONPATH=. python benchmarks/bench_grids.py --task image-completion --vs main --pairs 2 \
        --vs-trials 10 --vs-steps 0 --no-startup     # ten full-length trials in lockstep
    PYTHONPATH=. python benchmarks/bench_grids.py --task image-completion --vs main --pairs 3 \
        --vs-trials 1 --no-startup                   # one trial alone (what the default rows run)

With ``--vs main`` the printed ratio (main / this tree, above 1: this tree is faster) is the
comparison against main's implementation in the same run: both trees run the same command,
alternating, in fresh processes.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from paired import add_vs_argument, compare, worktree

from lagrseq import config as cfg
from lagrseq.running.runner import run_one
from lagrseq.running.wiring import make_env

STEPS = {"image-completion": 10_000, "object-arrangement": 5_000}
TARGET_SECONDS = {"image-completion": 30.0, "object-arrangement": 15.0}


def pin_one_core() -> str:
    """Run on one core: one torch thread and, where the OS allows, one CPU."""
    import torch

    torch.set_num_threads(1)
    if hasattr(os, "sched_setaffinity"):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"CPU {cpu}, 1 torch thread"
    return "1 torch thread (no CPU affinity on this OS)"


def env_only(task: str, preset: str, steps: int) -> float:
    """Steps per second of the environment alone under a uniformly random policy."""
    env = make_env(cfg.load(task, "baseline", preset))
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    started = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(int(rng.integers(2)))
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - started)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=sorted(STEPS), action="append")
    parser.add_argument("--method", choices=["baseline", "lagr", "lagr-seq"], action="append")
    parser.add_argument("--preset", choices=cfg.PRESETS, default="paper")
    parser.add_argument("--trials", type=int, default=1, help="trials per row (seeds 0..N-1)")
    parser.add_argument("--out", type=Path, default=None, help="keep the MCAP logs here")
    add_vs_argument(parser)
    parser.add_argument("--vs-steps", type=int, default=2000, help="with --vs: steps per trial (default 2000)")
    parser.add_argument("--vs-trials", type=int, default=2, help="with --vs: trials per run (default 2)")
    parser.add_argument("--vs-jobs", type=int, default=1, help="with --vs: --jobs of the run (default 1)")
    parser.add_argument("--no-startup", action="store_true", help="with --vs: skip the start-up comparison")
    args = parser.parse_args(argv)
    if args.vs:
        for task in args.task or sorted(STEPS):
            run_vs(task, args.preset, args.vs, args.pairs, args.vs_steps, args.vs_trials, args.vs_jobs,
                   not args.no_startup)
        return 0
    where = pin_one_core()
    tasks = args.task or sorted(STEPS)
    methods = args.method or ["baseline", "lagr-seq"]
    print(f"# lagrseq grid benchmark, preset {args.preset}, {where}, python {sys.version.split()[0]}")
    for task in tasks:
        print(f"{task:<20} env alone (random policy): {env_only(task, args.preset, 20_000):>9.0f} steps/s")
    print(f"{'task':<20} {'method':<10} {'steps':>6} {'steps/s':>8} {'s/trial':>8}  target")
    failed = False
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or Path(scratch)
        for task in tasks:
            for method in methods:
                config = cfg.load(task, method, args.preset, overrides=[f"run.max_steps={STEPS[task]}"])
                seconds = []
                for trial in range(args.trials):
                    path = out / task / method / args.preset / f"trial-{trial:03d}.mcap"
                    result = run_one(config, trial, 0, "mock", path)
                    seconds.append(result.seconds)
                mean = float(np.mean(seconds))
                ok = mean <= TARGET_SECONDS[task]
                failed |= not ok
                print(
                    f"{task:<20} {method:<10} {STEPS[task]:>6} {STEPS[task] / mean:>8.0f} {mean:>8.2f}"
                    f"  <= {TARGET_SECONDS[task]:.0f} s {'ok' if ok else 'MISSED'}"
                )
    return 1 if failed else 0


def run_vs(task: str, preset: str, ref: str, pairs: int, steps: int, trials: int, jobs: int = 1,
           startup: bool = True) -> None:
    def command(max_steps: int, count: int, run_jobs: int) -> object:
        def make(scratch: Path) -> list[str]:
            sets = ["--set", f"run.max_steps={max_steps}"] if max_steps else []
            return [
                sys.executable, "-m", "lagrseq", "run", task, "--method", "lagr-seq", "--preset", preset,
                "--provider", "mock", "--trials", str(count), "--jobs", str(run_jobs), "--quiet",
                *sets, "--out", str(scratch),
            ]

        return make

    length = f"{steps} steps" if steps else "full-length"
    with worktree(ref) as tree:
        if startup:
            print(f"{task}: start-up (one step), here vs {ref}:")
            print(compare(command(1, 1, 1), tree, pairs).line(f"{task} start-up", ref))  # type: ignore[arg-type]
        print(f"{task}: {trials} {length} trials, --jobs {jobs}, here vs {ref}:")
        print(compare(command(steps, trials, jobs), tree, pairs).line(f"{task} {trials} trials x {length}", ref))  # type: ignore[arg-type]


if __name__ == "__main__":
    raise SystemExit(main())
