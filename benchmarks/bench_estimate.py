"""How close ``lagrseq reproduce``'s estimate comes to each run, run by run.

    PYTHONPATH=. python benchmarks/bench_estimate.py --tasks image-completion,object-arrangement
    PYTHONPATH=. python benchmarks/bench_estimate.py --tasks cube-stacking --full

Plans the quick suite (``--full``: the full suite), times it as ``reproduce --jobs 2`` does (the
experiments in a pool of two workers, side by side), then runs every trial run of the chosen
tasks here, one run after the other (a run's trials in lockstep where they train networks), and
prints, per run, the estimate's CPU seconds (its share of the wall estimate times the workers)
against the CPU seconds the run took, and the sums. The runs here are alone: in ``reproduce``
they share lockstep groups with other runs and the pool's two workers, so the sums, not single
rows, are what the estimate is for. Nothing under ``--out`` is kept between invocations.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", default="image-completion,object-arrangement,cube-stacking", help="comma-separated task names")
    parser.add_argument("--full", action="store_true", help="the full suite's runs (default: the quick suite's)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/lagrseq-bench-estimate"), help="scratch directory (emptied first)")
    args = parser.parse_args()

    from lagrseq.progress import Reporter
    from lagrseq.running import runner
    from lagrseq.study import reproduce
    from lagrseq.suite import load_suite

    tasks = set(args.tasks.split(","))
    shutil.rmtree(args.out, ignore_errors=True)
    runs_dir = args.out / "runs"
    runs_dir.mkdir(parents=True)
    suite = load_suite(None)
    plan = reproduce.plan(suite, not args.full, None, runs_dir, suite.seed)
    plan.runs = [run for run in plan.runs if run.config.task.name in tasks and run.kind == "trial"]
    if not plan.runs:
        parser.exit(2, f"no trial runs of {', '.join(sorted(tasks))} in the suite; --tasks takes task names, e.g. cube-stacking\n")
    started = time.perf_counter()
    with runner.make_executor("local", 2, None, Reporter()) as pool:
        guess = reproduce.estimate_phases(plan, 2, pool=pool)
    print(f"calibration: {reproduce.calibration_keys(plan, 2)} experiments in {time.perf_counter() - started:.1f} s wall", flush=True)
    estimated = actual = 0.0
    ratios: list[float] = []
    for run in plan.runs:
        expected = 2 * guess.per_run.get(run.path, 0.0)
        cpu = time.process_time()
        runner.run_trials(run.config, run.trials, run.seed, run.provider, run.path, provider_options=run.options)
        took = time.process_time() - cpu
        estimated += expected
        actual += took
        ratios.append(took / expected if expected else float("nan"))
        print(
            f"{run.config.task.name:18s} {run.config.method:8s} {run.provider[:34]:34s} {run.path.name[-8:]} "
            f"n={run.trials:2d}  estimate {expected:6.2f} s  took {took:6.2f} s  took/estimate {ratios[-1]:5.2f}",
            flush=True,
        )
    quartiles = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else ratios * 3
    print(
        f"{len(ratios)} runs: estimate {estimated:.1f} s, took {actual:.1f} s of CPU, took/estimate {actual / estimated:.2f} "
        f"(runs: median {statistics.median(ratios):.2f}, quartiles {quartiles[0]:.2f} to {quartiles[2]:.2f}, "
        f"range {min(ratios):.2f} to {max(ratios):.2f})"
    )


if __name__ == "__main__":
    main()
