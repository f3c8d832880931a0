"""``lagrseq record``: which prompts to ask, the store they go to, the recorder and its budget.

The prompts are exactly those a run sends (same task descriptor, same key), built from every
prefix of a cube target or from the states met in earlier runs' MCAP logs; each is topped up to K
answers in the store by a recording wrapper around the live provider, behind a budget guard.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.config import ExperimentConfig
from lagrseq.errors import BudgetExceeded, LogError, UsageError
from lagrseq.llm.base import Query, samplers_of
from lagrseq.logs.reader import find_logs, read_info, read_topic
from lagrseq.loop.lagr import query_for
from lagrseq.progress import Reporter
from lagrseq.registry import ProviderKind
from lagrseq.running.wiring import make_live, make_task
from lagrseq.tasks.base import Task
from lagrseq.text import shown

STATE_TOPICS = ("/query", "/transition")


def pattern_from(task: Task, value: Any) -> Any:
    """A task pattern from outside data (an authors' cache key, an MCAP ``state``); raises
    ValueError when it does not fit the task. Tasks check shapes with ``coerce_pattern``."""
    coerce = getattr(task, "coerce_pattern", None)
    if coerce is not None:
        return coerce(value)
    array = np.asarray(value)
    return array if array.ndim > 1 else tuple(int(x) for x in array)


def prompt_function(config: ExperimentConfig) -> Callable[[Any], str]:
    """``prompt_for(key)``: the prompt a run sends for an outside pattern (authors' cache import)."""
    task = make_task(config)
    return lambda key: query_for(task, config.llm, pattern_from(task, key)).prompt


def record_patterns(
    config: ExperimentConfig,
    runs: Sequence[str | Path] = (),
    topic: str = "/query",
    reporter: Reporter | None = None,
) -> list[Any]:
    """The patterns ``lagrseq record`` asks about, without duplicates, in first-met order: the
    states of ``topic`` records in the MCAP logs under ``runs`` (``/query``: where the secondary
    agent decided; ``/transition``: every state met), or, with no runs, every prefix of a cube
    target. A damaged log is skipped with a warning to ``reporter`` (None: ``warning: ...`` on
    stderr), as replay skips it."""
    task = make_task(config)
    if not runs:
        prefixes = getattr(task, "prefixes", None)  # a task's own default states (cube stacking's)
        if prefixes is not None:
            return list(prefixes())
        raise UsageError(f"{config.task.name} has no default set of prompts; give runs with --from-runs")
    if topic not in STATE_TOPICS:
        raise UsageError(f"--states-from {topic!r}; expected /query or /transition")
    reporter = reporter or Reporter(warn=lambda message: print(f"warning: {shown(message)}", file=sys.stderr))
    wanted = json.loads(json.dumps(asdict(config.task)))
    patterns: list[Any] = []
    seen: set[str] = set()
    skipped: list[str] = []
    for path in find_logs(runs):
        try:
            logged_task = read_info(path).config.get("task", {})
            if logged_task != wanted:
                raise UsageError(
                    f"{path}: a run of task {logged_task}, not {wanted}; pass matching runs or --set task fields"
                )
            for record in read_topic(path, topic):
                state = record.get("state")
                marker = json.dumps(state)
                if state is None or marker in seen:
                    continue
                seen.add(marker)
                try:
                    patterns.append(pattern_from(task, state))
                except ValueError as exc:
                    raise UsageError(f"{path}: state {marker[:60]} does not fit the task: {exc}") from None
        except LogError as exc:
            skipped.append(f"{exc}; skipped")
    if not patterns:  # one line: why there is nothing to ask, with the first log left out
        first = f" ({len(skipped)} log{'s' if len(skipped) != 1 else ''} skipped; first: {skipped[0]})" if skipped else ""
        raise UsageError(f"no {topic} states in {', '.join(map(str, runs))}{first}")
    for line in skipped:
        reporter.warn(line)
    return patterns


def queries_for(config: ExperimentConfig, patterns: Sequence[Any]) -> list[Query]:
    """The queries a run of ``config`` would send from ``patterns`` (same key, same prompt)."""
    task = make_task(config)
    return [query_for(task, config.llm, pattern) for pattern in patterns]


@dataclass(frozen=True)
class RecordingReport:
    """What one ``lagrseq record`` achieved."""

    prompts: int
    full: int
    """Prompts that hold at least ``samples`` answers."""
    samples: int
    store: Path
    answers: int = 0
    """New answers recorded by this call."""
    spent_usd: float = 0.0
    unpriced: int = 0
    stopped: BudgetExceeded | None = None
    """Why recording stopped early (the budget), if it did."""

    def summary(self) -> str:
        unpriced = f" ({self.unpriced} with no price)" if self.unpriced else ""
        return (
            f"{self.full}/{self.prompts} prompts hold at least {self.samples} answers in {self.store}; "
            f"spent ${self.spent_usd:.4f} on {self.answers} new answers{unpriced}"
        )

    def missing(self, mode: str) -> UsageError | None:
        """The error to end with when prompts still lack answers (None when none do)."""
        if self.full >= self.prompts:
            return None
        return UsageError(
            f"{self.prompts - self.full} of {self.prompts} prompts have fewer than {self.samples} answers "
            f"in {self.store} (record mode {mode}); run with --mode new to top them up"
        )


def record(
    queries: Sequence[Query],
    store_path: Path,
    samples: int,
    mode: str,
    options: Any,
    bar: Any = None,
    provider: str = "live",
    concurrency: int = 1,
) -> RecordingReport:
    """Top every query up to ``samples`` answers in ``store_path`` from the server of
    ``options`` (the provider kind's: ``LiveOptions`` or ``LocalOptions``; mode ``none`` asks nobody and only counts), with up to ``concurrency`` requests
    in flight. ``provider``: ``live``, or ``local[:MODEL]`` for a llama.cpp server started for the
    recording (its answers are keyed under the endpoint ``local``). ``bar``: a tqdm-like progress
    bar (``update``, ``write``, ``set_postfix_str``) or None."""
    from lagrseq.llm.store import endpoint_of
    from lagrseq.running.wiring import local_live, local_settings, parse_provider

    spec = parse_provider(provider)
    kind = recording_kind(provider)
    queries = served_queries(queries, kind.local_server or getattr(options, "server", None) == "llama.cpp")
    if not kind.local_server or mode == "none":
        endpoint = _local_endpoint() if kind.local_server else endpoint_of(options.base_url)
        return _record(queries, store_path, samples, mode, options, bar, endpoint, concurrency)
    from lagrseq.llm.local import LocalServer, Supervisor

    say = (lambda message: bar.write(shown(message))) if bar is not None else (lambda message: print(shown(message), file=sys.stderr))
    settings = local_settings(spec.argument, options)
    reporter = Reporter(lambda line: say(f"  {line}"))
    with LocalServer(settings, reporter=reporter) as server:
        supervisor = Supervisor(server, reporter)  # a dying server: restarted once, then one line
        try:
            return _record(queries, store_path, samples, mode, local_live(options, server.base_url), bar, _local_endpoint(), concurrency, settings.model_name, supervisor.on_retry)
        finally:
            supervisor.close()


def served_queries(queries: Sequence[Query], llama_cpp: bool) -> list[Query]:
    """``queries`` as they are sent and keyed: served by llama.cpp (``llama_cpp``), with its
    samplers pinned to OpenAI's meaning of temperature (:data:`lagrseq.llm.servers.LLAMA_CPP_SAMPLERS`)."""
    from lagrseq.llm.base import with_samplers
    from lagrseq.llm.servers import LLAMA_CPP_SAMPLERS

    return [with_samplers(q, LLAMA_CPP_SAMPLERS) for q in queries] if llama_cpp else list(queries)


def check_record(store_path: Path, mode: str, options: Any, provider: str = "live") -> None:
    """What ``record`` needs, checked before its progress bar is drawn (one line, nothing asked):
    the provider (a live server's key and URL, a local model file) and, unless mode ``none``, a
    store that can be written (a read-only store, or one below a file, fails here)."""
    from lagrseq.llm.store import RecordStore
    from lagrseq.running.wiring import local_settings, parse_provider

    spec = parse_provider(provider)
    kind = recording_kind(provider)
    if mode == "none":
        return
    if kind.local_server:
        local_settings(spec.argument, options)
    else:
        make_live(options, np.random.default_rng(0)).close()
    with RecordStore(store_path) as store:
        store.writer()


def recording_kind(provider: str) -> ProviderKind:
    """The kind of ``provider`` if ``record`` can ask it (a live or local model); else one line
    saying it cannot (``record`` checks this before anything else: its prompts, its runs)."""
    from lagrseq.registry import PROVIDERS
    from lagrseq.running.wiring import provider_kind

    kind = provider_kind(provider)
    if not kind.records:
        usable = " or ".join(k.usage for k in PROVIDERS.specs() if k.records)
        raise UsageError(f"lagrseq record asks a live or local model, not {provider!r}; expected {usable}")
    return kind


def _local_endpoint() -> str:
    from lagrseq.llm.local import LOCAL_ENDPOINT

    return LOCAL_ENDPOINT


def _record(
    queries: Sequence[Query],
    store_path: Path,
    samples: int,
    mode: str,
    options: Any,
    bar: Any,
    endpoint: str,
    concurrency: int,
    local_model: str | None = None,
    on_retry: Callable[[str], None] | None = None,
) -> RecordingReport:
    from lagrseq.llm.recorded import RecordingProvider, record_queries
    from lagrseq.llm.store import RecordStore, query_key

    def held(store: RecordStore) -> int:
        entries = [store.entry(query_key(q, endpoint)[0]) for q in queries]
        return sum(1 for e in entries if e is not None and len(e.samples) >= samples)

    # a store recorded before llama.cpp's samplers were pinned holds them under the plain key: a
    # check that asks nobody (mode none) counts those too
    if mode == "none" and any(samplers_of(q) for q in queries):
        plain = [replace(q, top_k=None, min_p=None, repeat_penalty=None) for q in queries]
        with RecordStore(store_path, create=False) as store:
            if held(store) < len(queries):
                both = sum(
                    1
                    for q, p in zip(queries, plain)
                    if any(e is not None and len(e.samples) >= samples for e in (store.entry(query_key(q, endpoint)[0]), store.entry(query_key(p, endpoint)[0])))
                )
                return RecordingReport(len(queries), both, samples, store_path)

    if mode == "none":  # ask nobody (no key needed): report what the store lacks
        with RecordStore(store_path, create=False) as store:
            return RecordingReport(len(queries), held(store), samples, store_path)
    # The retry jitter's generator: seeded per process, so concurrent recorders back off apart.
    jitter = np.random.default_rng([os.getpid()])
    say = (lambda message: bar.write(shown(message))) if bar is not None else (lambda message: print(shown(message), file=sys.stderr))
    environ: dict[str, str] | None = {} if local_model is not None else None  # a local server: no key
    live = make_live(options, jitter, budgeted=True, on_retry=on_retry or (lambda message: say(f"  {message}")), environ=environ, local_model=local_model)
    budget = live.budget

    def show(_answers: Any) -> None:
        if bar is not None:
            unpriced = f", {budget.unpriced} unpriced" if budget.unpriced else ""
            bar.set_postfix_str(f"{budget.answers} new answers, ${budget.spent_usd:.4f}{unpriced}")

    stopped: BudgetExceeded | None = None
    on_query = lambda _q: bar.update(1) if bar is not None else None  # noqa: E731
    if concurrency > 1:
        from lagrseq.llm.concurrent import record_concurrently
        from lagrseq.llm.live import SharedBackoff

        live.inner.backoff = SharedBackoff()  # a 429 pauses every request in flight
        with RecordingProvider(RecordStore(store_path), live.inner, endpoint, mode, samples) as recorder:  # type: ignore[arg-type]
            try:
                record_concurrently(recorder, list(queries), budget, live.prices, concurrency, on_answers=show, on_query=on_query)
            except BudgetExceeded as exc:
                stopped = exc
            full = held(recorder.store)
        return RecordingReport(
            len(queries), full, samples, store_path, budget.answers, budget.spent_usd, budget.unpriced, stopped
        )
    with RecordingProvider(RecordStore(store_path), live, endpoint, mode, samples) as recorder:  # type: ignore[arg-type]
        try:
            record_queries(recorder, list(queries), on_answers=show, on_query=on_query)
        except BudgetExceeded as exc:
            stopped = exc
        full = held(recorder.store)
    return RecordingReport(
        len(queries), full, samples, store_path, budget.answers, budget.spent_usd, budget.unpriced, stopped
    )


def record_config(
    task: str,
    preset: str,
    config_file: Path | None,
    overrides: Sequence[str],
    model: str | None = None,
    temperature: float | None = None,
    max_tokens: int | None = None,
) -> ExperimentConfig:
    """The configuration whose queries are recorded (or imported): the preset's, with the model,
    temperature and max tokens given (each defaults to the preset's)."""
    from lagrseq import config as cfg

    config = cfg.load(task, "lagr", preset, config_file, overrides)
    llm = replace(
        config.llm,
        model=model or config.llm.model,
        temperature=config.llm.temperature if temperature is None else temperature,
        max_tokens=config.llm.max_tokens if max_tokens is None else max_tokens,
    )
    return replace(config, llm=llm)


def import_answers(
    file: Path,
    store_path: Path,
    fmt: str,
    task: str | None,
    preset: str,
    config_file: Path | None,
    overrides: Sequence[str],
    model: str | None,
    temperature: float | None,
    max_tokens: int | None,
    base_url: str,
    reporter: Reporter,
) -> str:
    """``lagrseq cache import``: a JSONL export, or an authors' pickle whose keys are rebuilt
    from the task descriptor. Returns the line to print."""
    from lagrseq.llm.store import RecordStore, endpoint_of, import_jsonl_file

    fmt = fmt if fmt != "auto" else ("jsonl" if file.suffix == ".jsonl" else "pkl")
    if not file.is_file():
        raise UsageError(f"{file}: no such file")
    if fmt == "jsonl":
        from lagrseq.llm.servers import DEFAULT_BASE_URL

        given = [flag for flag, value in (("--task", task), ("--model", model), ("--temperature", temperature), ("--max-tokens", max_tokens)) if value is not None]
        given += ["--base-url"] if base_url != DEFAULT_BASE_URL else []
        given += ["--config"] if config_file is not None else []
        given += ["--set"] if overrides else []
        if given:
            raise UsageError(
                f"{' and '.join(given)} describe{'s' if len(given) == 1 else ''} the answers of a pickle; "
                f"a JSONL export holds each answer's own request: leave {'it' if len(given) == 1 else 'them'} out (or give --format pkl for a pickle)"
            )
        # The whole file is checked before the store is created or written.
        lines = import_jsonl_file(file, store_path, file.name, reporter)
        return f"{file}: {lines.lines} answers under {lines.keys} keys; {lines.added} added, {lines.already_present} already in {store_path}"
    missing = [flag for flag, value in (("--task", task), ("--model", model), ("--temperature", temperature)) if value is None]
    if missing or task is None or model is None or temperature is None:
        raise UsageError(f"importing a pickle needs {', '.join(missing)}: the authors' caches do not record them")
    from lagrseq.llm.authors_cache import import_authors_cache

    config = record_config(task, preset, config_file, overrides, model, temperature, max_tokens)
    endpoint = endpoint_of(base_url)  # a URL carrying a key is refused before the store is made
    with RecordStore(store_path) as store:
        report = import_authors_cache(
            file,
            store,
            prompt_function(config),
            task=task,
            model=model,
            temperature=temperature,
            endpoint=endpoint,
            max_tokens=config.llm.max_tokens,
            reporter=reporter,
        )
    return (
        f"{file}: {report.pairs} pairs; {report.imported} answers added under {report.keys} keys, "
        f"{report.already_present} already in {store_path}, {report.skipped} skipped"
    )


def export_answers(store_path: Path, out: str, stdout: Any) -> str:
    """``lagrseq cache export``: the store as JSONL into ``out`` (``-``: ``stdout``), written to a
    new file beside it and renamed, so a failed export leaves nothing half-written; ``out`` may
    replace a file, never a symbolic link (refused), and may not lie inside the store it exports
    (it would replace the store's own database)."""
    from lagrseq.llm.store import RecordStore, export_jsonl
    from lagrseq.paths import check_output, write_output

    if out != "-":
        path = Path(out)
        try:
            store_real, out_real = Path(store_path).resolve(), path.resolve()
        except (OSError, RuntimeError):  # a symlink loop: compared as written (the open reports the loop)
            store_real, out_real = Path(os.path.abspath(store_path)), Path(os.path.abspath(path))
        if out_real == store_real or store_real in out_real.parents:
            raise UsageError(
                f"--out {out} lies inside the store {store_path} that it exports: the export would replace "
                "the store's own files; give a path outside the store directory"
            )
        check_output(path, "--out", replace=True)
    with RecordStore(store_path, create=False) as store:
        if out == "-":
            report = export_jsonl(store, stdout)
        else:
            report = write_output(Path(out), lambda handle: export_jsonl(store, handle), "--out", replace=True)
    return f"{report.lines} answers under {report.keys} keys written to {out}"


def list_answers(store_path: Path) -> list[str]:
    """``lagrseq cache list``: one line per recorded key."""
    from lagrseq.llm.store import RecordStore

    lines = []
    with RecordStore(store_path, create=False) as store:
        for entry in store.entries():
            r = entry.request
            tail = " ".join(entry.prompt.split())[-48:]
            lines.append(
                f"{entry.key[:12]}  {entry.task or '-'}  {r['model']}  t={r['temperature']}  {r['endpoint']}  "
                f"{len(entry.samples):3d} samples  ...{tail}"
            )
    return lines


# ------------------------------------------------------------------------------------------
# Recorded answers through the task's parser: what a real model's text does to it
# ------------------------------------------------------------------------------------------
REFUSALS = ("no list", "prose", "repeated letter", "wrong size", "not a cube", "other")
"""How a parser refusal is classified (``prose``: no list, in an answer of 8 words or more)."""
PROSE_WORDS = 8


def classify(task: Task, text: str) -> tuple[str, Any]:
    """(class, parsed solution or None) of one answer: ``correct``, ``wrong`` (a solution, not the
    target), ``partial`` (a cube list shorter than the stack), or one of :data:`REFUSALS`."""
    parsed = task.parse(text)
    if parsed.ok:
        solution = parsed.solution
        partial = getattr(task, "is_partial", None)  # a solution of the wrong size (cube stacking's)
        if partial is not None and partial(solution):
            return "partial", solution
        return ("correct" if task.evaluate(solution) >= 1.0 else "wrong"), solution
    error = parsed.error or ""
    if error.startswith("no list") or error.startswith("no matrix"):
        return ("prose" if len(text.split()) >= PROSE_WORDS else "no list"), None
    if "appears twice" in error:
        return "repeated letter", None
    if "cubes listed" in error or "rows" in error or "columns" in error or "shape" in error:
        return "wrong size", None
    if "is not a cube" in error:
        return "not a cube", None
    return "other", None


@dataclass(frozen=True)
class CensusRow:
    """The answers of one recorded key, classified."""

    key: str
    temperature: float
    shown: int
    """Cube stacking: cubes in the prompt's partial stack (-1 for other tasks)."""
    counts: dict[str, int]

    @property
    def total(self) -> int:
        return sum(self.counts.values())


def answer_census(store_path: Path, config: ExperimentConfig) -> list[CensusRow]:
    """Every answer in the store (or a JSONL export) of ``config``'s task through its parser.
    Raises nothing on any answer text (the parsers never raise)."""
    from lagrseq.llm.store import RecordStore

    task = make_task(config)
    rows: list[CensusRow] = []
    with contextlib.ExitStack() as stack:
        if store_path.suffix == ".jsonl":
            from lagrseq.llm.recorded import JsonlRecordedProvider

            opened = stack.enter_context(JsonlRecordedProvider(store_path, "local", 0)).store
        else:
            opened = stack.enter_context(RecordStore(store_path, create=False))
        for entry in opened.entries():
            if entry.task != config.task.name:
                continue
            counts: dict[str, int] = {}
            for recorded in entry.samples:
                name, _ = classify(task, recorded.text)
                counts[name] = counts.get(name, 0) + 1
            shown = -1  # the key stands in for the stack shown (grids, or a prompt that is not a cube prompt)
            shown_of = getattr(task, "shown", None)  # cubes the prompt shows (cube stacking's)
            if shown_of is not None:
                with contextlib.suppress(ValueError):
                    shown = shown_of(entry.prompt)
            rows.append(CensusRow(entry.key, float(entry.request["temperature"]), shown, counts))
    return sorted(rows, key=lambda r: (r.temperature, r.shown, r.key))


def census_lines(rows: Sequence[CensusRow]) -> list[str]:
    """A Markdown table of :func:`answer_census`, one row per key and a total per temperature."""
    classes = ["correct", "wrong", "partial", *REFUSALS]
    lines = ["| τ | shown | answers | " + " | ".join(classes) + " | accuracy |", "|" + "---|" * (len(classes) + 4)]
    for temperature in sorted({r.temperature for r in rows}):
        group = [r for r in rows if r.temperature == temperature]
        for r in group:
            cells = " | ".join(str(r.counts.get(c, 0)) for c in classes)
            lines.append(f"| {temperature:g} | {r.shown if r.shown >= 0 else r.key[:12]} | {r.total} | {cells} | {r.counts.get('correct', 0) / max(r.total, 1):.2f} |")
        total = {c: sum(r.counts.get(c, 0) for r in group) for c in classes}
        answers = sum(total.values())
        cells = " | ".join(str(total[c]) for c in classes)
        lines.append(f"| {temperature:g} | all | {answers} | {cells} | {total['correct'] / max(answers, 1):.2f} |")
    return lines
