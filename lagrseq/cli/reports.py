"""``lagrseq reproduce``, ``replay``, ``compare`` and ``recover``: the paper's report, from runs or logs."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from lagrseq.cli.options import (
    _N,
    _SEED,
    _executor_options,
    _provider_argument,
    _quiet,
    _report_options,
)
from lagrseq.cli.output import _price_function, _print_report, _say, _say_error, _shown
from lagrseq.errors import UsageError

ITEMS_FAILED = 3
"""Exit status of ``reproduce`` when it finished but some items failed (distinct from 2, bad usage
or input, and 130, interrupted)."""


DEFAULT_REPRODUCE_OUT = Path("lagrseq-out")
"""Where ``lagrseq reproduce`` writes by default: a folder of its own (in .gitignore), so that a
run in a clone never touches a tracked file."""


def _add_replay(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        parents=[_report_options()],
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
    )
    p.add_argument("runs", nargs="+", type=Path, metavar="RUNS", help="MCAP files or directories searched for *.mcap")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    _provider_argument(p, None, "only this provider's runs for the default-provider runs", shown="any, mock first")
    p.add_argument("--jobs", type=_N["jobs"], default=None, help="log readers (default: the cores, at most 8); any number, same report")


COMPARE_FLIPPED = 4
"""``lagrseq compare``'s exit status when a verdict differs between the two reports (0: every
verdict agrees; 2: bad usage or a folder that is not a report; 1 stays an unexpected failure)."""


def _add_compare(sub: Any) -> None:
    p = sub.add_parser(
        "compare",
        help="compare two reports by their verdicts (another machine's run against the reference)",
        description=(
            "Read two report folders (what lagrseq replay --out and reproduce write: OUT/reports, "
            "or OUT itself) and print, per scoreboard row and per frontier point, both values with "
            "their 95% intervals and n, whether the intervals overlap and whether the verdicts "
            "agree. Rows in one report only are listed as such. Bytes agree only on one machine; "
            "across machines the verdicts must (docs/reproduce.md). Exit status: 0 every verdict "
            f"agrees, {COMPARE_FLIPPED} a verdict flips, 2 bad usage or a folder that is not a report."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq compare lagrseq-out/reports docs/reference-report\n"
            "  LAGRSEQ_NUMERICS=perturbed lagrseq reproduce --quick --out other \\\n      && lagrseq compare other docs/reference-report --differences\n"
            "  lagrseq compare report-a report-b --csv compare.csv --markdown compare.md"
        ),
    )
    p.add_argument("report_a", type=Path, metavar="REPORT_A", help="a report folder (or an output folder holding reports/)")
    p.add_argument("report_b", type=Path, metavar="REPORT_B", help="the report to compare it with (e.g. docs/reference-report)")
    p.add_argument("--differences", action="store_true", help="print only rows whose verdicts flip or that one report lacks (summary: all)")
    p.add_argument("--csv", type=Path, default=None, metavar="FILE", help="also write the comparison as CSV to FILE (every row)")
    p.add_argument("--markdown", type=Path, default=None, metavar="FILE", help="also write the comparison as a Markdown table to FILE (every row)")


def _add_reproduce(sub: Any) -> None:
    p = sub.add_parser(
        "reproduce",
        parents=[_report_options(), _executor_options(), _quiet()],
        help="run the paper's suite and build its report (figures, tables, costs)",
        description=(
            "Run every experiment of the paper's suite (lagrseq/experiments/paper_suite.toml) into "
            "OUT/runs, then replay the logs into OUT/reports (index.html, figures, tables). Reports "
            "the expected time before starting and shows progress; trials run in parallel on local "
            "cores; a rerun skips trials whose log is complete. Items whose task or provider is not "
            "available here are not run, with one line saying why. A run whose trials fail does not stop "
            "the others: it gets one short line on stderr, its whole error goes to OUT/reproduce-errors.log, "
            "and the items it feeds are marked FAILED on the report's index and scoreboard with the "
            "command that reruns them alone. The whole suite runs the cube-stacking audit; the grid tasks' "
            "audits run on request (--items audit-image-completion, audit-object-arrangement; the report's "
            "audit section says how long each takes here).\n\n"
            "exit status:\n  0 every item made or set aside\n"
            f"  {ITEMS_FAILED} finished, but some items failed (one summary line on stderr)\n"
            "  2 bad usage or input\n  130 interrupted (Ctrl-C)"
        ),
        epilog=(
            "examples:\n"
            "  lagrseq reproduce --quick                # ./lagrseq-out/runs and ./lagrseq-out/reports\n"
            "  lagrseq reproduce --out results --jobs 8\n"
            "  lagrseq reproduce --executor dask --scheduler tcp://head:8786 --out /shared/results\n"
            "  lagrseq reproduce --provider recorded:store/ --items fig6a   # a store from lagrseq cache import\n"
            "  lagrseq reproduce --quick --authors-caches ../LaGRSEQ   # add the authors' recorded GPT answers\n"
            "  lagrseq reproduce --items audit-object-arrangement      # one paper-vs-code audit alone"
        ),
    )
    p.add_argument("--quick", action="store_true", help="fewer trials, episodes and probe samples (each item's quick_* length)")
    p.add_argument("--out", type=Path, default=DEFAULT_REPRODUCE_OUT, metavar="DIR", help=f"writes DIR/runs and DIR/reports (default: {DEFAULT_REPRODUCE_OUT}, untracked)")
    _provider_argument(p, None, "provider of the suite's default-provider runs", shown="the suite's, mock")
    p.add_argument("--jobs", type=_N["jobs"], default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--seed", type=_SEED, default=None, help="run seed (default: the suite's, 0)")
    p.add_argument("--items", default=None, metavar="ID,ID", help="only these suite items (default: all); audit-TASK: that task's audit")
    p.add_argument(
        "--authors-caches", type=Path, default=None, metavar="DIR",
        help="a GKthom/LaGRSEQ clone or its pickles: the authors' GPT answers too",
    )


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
    p.add_argument("--out", type=Path, default=None, metavar="PATH", help="a new file (one FILE) or an existing folder (DIR/NAME.mcap each)")


def cmd_recover(args: argparse.Namespace) -> int:
    from lagrseq.logs.recover import recover_all

    outcomes = recover_all(args.files, args.out)  # one bad file does not stop the others
    for outcome in outcomes:
        if outcome.ok:
            print(_shown(outcome.message))
        else:
            print(f"lagrseq recover: error: {_shown(outcome.message)}", file=sys.stderr)
    return 0 if all(outcome.ok for outcome in outcomes) else 2


def cmd_replay(args: argparse.Namespace) -> int:
    import time

    from lagrseq.analysis.replay import replay
    from lagrseq.paths import writable_directory
    from lagrseq.suite import load_suite, suite_argument

    started = time.perf_counter()
    suite = None if args.suite is None else load_suite(suite_argument(args.suite))  # None: the logged tasks' suites
    price = _price_function(args.price_table)  # every input checked before OUT is made
    out = writable_directory(args.out)
    report = replay(args.runs, out, args.formats, suite, provider=args.provider, price=price, jobs=args.jobs)
    _print_report(report, time.perf_counter() - started)
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from lagrseq import outputs
    from lagrseq.analysis import compare

    wanted = [(flag, path) for flag, path in (("--csv", args.csv), ("--markdown", args.markdown)) if path is not None]
    folders = [compare.report_folder(args.report_a), compare.report_folder(args.report_b)]
    with outputs.outputs(inputs=folders):  # nothing is written into a report it reads
        for flag, path in wanted:  # every output checked before any report is read (docs/security.md)
            if not path.parent.is_dir():
                raise UsageError(f"{flag} {_shown(path)} is not a file in an existing folder; give a file path whose folder exists")
            outputs.check(path, flag)
        comparison = compare.compare(compare.read_report(args.report_a), compare.read_report(args.report_b))
        sys.stdout.write(compare.to_text(comparison, differences_only=args.differences))
        for flag, path in wanted:
            text = compare.to_csv(comparison) if flag == "--csv" else compare.to_markdown(comparison)
            outputs.write_text(path, text, flag)
            print(f"wrote {_shown(path)}")
    if comparison.flips:
        print(f"lagrseq compare: {comparison.flips} verdict(s) flip between the reports (exit status {COMPARE_FLIPPED})", file=sys.stderr)
        return COMPARE_FLIPPED
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from lagrseq.study import reproduce
    from lagrseq.suite import suite_argument

    items = [i.strip() for i in args.items.split(",") if i.strip()] if args.items is not None else None
    request = reproduce.Request(
        suite_argument(args.suite), items, args.quick, args.provider, args.out, args.jobs, args.seed,
        args.formats, _price_function(args.price_table), executor=args.executor, scheduler=args.scheduler,
        retries=args.retries, authors_caches=args.authors_caches,
    )
    done = reproduce.reproduce(request, reproduce.Reporter(_say, _say_error, quiet=args.quiet))
    report, elapsed = done.report, done.elapsed
    failed_runs = [Path(folder).resolve() for f in (*report.failed.values(), *report.problems.values()) for folder in f.folders]

    def said(warning: str) -> bool:  # a failed run's logs: its line was printed when it failed
        return any(Path(warning.split(": ", 1)[0]).is_relative_to(folder) for folder in failed_runs)

    _print_report(report, elapsed, not_run_said=True, width=reproduce.LINE_WIDTH, said=said)
    if report.failed or report.problems:
        summary = reproduce.failure_summary(report.failed, report.problems, len(report.items), args.out)
        print(f"lagrseq reproduce: {summary}", file=sys.stderr)
        return ITEMS_FAILED
    return 0
