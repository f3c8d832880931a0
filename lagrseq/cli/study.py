"""``lagrseq frontier``, ``audit`` and ``screen``: studies beyond one run."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from lagrseq.cli.options import (
    _COUNT,
    _N,
    _SEED,
    _TEMPERATURE,
    _experiment_options,
    _provider_argument,
    _provider_flags,
    _provider_options,
    _quiet,
    _task_argument,
    takes_provider_flags,
)
from lagrseq.cli.output import _bar, _price_function, _say, _shown, _warn
from lagrseq.errors import UsageError
from lagrseq.progress import Reporter


@takes_provider_flags("frontier")
def _add_frontier(sub: Any) -> None:
    p = sub.add_parser(
        "frontier",
        parents=[_experiment_options(), _provider_flags(per="trial"), _quiet()],
        help="run asking policies on one task and draw return against queries and dollars",
        description=(
            "Run the asking policies on TASK; write figures and verdicts to OUT/frontier/ (docs/frontier.md)."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq frontier cube-stacking --provider recorded:store --stop-at-first-solve --out fr\n"
            "  lagrseq frontier --replay fr --out fr/frontier     # the report again, from the logs"
        ),
    )
    from lagrseq.config import tasks

    p.add_argument("task", metavar="TASK", nargs="?", choices=tasks(), help="the task (not with --replay)")
    p.add_argument("--policies", default="never,always,seq,thompson,oracle", metavar="LIST", help="comma-separated NAME[:FIELD=VALUE] (lagrseq plugins lists the names)")
    p.add_argument("--sweep", action="append", default=[], metavar="N:F=V1,V2", help="one variant per value, a curve (repeatable); FIELD: a knob of NAME")
    _provider_argument(p, "mock", "provider of every run")
    p.add_argument("--trials", type=_COUNT, default=5, help="trials per policy (default 5)")
    p.add_argument("--seed", type=_SEED, default=0, help="run seed (default 0)")
    p.add_argument("--jobs", type=_N["jobs"], default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--out", type=Path, default=Path("frontier"), help="runs go under OUT, the report to OUT/frontier (default: frontier)")
    p.add_argument("--replay", type=Path, default=None, metavar="DIR", help="rebuild the report from the logs under DIR; run nothing")
    p.add_argument("--miss-threshold", type=_N["share"], default=0.1, metavar="F", help="mark points with > F of answers from a fallback (0.1)")
    p.add_argument("--scopes", default="auto", metavar="LIST", help="lagr.solution_scope values: episode, trial (default auto: the task's)")
    p.add_argument("--no-matched-random", dest="matched_random", action="store_false", help="no random run at each policy's query rate (then nothing is credited)")
    p.add_argument("--tune", action="store_true", help="choose each policy's knob on tuning seeds first (logged)")
    p.add_argument("--tune-seed", type=_SEED, default=None, metavar="S", help="run seed of the tuning trials (default: --seed + 1000003)")
    p.add_argument("--tune-trials", type=_COUNT, default=5, metavar="N", help="tuning trials per candidate (default 5)")
    p.add_argument("--stop-at-first-solve", action="store_true", help="end each trial at its first solve")
    p.add_argument("--full-horizon-trials", type=_N["count0"], default=0, metavar="K", help="with --stop-at-first-solve: also K full-length trials per variant")
    p.set_defaults(preset=None)  # cube stacking: paper (the upstream cube pays for wrong cubes); the rest: upstream


def _add_audit(sub: Any) -> None:
    p = sub.add_parser(
        "audit",
        parents=[_quiet()],
        help="measure what each deviation between the upstream and paper presets does",
        description=(
            "For every field where the upstream and paper presets differ (and lagr.solution_scope), "
            "run the upstream preset with only that field set to the paper's value and the paper "
            "preset with only that field set back, for baseline, lagr and lagr-seq; then report each "
            "field's effect on queries with and without SEQ, total return, the performance ratio and "
            "the steps to the first solved episode, with Welch 95% t-intervals and n; marks are "
            "Holm-corrected over the table's comparisons, and runs of fewer than 10 trials are "
            "indicative (never marked). On cube-stacking it also runs the primary's epsilon schedule, "
            "learning on guided steps and the secondary's epsilon schedule switched together (2x2x2) "
            "and reports their interaction contrasts. Writes OUT/runs and "
            "OUT/reports/audit-TASK[-interactions].md/.csv/.png; lagrseq replay rebuilds them from the logs."
        ),
        epilog=(
            "examples:\n  lagrseq audit cube-stacking --trials 10 --episodes 100 --provider mock:authors-t0\n"
            "  lagrseq audit object-arrangement --trials 3 --max-steps 1000 --out audit\n"
            "  lagrseq audit image-completion --provider mock:authors-gpt4 --trials 3 --max-steps 1000"
        ),
    )
    _task_argument(p)
    _provider_argument(p, "mock", "provider of the lagr and lagr-seq runs (the baseline never asks)")
    p.add_argument("--trials", type=_COUNT, default=5, help="trials per run (default 5)")
    p.add_argument("--episodes", type=_N["episodes"], default=0, help="episodes per trial (default 0: the preset's)")
    p.add_argument("--max-steps", type=_N["steps"], default=-1, help="step budget per trial (default -1: the preset's)")
    p.add_argument("--out", type=Path, default=Path("audit"), metavar="DIR", help="writes DIR/runs and DIR/reports (default: ./audit)")
    p.add_argument("--jobs", type=_N["jobs"], default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--seed", type=_SEED, default=0, help="run seed (default 0)")


@takes_provider_flags("screen")
def _add_screen(sub: Any) -> None:
    p = sub.add_parser(
        "screen",
        parents=[_experiment_options(), _provider_flags("screen"), _quiet()],
        help="how often a model is right on a task's prompts: accuracy by prefix or fill fraction, refusals, speed",
        description=(
            "Ask a model N of TASK's prompts (cube stacking: every prefix of the target, each asked "
            "ceil(N / prefixes) times; grid tasks: N distinct states of the MCAP runs of --from-runs, "
            "spread evenly over how much of the target they show, each asked once), keep the answers "
            "as recorded-answer JSONL (--answers), and write a table (Markdown and CSV) and a "
            "Fig. 4-style picture to OUT: accuracy by prefix length or fill fraction with n and a "
            "Wilson 95 percent interval per cell, the kinds of wrong answer, seconds per answer, tokens/s. "
            "With --from FILE.jsonl nothing is asked: the table and picture are rebuilt from answers "
            "recorded before, with neither the local-llm extra nor a model file."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq screen cube-stacking --provider local:qwen2.5-coder-0.5b-instruct-q4_k_m \\\n      --threads 1 --prompts 40 --answers cube.jsonl --out screen/\n"
            "  lagrseq screen object-arrangement --provider local --from-runs runs/object-arrangement \\\n      --prompts 48 --answers arr.jsonl --out screen/\n"
            "  lagrseq screen cube-stacking --provider local:qwen2.5-coder-1.5b-instruct-q4_k_m \\\n      --threads 1 --prompt-set relabelled --prompts 56 \\\n      --answers relabelled.jsonl --out screen/\n"
            "  lagrseq screen cube-stacking --from recorded_llm/screen-*.jsonl --out screen/"
        ),
    )
    _task_argument(p)
    _provider_argument(p, "local", "the model asked (not with --from)", records=True)
    p.add_argument("--prompts", type=_N["prompts"], default=40, metavar="N", help="answers to ask for (default 40)")
    p.add_argument("--temperature", type=_TEMPERATURE, default=0.0, metavar="T", help="sampling temperature, 0 to 2 (default 0)")
    p.add_argument("--from-runs", nargs="+", default=None, metavar="RUN", help="grid tasks: MCAP logs or folders whose /query states are screened")
    p.add_argument(
        "--prompt-set", choices=("prefixes", "relabelled", "runs", "sampled"), default=None, metavar="SET",
        help="cube: prefixes (default), relabelled; grid: runs (default), sampled",
    )
    p.add_argument("--seed", type=_SEED, default=0, metavar="S", help="seeds the relabellings and sampled states (default 0)")
    p.add_argument("--store", type=Path, default=None, metavar="STORE", help="also keep the answers in this store (an interrupted screen resumes)")
    p.add_argument("--answers", type=Path, default=None, metavar="FILE.jsonl", help="where the answers go (default OUT/screen-TASK-MODEL-tT.jsonl)")
    p.add_argument("--from", dest="from_files", nargs="+", type=Path, default=None, metavar="FILE", help="ask nothing: screen these recorded-answer JSONL files")
    p.add_argument("--out", type=Path, required=True, metavar="OUT", help="directory for screen-TASK.md, .csv and .png")


def _refuse_asking_flags(args: argparse.Namespace) -> None:
    """``screen --from`` reads answers: the flags of a screen that asks a model are refused."""
    asked = [flag for flag, given in (("--from-runs", args.from_runs), ("--store", args.store), ("--answers", args.answers), ("--prompt-set", args.prompt_set)) if given]
    if asked:
        raise UsageError(f"--from screens answers recorded before; {', '.join(asked)} belong to a screen that asks a model: leave them out")


def cmd_screen(args: argparse.Namespace) -> int:
    from lagrseq.cli.helpers import model_of
    from lagrseq.running import recording
    from lagrseq.study import screen

    if args.from_files:
        _refuse_asking_flags(args)
        config = recording.record_config(args.task, args.preset, args.config, args.overrides)
        files = list(args.from_files)
    else:
        model = model_of(args.provider, None)
        config = recording.record_config(args.task, args.preset, args.config, args.overrides, model, args.temperature)
        answers = args.answers or args.out / f"screen-{args.task}-{_slug(config.llm.model)}-t{config.llm.temperature:g}.jsonl"
        desc = f"screen {args.task} {config.llm.model} t={config.llm.temperature:g}"
        line = screen.record_screen(
            config, args.provider, args.prompts, args.from_runs or (), args.store, answers, _provider_options(args),
            lambda total: _bar(total, "prompt", desc, args.quiet), Reporter(_say, warn=_warn("screen")), args.prompt_set, args.seed,
        )
        _say(line)
        files = [answers]
    screens = screen.screens_from(files, [config])
    for path in screen.write_screen(screens, args.out, f"screen-{args.task}"):
        _say(f"wrote {path}")
    print("\n".join(screen.markdown(screens)))
    return 0


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "-" for c in text)[:80] or "model"


def cmd_frontier(args: argparse.Namespace) -> int:
    import time

    from lagrseq.analysis.frontier import report
    from lagrseq.study import frontier

    started = time.perf_counter()
    price = _price_function(args.price_table)
    variants = frontier.variants_of(args.policies, args.sweep)  # checked with --replay too: nothing is ignored unseen
    args.preset, args.on_miss = frontier.protocol_defaults(args.task, args.provider, args.preset, args.on_miss)
    out, roots = frontier.runs_or_replay(
        args.task, args.replay, variants, args.provider, None if args.replay else _provider_options(args, elsewhere=("price_table",)), args.out,
        args.trials, args.seed, args.preset, args.config, args.overrides, args.jobs,
        progress=lambda desc, total, unit: _bar(total, unit, desc, args.quiet),
        reporter=Reporter(_say), scopes=args.scopes, matched_random=args.matched_random, tune=frontier.tuning(args.tune, args.seed, args.tune_seed, args.tune_trials),
        stop_at_first_solve=args.stop_at_first_solve, full_horizon_trials=args.full_horizon_trials,
    )
    made = report(roots, out, price, args.miss_threshold)
    for warning in made.warnings:
        print(f"lagrseq frontier: warning: {_shown(warning)}", file=sys.stderr)
    width = max((len(row.label) for found in made.panels for row in found.rows), default=0)
    for found in made.panels:
        print(found.table.title)
        for row in found.rows:
            print(
                f"  {row.label:<{width}} queries {row.queries}; steps to first solve {row.steps}; seed {row.seed_role}; "
                f"vs always: {row.vs_always}; tail: {row.tail} [{row.tail_margins}]; "
                f"vs matched random: {row.vs_random}; credited: {row.credited}"
            )
    print(_shown(f"{len(made.written)} files in {out} ({time.perf_counter() - started:.1f} s)"))
    return 0


def cmd_audit(args: argparse.Namespace) -> int:
    from lagrseq.analysis.tables import to_markdown
    from lagrseq.study.audit import run_audit, warn_on_stderr

    made = run_audit(
        args.task, args.provider, args.trials, args.episodes, args.max_steps, args.out, args.jobs, args.seed,
        ["png"], Reporter(_say, warn=warn_on_stderr, quiet=args.quiet),
    )
    for audit in made:
        for stem, table in ((f"audit-{audit.task}", audit.table), (f"audit-{audit.task}-interactions", audit.interaction_table)):
            if table is not None:
                print(to_markdown(table))
                print(_shown(f"written: {args.out / 'reports' / stem}.md, .csv, .png"))
    return 0
