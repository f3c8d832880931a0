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
            "  lagrseq run image-completion --method lagr-seq --preset paper --trials 2\n"
            "  lagrseq run object-arrangement --method lagr --set task.target=\"square\"\n"
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
    unit, per_trial = experiment.progress_unit(config)
    with tqdm(
        total=args.trials * per_trial,
        unit=unit,
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


COMMANDS = {"run": cmd_run, "config": cmd_config}


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
