"""Replay benchmark: how fast the full suite's logs turn into the report, and proof that the
tables and costs never decompress a transition.

    PYTHONPATH=. python benchmarks/bench_replay.py                 # makes the full suite's logs
    PYTHONPATH=. python benchmarks/bench_replay.py --runs runs     # or uses existing logs

Prints the logs' size and message counts, then three timings:
1. ``lagrseq replay`` (figures, tables, costs, index), in transitions covered per minute;
2. the costs table alone, with the chunks it decompressed (none of them a transition chunk);
3. a full decode of every ``/transition`` message, for comparison.
Target: replay at >= 1 million transitions per minute.

``--vs REF`` then runs ``lagrseq replay RUNS --out SCRATCH`` in a fresh process from this tree
and from a worktree of REF, alternating, and prints paired CPU-time (and wall-time) ratios
(``benchmarks/paired.py``); this tree reads the logs with its default ``--jobs``. With ``--runs`` and ``--vs``, only the
paired comparison runs.

    PYTHONPATH=. python benchmarks/bench_replay.py --runs /tmp/q/runs --repeat 1 --vs f2d2ceb --pairs 3
    PYTHONPATH=. python benchmarks/bench_replay.py --runs /tmp/q/runs --vs f2d2ceb --replay-jobs 1
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from paired import add_vs_argument, compare, worktree

from lagrseq.analysis import costs, loading
from lagrseq.analysis.replay import replay
from lagrseq.logs.reader import ReadStats, read_topics

TARGET_PER_MINUTE = 1_000_000


def make_full_suite(out: Path, jobs: int) -> Path:
    command = [
        sys.executable,
        "-m",
        "lagrseq",
        "reproduce",
        "--out",
        str(out),
        "--jobs",
        str(jobs),
        "--quiet",
    ]
    print("making the full suite's logs:", " ".join(command[1:]), flush=True)
    subprocess.run(command, check=True)
    return out / "runs"


def chunk_census(paths: list[Path]) -> tuple[int, int, int]:
    """(chunks, chunks holding /transition, chunks holding /transition and /episode or /query)."""
    total = transition = mixed = 0
    for path in paths:
        with path.open("rb") as handle:
            summary = make_reader(handle).get_summary()
        assert summary is not None
        ids = {topic: cid for cid, ch in summary.channels.items() for topic in [ch.topic]}
        for index in summary.chunk_indexes:
            total += 1
            channels = index.message_index_offsets.keys()
            has_transition = ids.get("/transition") in channels
            transition += has_transition
            mixed += has_transition and bool({ids.get("/episode"), ids.get("/query")} & channels)
    return total, transition, mixed


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--runs", type=Path, default=None, help="existing logs (default: make the full suite's)"
    )
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument(
        "--repeat", type=int, default=3, help="timed repetitions (best is reported)"
    )
    parser.add_argument(
        "--replay-jobs", type=int, default=None,
        help="with --vs: this tree's `lagrseq replay --jobs` (default: its default, the cores, at most 8)",
    )
    parser.add_argument(
        "--ref-jobs", type=int, default=None,
        help="with --vs: REF's `lagrseq replay --jobs` (a REF that has the option; f2d2ceb has not)",
    )
    add_vs_argument(parser)
    args = parser.parse_args()

    if args.vs and args.runs is not None:  # the paired comparison alone
        run_vs(args.runs.absolute(), args.vs, args.pairs, args.replay_jobs, args.ref_jobs)
        return
    with tempfile.TemporaryDirectory(prefix="lagrseq-bench-") as scratch:
        runs = (
            args.runs
            if args.runs is not None
            else make_full_suite(Path(scratch) / "suite", args.jobs)
        )
        files = sorted(runs.rglob("*.mcap"))
        size = sum(p.stat().st_size for p in files)
        logs = loading.load([runs])
        transitions = logs.messages.get("/transition", 0)
        print(f"logs: {len(files)} files, {size / 1e6:.1f} MB, {len(logs.runs)} runs")
        print(
            "messages: " + ", ".join(f"{topic} {count}" for topic, count in logs.messages.items())
        )

        best = float("inf")
        for i in range(args.repeat):
            started = time.perf_counter()
            replay([runs], Path(scratch) / f"report-{i}")
            best = min(best, time.perf_counter() - started)
        rate = transitions / best * 60
        verdict = "meets" if rate >= TARGET_PER_MINUTE else "MISSES"
        print(
            f"replay (all figures, tables, costs, index.html): {best:.2f} s = "
            f"{rate / 1e6:.1f} M transitions/min ({verdict} the {TARGET_PER_MINUTE / 1e6:.0f} M/min target)"
        )

        total, transition_chunks, mixed = chunk_census(files)
        started = time.perf_counter()
        for_costs = loading.load([runs])
        costs.by_run(for_costs.runs)
        costs.by_method(for_costs.runs)
        costs_seconds = time.perf_counter() - started
        stats = for_costs.stats
        print(
            f"costs tables (/query + metadata): {costs_seconds:.2f} s; decompressed "
            f"{stats.chunks_decompressed} of {stats.chunks} chunks ({stats.bytes_decompressed / 1e6:.1f} MB); "
            f"the logs have {transition_chunks} transition chunks, {mixed} of them shared with "
            f"/episode or /query, so {mixed} transition chunks were decompressed"
        )
        assert total == stats.chunks

        all_stats = ReadStats()
        started = time.perf_counter()
        decoded = sum(len(read_topics(p, ["/transition"], all_stats)["/transition"]) for p in files)
        full = time.perf_counter() - started
        print(
            f"full /transition decode, for comparison: {decoded} transitions in {full:.2f} s = "
            f"{decoded / full * 60 / 1e6:.1f} M/min; decompressed {all_stats.chunks_decompressed} chunks "
            f"({all_stats.bytes_decompressed / 1e6:.1f} MB)"
        )
        if args.vs:
            run_vs(runs.absolute(), args.vs, args.pairs, args.replay_jobs, args.ref_jobs)


def run_vs(runs: Path, ref: str, pairs: int, jobs: int | None = None, ref_jobs: int | None = None) -> None:
    """Paired runs of ``lagrseq replay RUNS``; ``jobs`` / ``ref_jobs``: this tree's / REF's
    ``--jobs`` (default: none given; ``f2d2ceb`` has no ``--jobs``, it reads in one process)."""

    def command(scratch: Path, given: int | None) -> list[str]:
        line = [sys.executable, "-m", "lagrseq", "replay", str(runs), "--out", str(scratch / "report")]
        return [*line, *(["--jobs", str(given)] if given is not None else [])]

    flags = [f"{who} with --jobs {n}" for who, n in (("here", jobs), (ref, ref_jobs)) if n is not None]
    flag = f" ({', '.join(flags)})" if flags else ""
    print(f"whole process, lagrseq replay of {runs}, here vs {ref}{flag} ({pairs} alternating pairs):")
    with worktree(ref) as tree:
        paired = compare(lambda s: command(s, ref_jobs), tree, pairs, here=lambda s: command(s, jobs))
        print(paired.line("replay", ref))


if __name__ == "__main__":
    main()
