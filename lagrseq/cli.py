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
    from lagrseq.tasks.cube import PROFILE_HELP

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
    p.add_argument(
        "--provider",
        default="mock",
        metavar="SPEC",
        help=(
            "LLM provider (default: mock): mock = the rule-based extrapolator (no key, no network); "
            f"mock:PROFILE = a profile of it ({'; '.join(f'{k}: {v}' for k, v in PROFILE_HELP.items())}); recorded:STORE = "
            "answers recorded in the directory STORE (see --on-miss); live or live:MODEL = an "
            "OpenAI-compatible server (see --base-url; MODEL overrides llm.model)"
        ),
    )
    p.add_argument("--trials", type=int, default=10, help="number of independent trials (default 10)")
    p.add_argument("--seed", type=int, default=0, help="run seed; trial k uses a stream spawned from (seed, k) (default 0)")
    p.add_argument("--out", type=Path, default=Path("runs"), help="output directory (default: runs)")
    p.add_argument("--name", default=None, help="run directory name (default: preset-provider-seed-digest)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE.toml", help="a TOML file of [section] fields applied over the preset")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override one field (repeatable), e.g. --set env.horizon=100")
    p.add_argument("--jobs", type=int, default=1, help="trials run in parallel processes (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--on-miss",
        choices=("error", "mock", "live"),
        default="error",
        help=(
            "recorded:STORE only, a query the store has no answer for: error = stop with a message "
            "naming the nearest recorded keys (default); mock = answer it with the rule-based mock "
            "(not stored); live = ask the live server and record the answer into STORE"
        ),
    )
    _add_live_options(p, per="trial")


def _add_live_options(p: Any, per: str) -> None:
    """Options of the live provider and its budget (run and record)."""
    from lagrseq.llm.servers import DEFAULT_BASE_URL, SERVER_KINDS

    p.add_argument("--base-url", default=DEFAULT_BASE_URL, metavar="URL", help=f"API root of an OpenAI-compatible server; its host is part of every recorded key (default: {DEFAULT_BASE_URL})")
    p.add_argument("--api-key-env", default="OPENAI_API_KEY", metavar="NAME", help="environment variable that holds the API key (default: OPENAI_API_KEY); the key itself is never written anywhere")
    p.add_argument("--server", choices=tuple(SERVER_KINDS), default="openai", help="kind of server: openai and vllm return n samples per request, ollama and llama.cpp one (default: openai)")
    p.add_argument("--price-table", default=None, metavar="FILE.toml", help="prices (USD per million tokens, with source and date) over the built-in table")
    p.add_argument("--max-cost-usd", type=float, default=None, metavar="X", help=f"per {per}: stop before a live request that could take the spending past X US dollars (worst case: every completion uses max_tokens)")
    p.add_argument("--max-queries", type=int, default=None, metavar="N", help=f"per {per}: stop before a live request that would take the number of live answers past N")


def _provider_options(args: argparse.Namespace) -> Any:
    from lagrseq.experiment import ProviderOptions

    if args.max_cost_usd is not None and args.max_cost_usd < 0:
        raise UsageError(f"--max-cost-usd must be at least 0, got {args.max_cost_usd}")
    if args.max_queries is not None and args.max_queries < 0:
        raise UsageError(f"--max-queries must be at least 0, got {args.max_queries}")
    return ProviderOptions(
        base_url=args.base_url,
        api_key_env=args.api_key_env,
        server=args.server,
        on_miss=getattr(args, "on_miss", "error"),
        price_table=args.price_table,
        max_cost_usd=args.max_cost_usd,
        max_queries=args.max_queries,
    )


def _add_task_config(p: Any) -> None:
    from lagrseq.config import PRESETS

    p.add_argument("--preset", choices=PRESETS, default="upstream", help="preset the task and [llm] settings come from (default: upstream)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE.toml", help="a TOML file of [section] fields applied over the preset")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override one field (repeatable), e.g. --set task.stack_size=11")


def _add_record(sub: Any) -> None:
    from lagrseq.config import tasks
    from lagrseq.llm.servers import RECORD_MODES

    p = sub.add_parser(
        "record",
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
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("task", metavar="TASK", choices=tasks(), help=f"one of: {', '.join(tasks())}")
    p.add_argument("--store", type=Path, required=True, metavar="STORE", help="store directory (created if missing)")
    p.add_argument("--model", default=None, help="model to ask (default: the preset's llm.model)")
    p.add_argument("--temperature", type=float, default=None, metavar="T", help="sampling temperature (default: the preset's llm.temperature)")
    p.add_argument("--samples", type=int, default=10, metavar="K", help="answers to keep per prompt (default 10, as the paper's authors recorded)")
    p.add_argument("--mode", choices=RECORD_MODES, default="new", help="new: top every prompt up to K answers (default); once: record only into an empty store; none: ask nothing, report what is missing; all: ask K fresh answers for every prompt even if recorded")
    p.add_argument("--from-runs", nargs="+", default=None, metavar="RUN", help="MCAP logs or directories: ask from the states met there instead of the default prompt set")
    p.add_argument("--states-from", choices=("/query", "/transition"), default="/query", help="with --from-runs: the states of /query records (where a query was decided, default) or of every /transition")
    _add_task_config(p)
    _add_live_options(p, per="recording")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_cache(sub: Any) -> None:
    from lagrseq.config import tasks

    p = sub.add_parser(
        "cache",
        help="import, export or list recorded answers (JSONL, the authors' pickles)",
        description="Move recorded answers between a store directory and portable files.",
    )
    actions = p.add_subparsers(dest="action", metavar="ACTION", parser_class=_Parser, required=True)
    imp = actions.add_parser(
        "import",
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
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    imp.add_argument("file", type=Path, metavar="FILE", help="FILE.jsonl (a lagrseq export) or an authors' cache pickle")
    imp.add_argument("--store", type=Path, required=True, metavar="STORE", help="store directory (created if missing)")
    imp.add_argument("--format", choices=("auto", "jsonl", "pkl"), default="auto", help="auto: .jsonl is JSONL, anything else a pickle (default)")
    imp.add_argument("--task", choices=tasks(), default=None, help="pickles: the task whose prompts the keys are rendered with")
    imp.add_argument("--model", default=None, help="pickles: the model the answers came from (keys include it)")
    imp.add_argument("--temperature", type=float, default=None, metavar="T", help="pickles: the temperature they were sampled at")
    imp.add_argument("--max-tokens", type=int, default=None, metavar="N", help="pickles: max tokens of the keys (default: the preset's llm.max_tokens, what runs send)")
    from lagrseq.llm.servers import DEFAULT_BASE_URL

    imp.add_argument("--base-url", default=DEFAULT_BASE_URL, metavar="URL", help=f"pickles: the server they came from; its host goes into the keys (default: {DEFAULT_BASE_URL})")
    _add_task_config(imp)
    exp = actions.add_parser(
        "export",
        help="write every recorded answer of a store to JSONL",
        description="Write STORE as JSONL, one answer per line, in a stable order (keys sorted, answers in recorded order).",
    )
    exp.add_argument("--store", type=Path, required=True, metavar="STORE")
    exp.add_argument("--out", required=True, metavar="FILE.jsonl", help="output file, or - for standard output")
    lst = actions.add_parser("list", help="one line per recorded key", description="List the keys of STORE: key, task, model, temperature, samples, the partial pattern's end of the prompt.")
    lst.add_argument("--store", type=Path, required=True, metavar="STORE")


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
    p.add_argument("--price-table", default=None, metavar="FILE.toml", help="re-cost every logged query's token usage with these prices over the built-in dated table")


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
    p.add_argument("--price-table", default=None, metavar="FILE.toml", help="re-cost every logged query's token usage with these prices over the built-in dated table")
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
    _add_record(sub)
    _add_cache(sub)
    _add_reproduce(sub)
    _add_replay(sub)
    _add_recover(sub)
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
    options = _provider_options(args)
    if args.on_miss != "error" and not args.provider.startswith("recorded:"):
        raise UsageError(f"--on-miss {args.on_miss} applies to --provider recorded:STORE only")
    config = cfg.load(args.task, args.method, args.preset, args.config, args.overrides)
    config = experiment.with_provider_model(config, args.provider)
    missing = experiment.missing_dependency(config)
    if missing:
        raise UsageError(f"{args.task} {missing}")
    experiment.check_provider(args.provider, config, options)
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
            config,
            args.trials,
            args.seed,
            args.provider,
            directory,
            jobs=args.jobs,
            progress=bar,
            provider_options=options,
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


def _warn(command: str) -> Any:
    return lambda message: print(f"lagrseq {command}: warning: {message}", file=sys.stderr)


def cmd_record(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import numpy as np
    from tqdm import tqdm

    from lagrseq import config as cfg
    from lagrseq import experiment
    from lagrseq.errors import BudgetExceeded
    from lagrseq.llm.recorded import RecordingProvider, record_queries
    from lagrseq.llm.store import RecordStore, endpoint_of, query_key

    if args.samples < 1:
        raise UsageError(f"--samples must be at least 1, got {args.samples}")
    if args.temperature is not None and args.temperature < 0:
        raise UsageError(f"--temperature must be at least 0, got {args.temperature}")
    options = _provider_options(args)
    config = cfg.load(args.task, "lagr", args.preset, args.config, args.overrides)
    llm = replace(
        config.llm,
        model=args.model or config.llm.model,
        temperature=config.llm.temperature if args.temperature is None else args.temperature,
    )
    config = replace(config, llm=llm)
    queries = experiment.record_queries(
        config, experiment.record_patterns(config, args.from_runs or (), args.states_from)
    )
    endpoint = endpoint_of(options.base_url)

    def held(store: RecordStore) -> int:
        entries = [store.entry(query_key(q, endpoint)[0]) for q in queries]
        return sum(1 for e in entries if e is not None and len(e.samples) >= args.samples)

    def missing(full: int) -> UsageError:
        return UsageError(
            f"{len(queries) - full} of {len(queries)} prompts have fewer than {args.samples} answers "
            f"in {args.store} (record mode {args.mode}); run with --mode new to top them up"
        )

    if args.mode == "none":  # ask nobody (no key needed): report what the store lacks
        with RecordStore(args.store, create=False) as store:
            full = held(store)
        if full < len(queries):
            raise missing(full)
        print(f"all {len(queries)} prompts hold at least {args.samples} answers in {args.store}")
        return 0
    bar = tqdm(
        total=len(queries),
        unit="prompt",
        desc=f"record {args.task} {llm.model} t={llm.temperature:g}",
        disable=args.quiet,
        file=sys.stderr,
        dynamic_ncols=True,
    )
    # The retry jitter's generator: seeded per process, so concurrent recorders back off apart.
    jitter = np.random.default_rng([os.getpid()])
    live = experiment.make_live(options, jitter, budgeted=True, on_retry=lambda m: bar.write(f"  {m}"))
    budget = live.budget

    def show(_answers: Any) -> None:
        unpriced = f", {budget.unpriced} unpriced" if budget.unpriced else ""
        bar.set_postfix_str(f"{budget.answers} new answers, ${budget.spent_usd:.4f}{unpriced}")

    stopped: BudgetExceeded | None = None
    with RecordingProvider(RecordStore(args.store), live, endpoint, args.mode, args.samples) as recorder:
        try:
            with bar:
                record_queries(recorder, queries, on_answers=show, on_query=lambda _q: bar.update(1))
        except BudgetExceeded as exc:
            stopped = exc
        full = held(recorder.store)
    print(
        f"{full}/{len(queries)} prompts hold at least {args.samples} answers in {args.store}; "
        f"spent ${budget.spent_usd:.4f} on {budget.answers} new answers"
        + (f" ({budget.unpriced} with no price)" if budget.unpriced else "")
    )
    if stopped is not None:
        raise stopped
    if full < len(queries):
        raise missing(full)
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    return {"import": _cache_import, "export": _cache_export, "list": _cache_list}[args.action](args)


def _cache_import(args: argparse.Namespace) -> int:
    from lagrseq.llm.store import RecordStore, import_jsonl

    fmt = args.format if args.format != "auto" else ("jsonl" if args.file.suffix == ".jsonl" else "pkl")
    if not args.file.is_file():
        raise UsageError(f"{args.file}: no such file")
    if fmt == "jsonl":
        with RecordStore(args.store) as store, args.file.open(encoding="utf-8") as handle:
            lines = import_jsonl(handle, store, args.file.name, warn=_warn("cache import"))
        print(f"{args.file}: {lines.lines} answers under {lines.keys} keys; {lines.added} added, {lines.already_present} already in {args.store}")
        return 0
    missing = [flag for flag, value in (("--task", args.task), ("--model", args.model), ("--temperature", args.temperature)) if value is None]
    if missing:
        raise UsageError(f"importing a pickle needs {', '.join(missing)}: the authors' caches do not record them")
    from dataclasses import replace

    from lagrseq import config as cfg
    from lagrseq import experiment
    from lagrseq.llm.authors_cache import import_authors_cache
    from lagrseq.llm.store import endpoint_of

    config = cfg.load(args.task, "lagr", args.preset, args.config, args.overrides)
    max_tokens = config.llm.max_tokens if args.max_tokens is None else args.max_tokens
    config = replace(config, llm=replace(config.llm, model=args.model, temperature=args.temperature, max_tokens=max_tokens))
    with RecordStore(args.store) as store:
        report = import_authors_cache(
            args.file,
            store,
            experiment.prompt_function(config),
            task=args.task,
            model=args.model,
            temperature=args.temperature,
            endpoint=endpoint_of(args.base_url),
            max_tokens=max_tokens,
            warn=_warn("cache import"),
        )
    print(
        f"{args.file}: {report.pairs} pairs; {report.imported} answers added under {report.keys} keys, "
        f"{report.already_present} already in {args.store}, {report.skipped} skipped"
    )
    return 0


def _cache_export(args: argparse.Namespace) -> int:
    from lagrseq.llm.store import RecordStore, export_jsonl

    with RecordStore(args.store, create=False) as store:
        if args.out == "-":
            report = export_jsonl(store, sys.stdout)
        else:
            out = Path(args.out)
            partial = out.with_name(out.name + ".partial")
            try:
                with partial.open("w", encoding="utf-8") as handle:
                    report = export_jsonl(store, handle)
                os.replace(partial, out)
            except OSError as exc:
                raise UsageError(f"cannot write {out}: {exc.strerror or exc}") from None
    if args.out != "-":
        print(f"{report.lines} answers under {report.keys} keys written to {args.out}")
    return 0


def _cache_list(args: argparse.Namespace) -> int:
    from lagrseq.llm.store import RecordStore

    with RecordStore(args.store, create=False) as store:
        for entry in store.entries():
            r = entry.request
            tail = " ".join(entry.prompt.split())[-48:]
            print(f"{entry.key[:12]}  {entry.task or '-'}  {r['model']}  t={r['temperature']}  {r['endpoint']}  {len(entry.samples):3d} samples  ...{tail}")
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


def _price_function(price_table: str | None) -> Any:
    """``(model, prompt tokens, completion tokens) -> USD or None`` from the dated price table, for
    replay's costs tables (analysis never imports the provider layer itself)."""
    from lagrseq.llm.base import Usage
    from lagrseq.llm.pricing import PriceTable, read_price_table

    table = read_price_table(price_table) if price_table else PriceTable()
    return lambda model, prompt, completion: table.cost(Usage(prompt, completion), model)


def cmd_replay(args: argparse.Namespace) -> int:
    import time

    from lagrseq.analysis.replay import replay
    from lagrseq.suite import load_suite

    started = time.perf_counter()
    suite = load_suite(args.suite)
    report = replay(
        args.runs, args.out, args.formats, suite, provider=args.provider, price=_price_function(args.price_table)
    )
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
    # the bar counts episodes of cube runs and environment steps of grid runs
    with tqdm(total=total, unit="it", disable=args.quiet, file=sys.stderr, dynamic_ncols=True) as bar:
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
        price=_price_function(args.price_table),
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
    "record": cmd_record,
    "cache": cmd_cache,
    "recover": cmd_recover,
    "replay": cmd_replay,
    "reproduce": cmd_reproduce,
}
INTERRUPTED = {
    "run": "finished trial logs are kept",
    "record": "answers recorded so far are kept in the store; run the same command to go on",
    "reproduce": "finished trial logs are kept; run the same command to go on",
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
        kept = INTERRUPTED.get(args.command, "nothing finished is lost")
        print(f"lagrseq {args.command}: interrupted; {kept}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # pragma: no cover - e.g. piped into head
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
