"""Frontier benchmark: how long ``lagrseq frontier`` takes, and what the asking-policy call costs
in the loop.

    PYTHONPATH=. python benchmarks/bench_frontier.py                       # cube, mock answers
    PYTHONPATH=. python benchmarks/bench_frontier.py --provider recorded:STORE --on-miss mock \\
        --task object-arrangement --trials 2 --policies always,seq,thompson:query_cost=0.5

    PYTHONPATH=. python benchmarks/bench_frontier.py --task image-completion --provider mock:authors-gpt4 \
        --policies never,always,seq,oracle,thompson:query_cost=0.5:min_progress=3 --sweep "" \
        --trials 3 --set run.max_steps=2000 --compare

Prints timings measured in this run:
1. the whole frontier (every policy's trials, logged to MCAP, then the report) with ``--jobs``
   workers (default: the cores), every policy's trials submitted to one pool at once;
2. with ``--compare``: the same trials run the way the frontier ran them before, one pool per
   policy, each waiting for its policy's last trial (the logs are the same), and the ratio;
3. the report alone, rebuilt from the logs (``lagrseq frontier --replay``);
4. a cube trial unlogged with ``--method lagr`` against the same trial with ``--method lagr-seq``
   and ``secondary.policy = always`` (the same decisions, through the policy interface and its
   per-decision context): their ratio is the interface's overhead on the hot loop.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from lagrseq import cli
from lagrseq import config as cfg
from lagrseq.running import runner
from lagrseq.running.runner import run_one
from lagrseq.running.wiring import provider_options
from lagrseq.study import frontier


def timed(argv: list[str]) -> float:
    started = time.perf_counter()
    code = cli.main(argv)
    if code != 0:
        raise SystemExit(f"lagrseq {' '.join(argv)} failed with status {code}")
    return time.perf_counter() - started


def overhead(repeats: int) -> tuple[float, float]:
    """Best-of seconds of one unlogged cube trial: lagr, and always through the policy interface."""
    plain = cfg.load("cube-stacking", "lagr", "upstream")
    policy = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ['secondary.policy="always"'])
    best = [float("inf"), float("inf")]
    for _ in range(repeats):
        for i, config in enumerate((plain, policy)):
            started = time.perf_counter()
            run_one(config, 0, 0, "mock:authors-t0", Path("unused.mcap"), log=False)
            best[i] = min(best[i], time.perf_counter() - started)
    return best[0], best[1]


def one_pool_per_policy(args: argparse.Namespace, out: Path) -> float:
    """Seconds for the frontier's trials run as before: one process pool per policy variant."""
    variants = frontier.parse_policies(args.policies) + (frontier.parse_sweep(args.sweep) if args.sweep else [])
    on_miss = args.on_miss or ("refuse" if args.provider.startswith("recorded:") else None)
    options = provider_options(args.provider, {"on_miss": on_miss})
    started = time.perf_counter()
    for variant in variants:
        config, directory = runner.prepare(
            args.task, variant.method, "upstream", None, [*args.overrides, *variant.overrides()], args.provider, options, out, 0
        )
        runner.run_trials(config, args.trials, 0, args.provider, directory, args.jobs, provider_options=options)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="cube-stacking")
    parser.add_argument("--provider", default="mock:authors-t0")
    parser.add_argument("--on-miss", default=None)
    parser.add_argument("--policies", default="never,always,seq,thompson,oracle")
    parser.add_argument("--sweep", default="thompson:query_cost=0.25,0.5")
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--compare", action="store_true", help="also time one pool per policy (the old way)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fr"
        argv = [
            "frontier", args.task, "--provider", args.provider, "--policies", args.policies,
            "--trials", str(args.trials), "--out", str(out), "--quiet", "--jobs", str(args.jobs),
            # the same runs as one_pool_per_policy: the upstream preset in its own regime, no matched-rate random
            "--preset", "upstream", "--scopes", "episode" if args.task == "cube-stacking" else "trial", "--no-matched-random",
        ]
        argv += ["--sweep", args.sweep] if args.sweep else []
        argv += ["--on-miss", args.on_miss] if args.on_miss else []
        for override in args.overrides:
            argv += ["--set", override]
        variants = len(args.policies.split(",")) + (len(args.sweep.split("=", 1)[1].split(",")) if args.sweep else 0)
        whole = timed(argv)
        before = one_pool_per_policy(args, Path(tmp) / "before") if args.compare else None
        report = timed(["frontier", "--replay", str(out), "--out", str(Path(tmp) / "again")])
    plain, policy = overhead(args.repeats)
    print(f"\nfrontier of {variants} policy variants x {args.trials} trials ({args.task}, {args.provider}, {args.jobs} jobs): {whole:.1f} s")
    if before is not None:
        print(f"the same trials with one pool per policy (before): {before:.1f} s (one pool for all: {before / whole:.2f}x faster, report included)")
    print(f"report alone, from the logs: {report:.1f} s")
    print(f"one unlogged cube trial: lagr {plain:.3f} s, always through the policy interface {policy:.3f} s "
          f"(ratio {policy / plain:.3f})")


if __name__ == "__main__":
    main()
