"""The ``lagrseq`` command line. Exit status: 0 success, 2 bad usage or bad input (one line on
stderr), 1 an unexpected failure."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

from lagrseq import __version__
from lagrseq.errors import LagrseqError, UsageError

TASKS_HELP = "cube-stacking"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (the usage block is what --help is for)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _add_run(sub: Any) -> None:
    from lagrseq.config import METHODS, PRESETS, tasks

    p = sub.add_parser(
        "run",
        help="run trials of one task and method, logging every step to MCAP",
        description=(
            "Run TRIALS independent trials of one experiment and write one MCAP log per trial to "
            "OUT/<task>/<method>/<preset>-<provider>-seed<S>-<config digest>/trial-NNN.mcap. "
            "Trials whose log is complete are skipped, so an interrupted run can be resumed."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq run cube-stacking --method lagr-seq --preset upstream --trials 10 --out runs\n"
            "  lagrseq run cube-stacking --method lagr --set env.horizon=100 --set llm.temperature=1.0\n"
            "  lagrseq run cube-stacking --method baseline --set task.stack_size=11\n"
            "  lagrseq config cube-stacking --preset paper     # every field, its value and meaning"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("task", metavar="TASK", choices=tasks(), help=f"one of: {', '.join(tasks())}")
    p.add_argument("--method", choices=METHODS, default="lagr-seq", help="baseline: the plain RL agent; lagr: query the LLM whenever triggered; lagr-seq: the secondary agent decides (default)")
    p.add_argument("--preset", choices=PRESETS, default="upstream", help="upstream: as the released code runs; paper: as the paper's text says (default: upstream)")
    p.add_argument("--provider", default="mock", metavar="SPEC", help="LLM provider: mock (the rule-based extrapolator; no key, no network). Default: mock")
    p.add_argument("--trials", type=int, default=10, help="number of independent trials (default 10)")
    p.add_argument("--seed", type=int, default=0, help="run seed; trial k uses a stream spawned from (seed, k) (default 0)")
    p.add_argument("--out", type=Path, default=Path("runs"), help="output directory (default: runs)")
    p.add_argument("--name", default=None, help="run directory name (default: preset-provider-seed-digest)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE.toml", help="a TOML file of [section] fields applied over the preset")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override one field (repeatable), e.g. --set env.horizon=100")
    p.add_argument("--jobs", type=int, default=1, help="trials run in parallel processes (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_config(sub: Any) -> None:
    from lagrseq.config import METHODS, PRESETS, tasks

    p = sub.add_parser(
        "config",
        help="print the resolved configuration of an experiment, with each field's meaning",
        description="Print every field of the resolved configuration as TOML, with its docstring.",
    )
    p.add_argument("task", metavar="TASK", choices=tasks(), help=f"one of: {', '.join(tasks())}")
    p.add_argument("--method", choices=METHODS, default="lagr-seq")
    p.add_argument("--preset", choices=PRESETS, default="upstream")
    p.add_argument("--config", type=Path, default=None, metavar="FILE.toml")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE")


def _formats(text: str) -> list[str]:
    return [f.strip() for f in text.split(",") if f.strip()]


def _add_replay(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="rebuild the paper's figures, tables and costs from MCAP logs (offline)",
        description=(
            "Read MCAP logs only (no network, no LLM, no torch or gymnasium) and write, for every "
            "figure and table of the paper's suite the logs cover: figures/ID.png (SVG/PDF with "
            "--formats) with the numbers behind each as CSV, tables/ID.md and .csv, the LLM costs "
            "per run and per method, a table of the runs, and index.html showing all of it. The "
            "same logs always give the same bytes. Unfinished or damaged logs are skipped with a "
            "one-line warning."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq replay runs --out reports\n"
            "  lagrseq replay runs/cube-stacking other-runs --out /tmp/report --formats png,svg,pdf"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("runs", nargs="+", type=Path, metavar="RUNS", help="MCAP files or directories searched for *.mcap")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument("--formats", type=_formats, default=["png"], metavar="png,svg,pdf", help="figure formats; PNG is always written (default: png)")
    p.add_argument("--provider", default=None, metavar="SPEC", help="use only runs of this provider for the suite's default-provider runs (default: any, preferring mock)")
    p.add_argument("--suite", type=Path, default=None, metavar="FILE.toml", help="a suite file instead of the packaged paper suite")


def _add_reproduce(sub: Any) -> None:
    p = sub.add_parser(
        "reproduce",
        help="run the paper's suite and build its report (figures, tables, costs)",
        description=(
            "Run every experiment of the paper's suite (lagrseq/experiments/paper_suite.toml) into "
            "OUT/runs, then replay the logs into OUT/reports (index.html, figures, tables). Reports "
            "the expected time before starting and shows progress; trials run in parallel on local "
            "cores; a rerun skips trials whose log is complete. Items whose task or provider is not "
            "available here are not run, with one line saying why."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq reproduce --quick                # ./runs and ./reports, a few minutes\n"
            "  lagrseq reproduce --out results --jobs 8\n"
            "  lagrseq reproduce --provider recorded:recorded_llm/cube.jsonl --items table2"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="fewer trials, episodes and probe samples where it matters (each item's quick_* length)")
    p.add_argument("--out", type=Path, default=Path("."), metavar="DIR", help="writes DIR/runs and DIR/reports (default: .)")
    p.add_argument("--provider", default=None, metavar="SPEC", help="provider of the suite's default-provider runs (default: the suite's, mock)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--seed", type=int, default=None, help="run seed (default: the suite's, 0)")
    p.add_argument("--items", default=None, metavar="ID,ID", help="only these suite items (default: all)")
    p.add_argument("--suite", type=Path, default=None, metavar="FILE.toml", help="a suite file instead of the packaged paper suite")
    p.add_argument("--formats", type=_formats, default=["png"], metavar="png,svg,pdf", help="figure formats; PNG is always written")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_recover(sub: Any) -> None:
    p = sub.add_parser(
        "recover",
        help="repair a crash-truncated MCAP log, keeping every flushed episode",
        description=(
            "Rewrite the readable part of a log cut short by a crash (NAME.mcap.partial) as a valid "
            "MCAP file NAME.mcap holding every episode flushed before the crash, marked with status "
            "'recovered'. A NAME.mcap is repaired in place and its original kept as "
            "NAME.mcap.truncated. A file damaged in the middle (not cut short) is refused."
        ),
    )
    p.add_argument("files", nargs="+", type=Path, metavar="FILE", help="truncated .mcap or .mcap.partial files")
    p.add_argument("--out", type=Path, default=None, metavar="PATH", help="where to write the recovered log (one FILE only)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lagrseq",
        description=(
            "LaGR-SEQ reproducibility toolkit: run RL agents guided by (mock, recorded or live) "
            "LLM answers, log every step to MCAP, and rebuild the paper's results offline."
        ),
    )
    parser.add_argument("--version", action="version", version=f"lagrseq {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _add_run(sub)
    _add_config(sub)
    _add_recover(sub)
    _add_replay(sub)
    _add_reproduce(sub)
    return parser


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def cmd_config(args: argparse.Namespace) -> int:
    import dataclasses

    from lagrseq import config as cfg

    resolved = cfg.load(args.task, args.method, args.preset, args.config, args.overrides)
    print(f"# lagrseq {args.task}, method {args.method}, preset {args.preset}")
    print(f'method = "{resolved.method}"')
    for section in dataclasses.fields(resolved):
        value = getattr(resolved, section.name)
        if not dataclasses.is_dataclass(value):
            continue
        docs = cfg.field_docs(type(value))
        print(f"\n[{section.name}]")
        for f in dataclasses.fields(value):
            doc = docs.get(f.name, "")
            print(f"{f.name} = {_toml_value(getattr(value, f.name))}" + (f"  # {doc}" if doc else ""))
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from lagrseq import config as cfg
    from lagrseq import experiment

    if args.trials < 1:
        raise UsageError(f"--trials must be at least 1, got {args.trials}")
    if args.jobs < 1:
        raise UsageError(f"--jobs must be at least 1, got {args.jobs}")
    experiment.parse_provider(args.provider)
    config = cfg.load(args.task, args.method, args.preset, args.config, args.overrides)
    directory = experiment.run_directory(args.out, config, args.provider, args.seed, args.name)
    total = args.trials * config.run.episodes
    with tqdm(
        total=total,
        unit="ep",
        desc=f"{args.task} {args.method}",
        disable=args.quiet,
        file=sys.stderr,
        dynamic_ncols=True,
    ) as bar:
        results = experiment.run_trials(
            config, args.trials, args.seed, args.provider, directory, jobs=args.jobs, progress=bar
        )
    ran = [r for r in results if not r.skipped]
    skipped = len(results) - len(ran)
    print(f"{len(results)} trial logs in {directory}" + (f" ({skipped} already complete, skipped)" if skipped else ""))
    if ran:
        import numpy as np

        queries = np.array([r.queries for r in ran], dtype=float)
        returns = np.array([r.total_return for r in ran], dtype=float)
        se = queries.std(ddof=1) / np.sqrt(len(ran)) if len(ran) > 1 else 0.0
        print(
            f"queries per trial {queries.mean():.1f} +- {se:.2f} (s.e.), "
            f"return per trial {returns.mean():.1f}, "
            f"{np.mean([r.seconds for r in ran]):.2f} s per trial"
        )
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from lagrseq.logs.recover import recover

    if args.out is not None and len(args.files) > 1:
        raise UsageError("--out works with one FILE only")
    for path in args.files:
        print(recover(path, args.out).summary())
    return 0


def _print_report(report: Any, elapsed: float | None = None, not_run_said: bool = False) -> None:
    made = [r for r in report.items if r.status != "not run"]
    for r in report.items:
        if r.status == "not run":
            if not_run_said:
                continue
            print(f"{r.item.id}: {r.not_run_line()}")
        elif r.status == "partial":
            print(f"{r.item.id}: partial; missing {'; '.join(r.missing())}")
    for warning in report.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    took = f" in {elapsed:.1f} s" if elapsed is not None else ""
    print(f"{len(made)} of {len(report.items)} suite items made from {report.logs.files} logs{took}: {report.out / 'index.html'}")


def cmd_replay(args: argparse.Namespace) -> int:
    import time

    from lagrseq.analysis.replay import replay
    from lagrseq.suite import load_suite

    started = time.perf_counter()
    suite = load_suite(args.suite)
    report = replay(args.runs, args.out, args.formats, suite, provider=args.provider)
    _print_report(report, time.perf_counter() - started)
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    import time

    from tqdm import tqdm

    from lagrseq import reproduce
    from lagrseq.analysis.replay import replay
    from lagrseq.suite import load_suite

    if args.jobs < 1:
        raise UsageError(f"--jobs must be at least 1, got {args.jobs}")
    suite = load_suite(args.suite)
    if args.items:
        suite = suite.select([i.strip() for i in args.items.split(",") if i.strip()])
    seed = suite.seed if args.seed is None else args.seed
    if args.provider is not None:
        from lagrseq import experiment

        experiment.parse_provider(args.provider)
    runs_dir = args.out / "runs"
    reports_dir = args.out / "reports"
    started = time.perf_counter()
    the_plan = reproduce.plan(suite, args.quick, args.provider, runs_dir, seed)
    for item_id, reason in the_plan.not_run.items():
        print(f"{item_id}: not run: {reason}")
    pending = sum(run.pending() for run in the_plan.runs)
    trials = sum(run.trials if run.kind == "trial" else 1 for run in the_plan.runs)
    expected = reproduce.estimate(the_plan, args.jobs)
    print(
        f"{'quick' if args.quick else 'full'} suite: {len(the_plan.runs)} runs, {trials} trial logs, "
        f"{pending} to run ({trials - pending} already complete); expected about "
        f"{_duration(expected)} on {args.jobs} process{'es' if args.jobs > 1 else ''} "
        f"(timed on this machine; LLM latency of live providers not included)",
        flush=True,
    )
    total = sum(run.units() for run in the_plan.runs)
    with tqdm(total=total, unit="ep", disable=args.quiet, file=sys.stderr, dynamic_ncols=True) as bar:
        reproduce.execute(
            the_plan,
            args.jobs,
            bar,
            on_run=lambda run: bar.set_description(run.describe()),
        )
    ran = time.perf_counter() - started
    print(f"runs done in {_duration(ran)}: {runs_dir}", flush=True)
    command = "lagrseq reproduce" + (" --quick" if args.quick else "")
    report = replay(
        [runs_dir],
        reports_dir,
        args.formats,
        suite,
        provider=args.provider or suite.provider,
        unavailable=the_plan.unavailable,
        produced_by=command,
    )
    _print_report(report, time.perf_counter() - started, not_run_said=True)
    return 0


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


COMMANDS = {
    "run": cmd_run,
    "config": cmd_config,
    "recover": cmd_recover,
    "replay": cmd_replay,
    "reproduce": cmd_reproduce,
}


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return COMMANDS[args.command](args)
    except LagrseqError as exc:
        print(f"lagrseq {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"lagrseq {args.command}: interrupted; finished trial logs are kept", file=sys.stderr)
        return 130
    except BrokenPipeError:  # pragma: no cover - e.g. piped into head
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
