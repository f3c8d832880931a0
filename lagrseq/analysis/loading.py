"""MCAP logs -> runs: trial logs grouped by what was run, as pandas frames.

A *run* is every trial log of one experiment: the same task, method, preset, provider, seed and
configuration (its digest, i.e. the run directory's suffix). Everything comes from the logs: the
``lagrseq.run`` metadata and the ``/episode`` and ``/query`` topics, read through the chunk index
so that no transition chunk is decompressed (:func:`lagrseq.logs.reader.read_rows`).

Logs that are unfinished (``.mcap.partial``), unreadable, or whose trial did not complete are left
out with a one-line warning each, never failing the whole load. A warning names the log by its
full path and, where ``lagrseq recover`` can repair it, gives the command (quoted, to be run as
written); the totals (:attr:`Logs.files`, :attr:`Logs.bytes`, :attr:`Logs.messages`) count only
the logs that were used, :attr:`Logs.skipped` the others.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import gc
import hashlib
import json
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from lagrseq.config import config_digest
from lagrseq.errors import LogError
from lagrseq.logs.origins import PARTS_METADATA, read_parts
from lagrseq.logs.reader import ReadStats, full_path, read_rows, recover_command
from lagrseq.logs.schemas import ACCURACY_METHOD
from lagrseq.logs.sink import PARTIAL_SUFFIX
from lagrseq.paths import expand_user, input_path, walk_files
from lagrseq.suite import miss_variant

EPISODE_COLUMNS = (
    "trial",
    "episode",
    "return",
    "length",
    "queries",
    "accepted",
    "epsilon",
    "solved",
    "guided_steps",
    "global_step",
)
QUERY_COLUMNS = (
    "trial",
    "episode",
    "step",
    "global_step",
    "decision",
    "queried",
    "accepted",
    "evaluation",
    "provider",
    "model",
    "temperature",
    "prompt_tokens",
    "completion_tokens",
    "cost_usd",
    "latency_s",
    "source",
    "prefix_length",
    "fraction",
)


@dataclass(frozen=True, order=True)
class RunKey:
    """What identifies a run (the sort order is the report order)."""

    task: str
    method: str
    preset: str
    provider: str
    seed: int
    digest: str
    variant: str = ""
    """Accuracy probes: ``samples-K`` (answers per prefix); empty for RL trials."""

    @property
    def kind(self) -> str:
        return "accuracy" if self.method == ACCURACY_METHOD else "trial"

    def columns(self) -> dict[str, str | int]:
        """The identifying columns of a table row about this run."""
        return {
            "task": self.task,
            "method": self.method,
            "preset": self.preset,
            "provider": self.provider,
            "seed": self.seed,
            "config": self.digest,
        }

    @property
    def name(self) -> str:
        tail = f"/{self.variant}" if self.variant else ""
        return f"{self.task}/{self.method}/{self.preset}-{self.provider}-seed{self.seed}-{self.digest}{tail}"


@dataclass(frozen=True)
class Run:
    """The complete trial logs of one run."""

    key: RunKey
    config: dict[str, Any]
    files: tuple[str, ...]
    """Log paths relative to the directory given to :func:`load`."""
    trials: tuple[int, ...]
    episodes: pd.DataFrame
    """One row per episode: :data:`EPISODE_COLUMNS`, then the task's own fields."""
    queries: pd.DataFrame
    """One row per secondary decision (or probe query): :data:`QUERY_COLUMNS`."""
    transitions: int
    """``/transition`` messages in the logs (from their statistics; none were decompressed)."""
    samples: int = 0
    """Accuracy probes: answers per prefix."""
    paths: tuple[str, ...] = ()
    """The log files themselves, in trial order (for pictures read from one trial's log)."""
    task_fields: tuple[tuple[str, str], ...] = ()
    """The task's own ``/episode`` fields (name, JSON type), columns of :attr:`episodes` after
    :data:`EPISODE_COLUMNS` (``TaskSpec.episode_fields``, read from the logs' schema)."""
    step_fields: tuple[tuple[str, str], ...] = ()
    """The task's own ``/transition`` fields (``TaskSpec.step_fields``, read from the logs'
    schema): the columns of :attr:`steps` after ``trial``."""
    steps: pd.DataFrame | None = None
    """One row per step of a run whose task logs fields of its own per step (``trial`` and those
    fields); None for every other run (its transitions are never read)."""
    parts: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    """Which distribution and version made its task, provider, policy and executor, by role
    (its first trial's ``parts`` metadata, :mod:`lagrseq.logs.origins`; empty for logs made
    before it was logged)."""

    @functools.cached_property
    def episodes_per_trial(self) -> int:
        """Worked out once (a replay asks for it about 600 times; the frames are not changed)."""
        if self.episodes.empty:
            return 0
        return int(self.episodes.groupby("trial")["episode"].count().max())

    @property
    def size(self) -> int:
        """How much data the run holds (trials x episodes, or probe answers): bigger wins when
        several runs match one suite entry."""
        if self.key.kind == "accuracy":
            return len(self.queries)
        return len(self.trials) * self.episodes_per_trial

    def total_per_trial(self, column: str) -> dict[int, float]:
        """Sum of an ``/episode`` column over each trial (e.g. queries or return per trial);
        each column's sums are worked out once."""
        totals: dict[str, dict[int, float]] = self.__dict__.setdefault("_totals", {})
        if column not in totals:
            sums = self.episodes.groupby("trial")[column].sum()
            totals[column] = {int(t): float(v) for t, v in sums.items()}
        return dict(totals[column])


@dataclass(frozen=True)
class Logs:
    """Everything :func:`load` found."""

    runs: tuple[Run, ...]
    warnings: tuple[str, ...]
    files: int
    """Logs read into the runs (skipped ones are not counted)."""
    bytes: int
    """Their size."""
    messages: dict[str, int] = field(default_factory=dict)
    """Messages per topic in them."""
    stats: ReadStats = field(default_factory=ReadStats)
    skipped: int = 0
    """Logs left out with a warning: unfinished, unreadable, incomplete trials, duplicates."""


@dataclass
class _Trial:
    key: RunKey
    config: dict[str, Any]
    path: Path
    size: int
    display: str
    trial: int
    episodes: pd.DataFrame
    queries: pd.DataFrame
    counts: dict[str, int]
    samples: int
    task_fields: tuple[tuple[str, str], ...] = ()
    parts: dict[str, dict[str, str]] = field(default_factory=dict)
    step_fields: tuple[tuple[str, str], ...] = ()
    steps: pd.DataFrame | None = None


def _display(path: Path, root: Path) -> str:
    base = root if root.is_dir() else root.parent
    try:
        return path.relative_to(base).as_posix()
    except ValueError:  # pragma: no cover - find_logs only returns paths under root
        return path.name


def _find(roots: Sequence[str | Path]) -> tuple[list[tuple[Path, Path]], list[str]]:
    found: dict[Path, Path] = {}
    warnings = []
    for item in roots:
        if not os.path.lexists(expand_user(item, "logs", LogError)):
            raise LogError(f"{item}: no such MCAP file or directory")
        root = input_path(item, "logs", "any", LogError)
        if root.is_dir():
            # every match checked before it is opened or resolved: a FIFO named *.mcap would block
            # the reader, a symlink loop would make resolve() raise; loops of directories are
            # entered once
            names = walk_files(root, lambda name: name.endswith((".mcap", ".mcap" + PARTIAL_SUFFIX)))
            for path in names:
                input_path(path, "log", "file", LogError)
            for path in names:
                if path.name.endswith(".mcap"):
                    found.setdefault(path.resolve(), root)
            for path in names:
                if path.name.endswith(PARTIAL_SUFFIX):
                    warnings.append(_unfinished(path))
        elif root.name.endswith(".mcap"):
            found.setdefault(root.resolve(), root)
        else:
            raise LogError(f"{root}: no such MCAP file or directory")
    ordered = sorted(found.items(), key=lambda kv: _display(kv[0], kv[1]))
    return ordered, warnings


def _unfinished(path: Path) -> str:
    from lagrseq.logs.recover import diagnose

    verdict = diagnose(path)
    if verdict.recoverable:
        advice = (
            f"once its trial is no longer running, run `{recover_command(path)}` to keep it "
            f"({verdict.detail})"
        )
    else:
        advice = f"`lagrseq recover` cannot repair it ({verdict.detail})"
    return (
        f"{full_path(path)}: unfinished log (its trial crashed or is still running); "
        f"skipped: {advice}"
    )


def _read_trial(path: Path, root: Path, stats: ReadStats) -> _Trial:
    display = _display(path, root)
    # Only complete trials count; the topics are read in the same pass (cheap: summary chunks),
    # each record straight into the row of its frame
    data = read_rows(path, {"/episode": EPISODE_COLUMNS, "/query": QUERY_COLUMNS}, stats, missing=np.nan, task_fields=True)
    own = data.task_fields.get("/episode", ())  # the task's own /episode fields, named by the log's schema
    info, topics, counts = data.info, data.rows, data.counts
    status = info.status.get("status", "unfinished")
    run = info.run
    method = run.get("method", "")
    if status != "complete":
        raise LogError(
            f"{full_path(path)}: trial {status} ({info.status.get('error', '')}); skipped"
        )
    text = run["config"]
    try:
        digest = config_digest(json.loads(text))
    except (ValueError, RecursionError, AttributeError):
        digest = hashlib.sha256(text.encode()).hexdigest()[:8]
    samples = int(run.get("samples", 0)) if method == ACCURACY_METHOD else 0
    key = RunKey(
        task=run.get("task", ""),
        method=method,
        preset=run.get("preset", ""),
        provider=run.get("provider", ""),
        seed=int(run.get("seed", 0)),
        digest=digest,
        variant=f"samples-{samples}" if samples else miss_variant(run.get("provider", ""), logged_on_miss(run.get("provider_options"))),
    )
    step_fields, steps = _steps(path, data.declared.get(STEP_TOPIC, ()), stats)
    return _Trial(
        key=key,
        config=json.loads(text),
        path=path,
        size=path.stat().st_size,
        display=display,
        trial=int(run.get("trial", 0)),
        # Frames right away: a file's records as rows are big, its columns are small.
        episodes=_frame(topics["/episode"], (*EPISODE_COLUMNS, *(name for name, _ in own))),
        queries=_frame(topics["/query"], QUERY_COLUMNS),
        counts=counts,
        samples=samples,
        task_fields=own,
        parts=read_parts(run.get(PARTS_METADATA)),
        step_fields=step_fields,
        steps=steps,
    )


STEP_TOPIC = "/transition"


def _steps(path: Path, declared: tuple[tuple[str, str], ...], stats: ReadStats) -> tuple[tuple[tuple[str, str], ...], pd.DataFrame | None]:
    """The task's own step fields of a log and their values, one row per step (``trial`` first);
    the transitions are read only where the log's schema declares such fields."""
    if not declared:
        return (), None
    data = read_rows(path, {STEP_TOPIC: ("trial",)}, stats, missing=np.nan, task_fields=True)
    own = data.task_fields.get(STEP_TOPIC, ())
    return own, _frame(data.rows[STEP_TOPIC], ("trial", *(name for name, _ in own)))


def logged_on_miss(text: Any) -> str:
    """The ``on_miss`` a trial's ``provider_options`` metadata (JSON) names, empty if none."""
    try:
        options = json.loads(text) if isinstance(text, str) and text else {}
    except (ValueError, RecursionError):
        return ""
    value = options.get("on_miss") if isinstance(options, dict) else None
    return value if isinstance(value, str) else ""


def _frame(rows: list[tuple[Any, ...]], columns: Sequence[str]) -> pd.DataFrame:
    """The frame of ``rows`` (the same as of the records they come from, each column's type
    inferred from its values)."""
    return pd.DataFrame.from_records(rows, columns=list(columns))


def _task_fields(trials: Sequence[_Trial]) -> tuple[tuple[str, str], ...]:
    """The task's own fields of a run's trials (every one its logs name, in order)."""
    out: dict[str, str] = {}
    for trial in trials:
        for name, kind in trial.task_fields:
            out.setdefault(name, kind)
    return tuple(out.items())


def _step_fields(trials: Sequence[_Trial]) -> tuple[tuple[str, str], ...]:
    """The task's own step fields of a run's trials (every one its logs name, in order)."""
    return _task_fields([dataclasses.replace(t, task_fields=t.step_fields) for t in trials])


def _steps_of(trials: Sequence[_Trial]) -> pd.DataFrame | None:
    frames = [t.steps for t in trials if t.steps is not None]
    return _concat(frames, ("trial",)) if frames else None


def _concat(frames: list[pd.DataFrame], columns: Sequence[str]) -> pd.DataFrame:
    frames = [f for f in frames if not f.empty]
    if not frames:
        return pd.DataFrame(columns=list(columns))
    return pd.concat(frames, ignore_index=True)


@contextlib.contextmanager
def no_cycle_collection() -> Iterator[None]:
    """Python's cyclic garbage collector paused inside (as it was after). Reading logs makes
    millions of small objects, none of them in a cycle (reference counting frees them), and
    every full collection walks every element of the object columns of the frames read so far:
    that was about a fifth of a one-process replay's CPU (3.8 of 18.1 s on the quick suite)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _read_one(item: tuple[Path, Path]) -> tuple[_Trial | str, ReadStats]:
    """One log: its trial, or the warning that says why it is skipped; and what was read."""
    path, root = item
    stats = ReadStats()
    try:
        with no_cycle_collection():
            return _read_trial(path, root, stats), stats
    except LogError as exc:
        text = str(exc)
        return (text if text.endswith("skipped") else f"{text}; skipped"), stats
    except (KeyError, ValueError, RecursionError, OSError) as exc:
        return f"{full_path(path)}: not a lagrseq trial log ({type(exc).__name__}: {exc}); skipped", stats


PARALLEL_MIN_LOGS = 24
"""Fewer logs than this are read in this process: starting worker processes (each imports
pandas) costs more than reading a few logs."""


WORKERS_MIN_CPUS = 3
"""Fewer CPUs than this (for this process) and the logs are read in this process by default: on
2 cores the workers' imports and pickling cost more than the reading they share
(``benchmarks/bench_replay_jobs.py`` measures it)."""


def usable_cpus() -> int:
    """The CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def default_jobs() -> int:
    """Processes that read logs when none is asked for: the CPUs this process may use, at most 8;
    one (this process) with fewer than :data:`WORKERS_MIN_CPUS`."""
    cpus = usable_cpus()
    return 1 if cpus < WORKERS_MIN_CPUS else min(cpus, 8)


def parallel(logs: int, jobs: int) -> bool:
    """Whether ``logs`` logs are read in ``jobs`` worker processes (and replay draws its figures
    in a worker of its own)."""
    return jobs > 1 and logs >= PARALLEL_MIN_LOGS


def worker_pool(jobs: int) -> ProcessPoolExecutor:
    """``jobs`` spawned worker processes (they start on first use): a clean interpreter that
    imports only what its work needs, no fork of a process holding threads or big figures."""
    import multiprocessing

    from lagrseq.lifetime import die_with_parent

    # a replay killed with SIGKILL leaves no worker (nor, with them gone, resource tracker) behind
    return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"), initializer=die_with_parent)


def _read_all(paths: list[tuple[Path, Path]], jobs: int) -> list[tuple[_Trial | str, ReadStats]]:
    """Every log read, in the order given: in ``jobs`` worker processes when there are enough
    logs (the results, and so everything made from them, are the same as in one process)."""
    if not parallel(len(paths), jobs):
        return [_read_one(item) for item in paths]
    workers = min(jobs, len(paths))
    # chunks of logs so that each worker gets a few at a time
    with worker_pool(workers) as pool:
        return list(pool.map(_read_one, paths, chunksize=max(1, len(paths) // (workers * 8))))


def load(
    roots: Sequence[str | Path], jobs: int | None = None, on_found: Callable[[int], None] | None = None
) -> Logs:
    """Read every ``*.mcap`` under ``roots`` (files or directories) into runs; ``jobs``
    processes read the logs (default :func:`default_jobs`; the result does not depend on it).
    ``on_found`` is told how many logs there are before any is read."""
    paths, warnings = _find(roots)
    if on_found is not None:
        on_found(len(paths))
    skipped = len(warnings)  # the unfinished logs
    stats = ReadStats()
    groups: dict[RunKey, list[_Trial]] = {}
    with no_cycle_collection():  # also while the workers' trials arrive here (unpickled)
        everything = _read_all(paths, default_jobs() if jobs is None else jobs)
    for trial, read in everything:
        stats.add(read)
        if isinstance(trial, str):
            warnings.append(trial)
            skipped += 1
            continue
        groups.setdefault(trial.key, []).append(trial)

    runs = []
    used = size = 0
    messages: dict[str, int] = {}
    for key in sorted(groups):
        trials: dict[int, _Trial] = {}
        for trial in sorted(groups[key], key=lambda t: t.display):
            if trial.trial in trials:
                warnings.append(
                    f"{full_path(trial.path)}: trial {trial.trial} of {key.name} also in "
                    f"{full_path(trials[trial.trial].path)}; skipped"
                )
                skipped += 1
                continue
            trials[trial.trial] = trial
        ordered = [trials[t] for t in sorted(trials)]
        for trial in ordered:
            used += 1
            size += trial.size
            for topic, count in trial.counts.items():
                messages[topic] = messages.get(topic, 0) + count
        episodes = _concat([t.episodes for t in ordered], EPISODE_COLUMNS)
        queries = _concat([t.queries for t in ordered], QUERY_COLUMNS)
        runs.append(
            Run(
                key=key,
                config=ordered[0].config,
                files=tuple(t.display for t in ordered),
                paths=tuple(str(t.path) for t in ordered),
                trials=tuple(sorted(trials)),
                episodes=episodes,
                queries=queries,
                transitions=sum(t.counts.get("/transition", 0) for t in ordered),
                samples=ordered[0].samples,
                task_fields=_task_fields(ordered),
                parts=ordered[0].parts,
                step_fields=_step_fields(ordered),
                steps=_steps_of(ordered),
            )
        )
    return Logs(
        runs=tuple(runs),
        warnings=tuple(sorted(set(warnings))),
        files=used,
        bytes=size,
        messages=dict(sorted(messages.items())),
        stats=stats,
        skipped=skipped,
    )
