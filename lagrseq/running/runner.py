"""Several trials of one run: paths, resume, a process pool, progress, and Ctrl-C.

A run writes ``OUT/<task>/<method>/<name>/trial-NNN.mcap``, one file per trial. A rerun skips a
trial whose log is complete, but only if that log was made with the same configuration, seed and
provider (``--name`` lets two configurations meet in one directory: that is refused), and says
how many trials are complete, missing or unfinished before it starts. Trials run in this process
(``jobs=1``), in a pool of spawned worker processes, or on Dask (:mod:`lagrseq.running.executors`);
trials that train networks run in lockstep, several in one process (:func:`run_in_lockstep`, one
group per worker), with the logs they write alone; a trial
that raises is reported while the others go on; Ctrl-C cancels the trials
not started, stops the running ones (their flushed episodes stay in ``.partial`` files that
``lagrseq recover`` turns into valid logs) and raises KeyboardInterrupt; a second Ctrl-C exits at
once.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import json
import platform
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lagrseq import __version__
from lagrseq.agents.numerics import NATIVE, numerics
from lagrseq.config import ExperimentConfig
from lagrseq.errors import (
    BudgetExceeded,
    ConfigError,
    LagrseqError,
    LogError,
    ParseError,
    ProviderError,
    RecordError,
    RecordMiss,
    StoreError,
    TrialsFailed,
    UsageError,
)
from lagrseq.logs import origins
from lagrseq.logs.sink import PARTIAL_SUFFIX, McapSink, NullSink, Sink
from lagrseq.loop.experiment import TrialResult, run_trial
from lagrseq.progress import Reporter
from lagrseq.registry import find_part, logged_options, replace_part
from lagrseq.running import executors
from lagrseq.running.wiring import (
    default_options,
    parse_provider,
    pays,
    provider_kind,
    task_fields,
    trial_parts,
    view_topics,
    with_provider_model,
)

if TYPE_CHECKING:
    from lagrseq.logs.reader import LogInfo


def _pinned_samplers(provider_spec: str, provider_options: Any) -> str | None:
    """The sampler settings a llama.cpp server is sent beside temperature and top_p (``--provider
    local``, or a live provider with ``--server llama.cpp``), as JSON; None for any other."""
    import json

    from lagrseq.llm.servers import LLAMA_CPP_SAMPLERS

    kind = provider_spec.partition(":")[0]
    if kind == "local" or (kind == "live" and getattr(provider_options, "server", None) == "llama.cpp"):
        return json.dumps(dict(LLAMA_CPP_SAMPLERS), sort_keys=True)
    return None


def run_metadata(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    provider_options: Any = None,
    notes: Mapping[str, str] | None = None,
    executor: str = "local",
) -> dict[str, str]:
    """The ``lagrseq.run`` metadata record: everything replay needs to know about the trial.
    ``notes``: more entries under names of their own (``frontier_tuning``: how ``lagrseq frontier
    --tune`` chose the run's knobs); none by default, so ordinary logs are unchanged.
    ``numerics``: ``perturbed`` in a trial that trains a network under ``LAGRSEQ_NUMERICS=perturbed``
    (:mod:`lagrseq.agents.numerics`); absent under native numerics, so native logs keep their bytes.
    ``llm_samplers``: the samplers a llama.cpp-served run pins (top_k, min_p, repeat_penalty).
    ``parts``: the distribution and version of the trial's task, provider, policy and
    ``executor`` (:mod:`lagrseq.logs.origins`)."""
    machine = trial_numerics(config)
    samplers = _pinned_samplers(provider_spec, provider_options)
    return {
        **(notes or {}),
        **({"numerics": machine} if machine != NATIVE else {}),
        **({"llm_samplers": samplers} if samplers else {}),
        "provider_options": logged_options(provider_options if provider_options is not None else default_options(provider_spec)),
        "config": _config_json(config),
        origins.PARTS_METADATA: origins.parts_json(origins.trial_parts_origins(config, provider_spec, executor)),
        "task": config.task.name,
        "method": config.method,
        "preset": config.preset,
        "provider": provider_spec,
        "seed": str(seed),
        "trial": str(trial),
        "lagrseq_version": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


@functools.lru_cache(maxsize=16)
def _config_json(config: ExperimentConfig) -> str:
    """``config.to_json()``, made once per configuration (a frozen one): every trial of a run
    logs it, and making it costs about as much as a trial's file header."""
    return config.to_json()


def trains_network(config: ExperimentConfig) -> bool:
    """Whether a trial of ``config`` trains a network (the grid tasks' DQN, the neural SEQ agent):
    only those depend on the machine's floating point."""
    from lagrseq.config import DQNConfig, NeuralSecondaryConfig

    return isinstance(config.primary, DQNConfig) or isinstance(config.secondary, NeuralSecondaryConfig)


def trial_numerics(config: ExperimentConfig) -> str:
    """The numerics a trial of ``config`` runs with here: ``LAGRSEQ_NUMERICS``'s setting for a trial
    that trains a network, ``native`` for one that does not (the setting changes nothing there)."""
    return numerics() if trains_network(config) else NATIVE


def run_one(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    path: Path,
    log: bool = True,
    on_episode: Callable[[int], None] | None = None,
    provider_options: Any = None,
    render_dir: Path | None = None,
    notes: Mapping[str, str] | None = None,
    on_ready: Callable[[], None] | None = None,
    executor: str = "local",
) -> TrialResult:
    """Build trial ``trial``'s parts and run it into ``path`` (``log=False``: no file, for
    benchmarks). ``on_episode(length)`` is called after every episode. ``render_dir``: arm
    tasks write PNG frames and GIFs of the trial's episodes under it (``--render``).
    ``on_ready()`` is called once the parts are built, before the first step (the estimate
    times a trial's start apart from its steps). ``executor``: the executor that runs it, as its
    log names it."""
    config = with_provider_model(config, provider_spec)  # live:MODEL asks MODEL, and the log says so

    def open_sink() -> Sink:
        if not log:
            return NullSink()
        metadata = run_metadata(config, trial, seed, provider_spec, provider_options, notes, executor)
        return McapSink(path, metadata, extra_topics=view_topics(config), task_fields=task_fields(config))

    parts = trial_parts(config, trial, seed, provider_spec, open_sink, provider_options, render_dir)
    if on_ready is not None:
        on_ready()
    with _older_objects_frozen():
        return run_trial(parts, path, on_episode)


@contextlib.contextmanager
def _older_objects_frozen() -> Iterator[None]:
    """During a trial, the garbage collector leaves alone everything that existed before it
    (modules, the configuration, the parts): a trial allocates many short-lived containers, and
    each full collection would walk those objects again for nothing. Measured: about a third of
    the cost of MCAP logging on a cube trial (``benchmarks/bench_cube.py``)."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


# ------------------------------------------------------------------------------------------
# Paths and resume
# ------------------------------------------------------------------------------------------
def provider_slug(spec: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in spec)


MAX_NAME_BYTES = 200
"""Longest ``--name`` (file systems allow 255 bytes a component; a margin for suffixes)."""


def check_name(name: str) -> str:
    """A run directory name given with ``--name``: one path component, inside ``--out``."""
    if (
        not name.strip()
        or name != name.strip()
        or name in (".", "..")
        or any(ch in name for ch in "/\\") or any(ord(ch) < 32 or ord(ch) == 127 for ch in name)
        or Path(name).is_absolute()
    ):
        raise UsageError(
            f"--name {name!r} is not a plain directory name; give one name without '/', '\\', '..', "
            "control characters or surrounding spaces (the run directory is always OUT/<task>/<method>/NAME)"
        )
    if len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        raise UsageError(f"--name is {len(name.encode('utf-8', 'surrogatepass'))} bytes long; give a name of at most {MAX_NAME_BYTES} bytes")
    return name


def run_directory(
    out: Path, config: ExperimentConfig, provider_spec: str, seed: int, name: str | None = None, variant: str = ""
) -> Path:
    """``OUT/<task>/<method>/<name>``; the default name tells preset, provider, seed and a digest
    of the whole configuration, so runs that differ in any field never share a directory, then
    ``-VARIANT`` where given (runs on the authors' answers whose misses are refused or drawn:
    ``lagrseq.suite.miss_variant``)."""
    if name is None:
        name = f"{config.preset}-{provider_slug(provider_spec)}-seed{seed}-{config.digest()}" + (f"-{variant}" if variant else "")
    return out / config.task.name / config.method / check_name(name)


def trial_path(directory: Path, trial: int) -> Path:
    return directory / f"trial-{trial:03d}.mcap"


def _differences(logged: dict[str, Any], wanted: dict[str, Any], prefix: str = "") -> list[str]:
    """``section.field: logged -> wanted`` for every field that differs."""
    out: list[str] = []
    for key in sorted(set(logged) | set(wanted)):
        a, b = logged.get(key), wanted.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            out += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            out.append(f"{prefix}{key}: {json.dumps(a)} -> {json.dumps(b)}")
    return out


def _unfinished_info(path: Path) -> LogInfo | None:
    """What an unfinished log (a finished file with another status, or a ``.partial`` cut short
    by a crash) says about its run: from its summary when it has one, else from the run metadata
    record written at its start. None when neither can be read (nothing to protect then)."""
    from mcap.records import Metadata

    from lagrseq.logs.mcap_reader import Damage, McapFile
    from lagrseq.logs.reader import LogInfo, read_info
    from lagrseq.logs.sink import RUN_METADATA

    with contextlib.suppress(LagrseqError):
        return read_info(path)
    try:
        with McapFile(path) as log:
            for count, (_, _, record) in enumerate(log.scan()):
                if isinstance(record, Metadata) and record.name == RUN_METADATA:
                    return LogInfo(path, dict(record.metadata))
                if count > 16:  # the run metadata follows the header and schemas
                    break
    except (Damage, OSError, LagrseqError):
        pass
    return None


OPERATIONAL_OPTIONS = frozenset({
    "api_key_env", "price_table", "read_timeout_s", "request_deadline_s", "max_response_bytes",
    "max_cost_usd", "max_queries", "local_threads",
})
"""Logged provider options that cannot change an answer (where the key is read, what a request
may cost or take): a rerun may change them (raise a spent budget, wait longer). Every other
option, a plugin provider's included, is part of a run's identity."""


def _shown_value(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def option_differences(logged_text: Any, provider_spec: str, provider_options: Any) -> list[str]:
    """``provider_options.NAME: logged -> wanted`` for every provider option that can change an
    answer and differs between a log and this run (an option the log does not name counts at
    its default: a log made before the option existed)."""
    try:
        logged = json.loads(logged_text) if isinstance(logged_text, str) else None
    except (ValueError, RecursionError):
        logged = None
    if not isinstance(logged, dict):
        return []  # a log without the record: nothing to compare
    defaults = json.loads(logged_options(default_options(provider_spec)))
    wanted = json.loads(logged_options(provider_options if provider_options is not None else default_options(provider_spec)))
    out = []
    for name in sorted(set(logged) | set(wanted)):
        if name in OPERATIONAL_OPTIONS:
            continue
        before, now = logged.get(name, defaults.get(name)), wanted.get(name, defaults.get(name))
        if before != now:
            out.append(f"provider_options.{name}: {_shown_value(before)} -> {_shown_value(now)}")
    return out


def part_differences(logged_text: Any, config: ExperimentConfig, provider_spec: str) -> list[str]:
    """``parts.ROLE: logged -> wanted`` for the task, provider and policy whose distribution (a
    plugin's: distribution and version) differs between a log and this run."""
    logged = origins.read_parts(logged_text)
    if not logged:
        return []  # a log made before parts were logged
    wanted = origins.trial_parts_origins(config, provider_spec)
    out = []
    for role in origins.ANSWER_ROLES:
        before, now = logged.get(role), wanted.get(role)
        if before is None or now is None:
            continue
        if origins.identity(before) != origins.identity(now):
            out.append(f"parts.{role}: {json.dumps(origins.identity(before))} -> {json.dumps(origins.identity(now))}")
    return out


def check_resumable(
    path: Path, config: ExperimentConfig, seed: int, provider_spec: str, trial: int, info: LogInfo | None = None,
    provider_options: Any = None,
) -> None:
    """A complete log may stand for trial ``trial`` of this run only if it was made with the
    same identity: configuration, seed, provider, the provider options that can change an
    answer (``on_miss``, a plugin provider's own), the distribution of each part (a plugin's
    version too) and the numerics; otherwise the rerun is refused in one line naming what
    differs. An unfinished log (``info`` given) of another run is refused too: rerunning the
    trial would overwrite it."""
    unfinished = info is not None
    if info is None:
        from lagrseq.logs.reader import read_info

        info = read_info(path)
    try:
        logged = info.config
    except LagrseqError:
        if not unfinished:
            raise
        return  # no configuration to compare: nothing recognisable to protect
    differences = _config_differences(logged, config)
    for key, value in (("seed", str(seed)), ("provider", provider_spec), ("trial", str(trial))):
        if info.run.get(key) != value:
            differences.append(f"{key}: {json.dumps(info.run.get(key))} -> {json.dumps(value)}")
    differences += option_differences(info.run.get("provider_options"), provider_spec, provider_options)
    differences += part_differences(info.run.get(origins.PARTS_METADATA), config, provider_spec)
    # the numerics are the machine's, not the configuration's (no field, no digest): a log made
    # under other numerics stands for another machine's trial, not for this one's
    made_under, wanted_now = info.run.get("numerics", NATIVE), trial_numerics(config)
    if made_under != wanted_now:
        differences.append(
            f"numerics: {json.dumps(made_under)} -> {json.dumps(wanted_now)} (set LAGRSEQ_NUMERICS={made_under} to resume it)"
        )
    if differences:
        shown = "; ".join(differences[:3]) + (f"; and {len(differences) - 3} more" if len(differences) > 3 else "")
        kept = " (unfinished: a rerun would overwrite it; lagrseq recover keeps its flushed episodes)" if unfinished else ""
        raise UsageError(
            f"{path} was made by another run ({shown}){kept}; give another --name or --out, or remove "
            f"{path.parent} to start over"
        )


def _config_differences(logged: dict[str, Any], config: ExperimentConfig) -> list[str]:
    from lagrseq import config as cfg

    with contextlib.suppress(ConfigError):  # a log made before a field existed holds its default
        logged = json.loads(cfg.from_dict(logged).to_json())
    return _differences(logged, json.loads(config.to_json()))


def progress_unit(config: ExperimentConfig) -> tuple[str, int]:
    """What a progress bar counts for ``config`` and how many per trial: environment steps when
    the trial has a step budget (grid tasks), else episodes. ``run`` and ``reproduce`` both count
    in it."""
    if config.run.max_steps:
        return "step", config.run.max_steps
    return "ep", config.run.episodes


# ------------------------------------------------------------------------------------------
# Running trials
# ------------------------------------------------------------------------------------------
# The process pool lives in lagrseq.running.executors; these names stay importable from here.
_ignore_interrupts = executors._ignore_interrupts
exit_on_next_interrupt = executors.exit_on_next_interrupt
stop_pool = executors.stop_pool
make_executor = executors.make_executor


def lockstep_helps(config: ExperimentConfig) -> bool:
    """Whether the trials of ``config`` gain from running in lockstep: they train networks
    (the grid tasks' DQN, the neural SEQ agent), which then learn in batched calls; and the
    ``greenlet`` package lockstep runs on is installed (else one after the other: the same logs)."""
    from lagrseq.agents import lockstep

    return trains_network(config) and lockstep.available()


def run_in_lockstep(trials: list[Callable[[], TrialResult]]) -> list[TrialResult | BaseException]:
    """Trials (each a call of :func:`run_one`) in lockstep in this process
    (:mod:`lagrseq.agents.lockstep`); each one's result or error. A Ctrl-C stops every trial
    (each keeps its finished episodes) and is raised; a second one ends the process at once."""
    from lagrseq.agents.lockstep import Conductor

    with _older_objects_frozen():
        return Conductor().run(trials, on_interrupt=executors.exit_on_next_interrupt)


def run_group_job(group: executors.GroupJob) -> list[TrialResult | BaseException]:
    """Several trials of one run in lockstep, as one task of an executor; each trial's result
    or error (an error that cannot be pickled is replaced by one that names it)."""
    import pickle

    outcomes = run_in_lockstep([functools.partial(run_trial_job, job) for job in group.jobs])
    for i, outcome in enumerate(outcomes):
        if isinstance(outcome, BaseException):
            try:
                pickle.dumps(outcome)
            except Exception:  # noqa: BLE001 - any pickling failure
                outcomes[i] = RuntimeError(_error_line(outcome))
    return outcomes


def run_trial_job(job: executors.TrialJob) -> TrialResult:
    """One trial as a task of an executor (a module-level function: spawned and Dask workers
    import it). Returns the small result record, never the trial's objects."""
    from lagrseq.config import from_dict

    render_dir = Path(job.render_dir) if job.render_dir is not None else None
    return run_one(
        from_dict(job.config), job.trial, job.seed, job.provider_spec, Path(job.path), provider_options=job.options,
        render_dir=render_dir, notes=job.notes, executor=job.executor,
    )


@dataclass(frozen=True)
class ResumePlan:
    """What a (re)run finds in its directory before it starts."""

    complete: list[int]
    missing: list[int]
    unfinished: list[int]
    """A log or ``.partial`` file that is not a complete log: cut short, failed or recovered."""

    @property
    def todo(self) -> list[int]:
        return sorted(self.missing + self.unfinished)

    def describe(self) -> str:
        return (
            f"resuming: {len(self.complete)} trial{'s' if len(self.complete) != 1 else ''} complete (skipped), "
            f"{len(self.missing)} missing and {len(self.unfinished)} unfinished (cut short, failed or recovered) to run"
        )


def _is_complete(path: Path) -> bool:
    from lagrseq.logs.reader import is_complete

    return is_complete(path)


def resume_plan(
    config: ExperimentConfig, trials: int, seed: int, provider_spec: str, directory: Path, provider_options: Any = None
) -> ResumePlan:
    """Sort trials 0..trials-1 by what their log says; a log made by another run (another
    identity, ``provider_options`` included) is refused (:func:`check_resumable`)."""
    complete: list[int] = []
    missing: list[int] = []
    unfinished: list[int] = []
    for trial in range(trials):
        path = trial_path(directory, trial)
        # the log reader is imported only where there is a log to read (a fresh run has none)
        if path.exists() and _is_complete(path):
            check_resumable(path, config, seed, provider_spec, trial, provider_options=provider_options)
            complete.append(trial)
        elif path.exists() or path.with_name(path.name + PARTIAL_SUFFIX).exists():
            for found in (path, path.with_name(path.name + PARTIAL_SUFFIX)):
                info = _unfinished_info(found) if found.exists() else None
                if info is not None:
                    check_resumable(found, config, seed, provider_spec, trial, info, provider_options)
            unfinished.append(trial)
        else:
            missing.append(trial)
    return ResumePlan(complete, missing, unfinished)


RERUN_ADVICE = "run the same command again to rerun the failed trials"
"""What to do about a failure that may pass (a server that did not answer, a worker that died,
a full disk)."""
MISS_ADVICE = (
    "a store miss is deterministic (a rerun misses again): record the prompt (lagrseq record) "
    "or set what a miss does (on_miss, --on-miss mock|refuse)"
)
"""What to do about a recorded store's miss (:class:`~lagrseq.errors.RecordMiss`)."""
BUDGET_ADVICE = "the budget is spent: raise --max-cost-usd or --max-queries, then run the same command again"
FIX_ADVICE = "a rerun fails the same way: fix what the error names, then run the same command again"
CODE_ADVICE = (
    "a trial is deterministic, so a rerun most likely fails the same way: fix the part that raised it "
    "(lagrseq plugins names where each part comes from), then run the same command again"
)
"""What to do about an exception of the trial's own code (a task's, a policy's, a provider's)."""
TRANSIENT_ERRORS: tuple[type[BaseException], ...] = (OSError, MemoryError, ProviderError, LogError)
"""Failures that may pass: the network, a server, the disk, memory (a record a task made that
it does not declare is a :class:`~lagrseq.errors.RecordError`, never transient)."""
DETERMINISTIC_ERRORS: tuple[type[BaseException], ...] = (ConfigError, UsageError, StoreError, ParseError, RecordError)


def rerun_advice(exc: BaseException) -> str:
    """What to do about a trial that raised ``exc``, by its cause: "run again" only where the
    cause may pass (a network or disk error, a lost worker); a store's miss, a spent budget, a
    bad configuration, store or task record, and any other exception of the trial's own code
    (deterministic: the same seed raises it again) say what to change instead."""
    if isinstance(exc, RecordMiss):
        return MISS_ADVICE
    if isinstance(exc, BudgetExceeded):
        return BUDGET_ADVICE
    if isinstance(exc, DETERMINISTIC_ERRORS):
        return FIX_ADVICE
    if isinstance(exc, TRANSIENT_ERRORS) or _lost_worker(exc):
        return RERUN_ADVICE
    return CODE_ADVICE


def _lost_worker(exc: BaseException) -> bool:
    """A worker process that died (a pool's BrokenProcessPool, Dask's KilledWorker or a closed
    connection to it)."""
    from concurrent.futures import BrokenExecutor

    return isinstance(exc, BrokenExecutor) or type(exc).__name__ in ("KilledWorker", "CommClosedError")


@dataclass(frozen=True)
class TrialFailure:
    trial: int
    seed: int
    digest: str
    error: str
    """The error's whole text, on one line (an exception that is no lagrseq error: with its type)."""
    advice: str = RERUN_ADVICE
    """:func:`rerun_advice` of the error."""

    def describe(self) -> str:
        return f"trial {self.trial} (seed {self.seed}, config {self.digest}) failed: {self.error}"


@dataclass(frozen=True)
class RunFailures:
    """One run's failed trials: what :class:`~lagrseq.errors.TrialsFailed` carries per run."""

    directory: Path
    total: int
    """Trials the run had to run (the failed ones among them)."""
    failures: tuple[TrialFailure, ...]

    @property
    def advice(self) -> str:
        """The failures' advice (each distinct one once, the first failure's first)."""
        return "; ".join(dict.fromkeys(f.advice for f in self.failures))


def _error_line(exc: BaseException) -> str:
    text = str(exc) if isinstance(exc, LagrseqError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def _failed(failures: list[TrialFailure], total: int, directory: Path) -> TrialsFailed:
    """The one line that ends a sweep in which some trials raised."""
    failures = sorted(failures, key=lambda f: f.trial)
    run = RunFailures(directory, total, tuple(failures))
    if total == 1 and len(failures) == 1:
        return TrialsFailed(f"{failures[0].describe()}; {run.advice}", [run])
    shown = ", ".join(str(f.trial) for f in failures[:10]) + (", ..." if len(failures) > 10 else "")
    others = f"the other logs in {directory} are complete" if len(failures) < total else "no trial finished"
    return TrialsFailed(
        f"{len(failures)} of {total} trials failed (trials {shown}; first: {failures[0].describe()}); "
        f"{others}; {run.advice}",
        [run],
    )


def run_trials(
    config: ExperimentConfig,
    trials: int,
    seed: int,
    provider_spec: str,
    directory: Path,
    jobs: int = 1,
    progress: Any = None,
    provider_options: Any = None,
    pool: executors.TrialExecutor | None = None,
    reporter: Reporter | None = None,
    retries: int = 0,
    render_dir: Path | None = None,
) -> list[TrialResult]:
    """Run trials 0..trials-1 into ``directory``; trials whose log is complete (and made by this
    very run) are skipped, and ``reporter`` is told how many of each kind there are before
    anything starts (None: nothing is said). ``pool``: an executor to use (``reproduce`` keeps
    one warm; ``--executor dask``); without one, ``jobs > 1`` runs a local process pool and
    ``jobs = 1`` this process.

    A trial that raises is tried again up to ``retries`` times (not after a budget stop); then it
    is reported to ``reporter.warn`` (with its config digest, seed and index) while the other
    trials go on, and :class:`TrialsFailed` is raised at the end. A spent run budget stops each trial at its
    first paid request, so trials that need none still finish. Ctrl-C stops the running trials
    (their ``.partial`` files stay). ``render_dir``: arm tasks write PNG frames and GIFs there
    (``--render``)."""
    run = SweepRun(config, trials, seed, provider_spec, directory, provider_options, render_dir, progress)
    return run_sweep([run], jobs, pool, reporter, retries)[0]


@dataclass
class SweepRun:
    """One run of a sweep: what :func:`run_trials` takes, as data. ``progress``: something with
    ``update(n)`` that counts this run's steps or episodes (:func:`progress_unit`)."""

    config: ExperimentConfig
    trials: int
    seed: int
    provider_spec: str
    directory: Path
    provider_options: Any = None
    render_dir: Path | None = None
    progress: Any = None
    notes: Mapping[str, str] | None = None
    """More entries for each trial's run metadata (:func:`run_metadata`)."""
    seconds: float | None = None
    """Expected seconds of one of its trials, if known (``reproduce``'s estimate): a pool starts
    the longest groups of trials first, so that no long group starts last and runs alone."""


@dataclass
class _Todo:
    """A run's trials still to run, and where their outcomes go."""

    run: SweepRun
    todo: list[int]
    options: Any
    per_trial: int
    results: list[TrialResult]
    failures: list[TrialFailure]


def run_sweep(
    runs: list[SweepRun],
    jobs: int = 1,
    pool: executors.TrialExecutor | None = None,
    reporter: Reporter | None = None,
    retries: int = 0,
    keep_going: bool = False,
) -> list[list[TrialResult]]:
    """Several runs' trials through one executor, as :func:`run_trials` runs one run's: every
    pending trial of every run is submitted at once, so no worker waits for the last trial of one
    run before the next run starts (a frontier's policies, a suite's runs). Each run's directory
    is checked (resume plan, refused foreign logs) before any trial starts. Returns each run's
    results, in the order of ``runs``; a trial that keeps failing is reported to ``reporter.warn`` while
    the others go on, and one :class:`TrialsFailed` at the end names them all (and carries each
    run's failures). ``keep_going``: a run whose directory or provider is refused before it
    starts (a foreign log, a store that cannot be read) counts as a run whose trials all failed,
    and the other runs go on (``lagrseq reproduce``); otherwise nothing starts."""
    reporter = reporter or Reporter.silent()
    plans: list[_Todo] = []
    refused: list[RunFailures] = []
    for run in runs:
        try:
            parse_provider(run.provider_spec)
            found = resume_plan(run.config, run.trials, run.seed, run.provider_spec, run.directory, run.provider_options)
        except LagrseqError as exc:
            if not keep_going:
                raise
            failure = functools.partial(TrialFailure, seed=run.seed, digest=run.config.digest(), error=_error_line(exc), advice=rerun_advice(exc))
            refused.append(RunFailures(run.directory, run.trials, tuple(failure(trial) for trial in range(run.trials))))
            continue
        if found.complete or found.unfinished:
            reporter.say(found.describe() if len(runs) == 1 else f"{run.directory}: {found.describe()}")
        _, per_trial = progress_unit(run.config)
        results = [TrialResult(trial_path(run.directory, t), t, 0, 0, 0, 0.0, 0.0, skipped=True) for t in found.complete]
        if run.progress is not None and found.complete:
            run.progress.update(per_trial * len(found.complete))
        options = _with_ledger(run.provider_spec, run.provider_options, run.directory)
        plans.append(_Todo(run, found.todo, options, per_trial, results, []))
    pending = sum(len(p.todo) for p in plans)

    def failed(plan: _Todo, trial: int, exc: BaseException) -> None:
        failure = TrialFailure(trial, plan.run.seed, plan.run.config.digest(), _error_line(exc), rerun_advice(exc))
        plan.failures.append(failure)
        if pending > 1:
            reporter.warn(failure.describe() if len(runs) == 1 else f"{plan.run.directory}: {failure.describe()}")

    if pool is None and (jobs <= 1 or pending <= 1):
        _run_here(plans, retries, failed)
    else:
        with contextlib.ExitStack() as stack:
            if pool is None:
                pool = stack.enter_context(executors.LocalExecutor(jobs))
            _run_pooled(pool, plans, retries, failed)
    broken = [p for p in plans if p.failures]
    if len(broken) == 1 and len(runs) == 1:
        raise _failed(broken[0].failures, len(broken[0].todo), broken[0].run.directory)
    if broken or refused:
        ended = [_failed(p.failures, len(p.todo), p.run.directory) for p in broken]
        ended += [_failed(list(r.failures), r.total, r.directory) for r in refused]
        raise TrialsFailed(
            f"{len(ended)} of {len(runs)} runs had failed trials: " + " | ".join(map(str, ended)),
            [run for error in ended for run in error.runs],
        )
    return [sorted(p.results, key=lambda r: r.trial) for p in plans]


LOCKSTEP_GROUP_MAX = 16
"""At most this many trials in one lockstep group where there are more than one group per
worker's worth (a group's trials report their progress when the group ends)."""


def lockstep_family(config: ExperimentConfig) -> str | None:
    """Which trials may share a lockstep group: trials that train networks (:func:`lockstep_helps`)
    of one task, whatever their run (their networks have the task's shapes, so they meet in one
    batched call), or None for a trial that runs alone."""
    return config.task.name if lockstep_helps(config) else None


def lockstep_groups(runs: Sequence[tuple[ExperimentConfig, list[int]]], workers: int) -> list[list[tuple[int, int]]]:
    """The groups the pending trials of ``runs`` (each a configuration and its pending trials)
    run in, as (index into ``runs``, trial): trials of one lockstep family
    (:func:`lockstep_family`), across runs, in contiguous groups of near-equal size, as many as
    ``workers`` (a multiple of it where groups would be larger than :data:`LOCKSTEP_GROUP_MAX`);
    every other trial a group of its own. Which trials share a group changes only the speed,
    never a log (a trial in lockstep writes the bytes it writes alone)."""
    workers = max(1, workers)
    families: dict[str, list[tuple[int, int]]] = {}
    groups: list[list[tuple[int, int]]] = []
    for index, (config, todo) in enumerate(runs):
        family = lockstep_family(config)
        for trial in todo:
            if family is None:
                groups.append([(index, trial)])
            else:
                families.setdefault(family, []).append((index, trial))
    for members in families.values():
        count = workers * -(-len(members) // (workers * LOCKSTEP_GROUP_MAX))
        groups += [[members[i] for i in group] for group in groups_of(list(range(len(members))), count)]
    return groups


def _groups(plans: list[_Todo], workers: int) -> list[list[tuple[_Todo, int]]]:
    groups = lockstep_groups([(plan.run.config, plan.todo) for plan in plans], workers)
    return [[(plans[index], trial) for index, trial in group] for group in groups]


def _run_here(plans: list[_Todo], retries: int, failed: Callable[[_Todo, int, BaseException], None]) -> None:
    """The runs' trials in this process, episode by episode on their bars: trials that train
    networks in lockstep groups across runs (:func:`lockstep_groups`), the others one after the
    other."""

    def trial_call(plan: _Todo, trial: int) -> Callable[[], TrialResult]:
        run = plan.run
        unit, _ = progress_unit(run.config)
        on_episode = None
        if run.progress is not None:
            bar = run.progress
            on_episode = (lambda steps: bar.update(steps)) if unit == "step" else (lambda _: bar.update(1))
        return functools.partial(
            run_one, run.config, trial, run.seed, run.provider_spec, trial_path(run.directory, trial), on_episode=on_episode,
            provider_options=plan.options, render_dir=run.render_dir, notes=run.notes,
        )

    for group in _groups(plans, 1):
        if len(group) > 1:
            todo = list(group)
            for attempt in range(retries + 1):
                outcomes = run_in_lockstep([trial_call(plan, trial) for plan, trial in todo])
                again: list[tuple[_Todo, int]] = []
                for (plan, trial), outcome in zip(todo, outcomes, strict=True):
                    if isinstance(outcome, TrialResult):
                        plan.results.append(outcome)
                    elif attempt == retries or isinstance(outcome, BudgetExceeded) or not isinstance(outcome, Exception):
                        failed(plan, trial, outcome)
                    else:
                        again.append((plan, trial))
                todo = again
                if not todo:
                    break
            continue
        [(plan, trial)] = group
        for attempt in range(retries + 1):
            try:
                plan.results.append(trial_call(plan, trial)())
                break
            except Exception as exc:
                if attempt == retries or isinstance(exc, BudgetExceeded):
                    failed(plan, trial, exc)
                    break


def groups_of(todo: list[int], workers: int) -> list[list[int]]:
    """Pending trials as ``workers`` contiguous groups of near-equal size (fewer when there are
    fewer trials): which trials share a group changes only the speed, never a log."""
    count = max(1, min(workers, len(todo)))
    size, extra = divmod(len(todo), count)
    groups: list[list[int]] = []
    start = 0
    for i in range(count):
        end = start + size + (1 if i < extra else 0)
        groups.append(todo[start:end])
        start = end
    return [g for g in groups if g]


def executor_name(pool: executors.TrialExecutor) -> str:
    """The registered name of ``pool``'s executor (:func:`executors.make_executor` names every
    executor it makes; an executor made otherwise is the one its class names)."""
    return str(getattr(pool, "name", "local"))


def _run_pooled(
    pool: executors.TrialExecutor,
    plans: list[_Todo],
    retries: int,
    failed: Callable[[_Todo, int, BaseException], None],
) -> None:
    """The trials of ``plans`` as tasks of ``pool``, all submitted at once: trials that train
    networks as lockstep groups across runs (:func:`lockstep_groups`, at least one per worker),
    the others one trial a task; the longest first where every run's trial length is known
    (:attr:`SweepRun.seconds`), else the groups first, in run order. A trial that fails is
    retried up to ``retries`` times, alone."""
    owners: dict[Any, tuple[list[tuple[_Todo, int]], int]] = {}
    digests = {
        id(plan): executors.run_digest(plan.run.config.to_json(), plan.run.seed, plan.run.provider_spec, str(plan.run.directory))
        for plan in plans
    }
    dicts = {id(plan): plan.run.config.to_dict() for plan in plans}

    def job(plan: _Todo, trial: int, attempt: int) -> executors.TrialJob:
        run = plan.run
        return executors.TrialJob(
            dicts[id(plan)], trial, run.seed, run.provider_spec, str(trial_path(run.directory, trial)), plan.options,
            executors.task_key(digests[id(plan)], trial, attempt),
            str(run.render_dir) if run.render_dir is not None else None, dict(run.notes) if run.notes else None,
            executor_name(pool),
        )

    def submit(trials: list[tuple[_Todo, int]], attempt: int) -> Any:
        if len(trials) == 1:
            handle = pool.submit(run_trial_job, job(*trials[0], attempt))
        else:
            jobs = tuple(job(plan, trial, attempt) for plan, trial in trials)
            handle = pool.submit(run_group_job, executors.GroupJob(jobs, executors.group_key(jobs)))
        owners[handle] = (trials, attempt)
        return handle

    groups = _groups(plans, pool.workers)
    if all(plan.run.seconds is not None for plan in plans):  # the longest first (as a list scheduler does)
        groups.sort(key=lambda group: -sum(plan.run.seconds or 0.0 for plan, _ in group))
    else:  # groups (long) first, then the trials alone
        groups.sort(key=lambda group: len(group) == 1)
    pending = [submit(group, 0) for group in groups]
    try:
        while pending:
            again: list[Any] = []
            for handle in pool.completed(pending):
                trials, attempt = owners[handle]
                try:
                    value = pool.result(handle)
                    outcomes = value if len(trials) > 1 else [value]
                except Exception as exc:  # the task itself failed (a trial alone, or a worker lost)
                    outcomes = [exc] * len(trials)
                for (plan, trial), outcome in zip(trials, outcomes, strict=True):
                    if isinstance(outcome, BaseException):
                        if attempt < retries and isinstance(outcome, Exception) and not isinstance(outcome, BudgetExceeded):
                            again.append(submit([(plan, trial)], attempt + 1))
                        else:
                            failed(plan, trial, outcome)
                        continue
                    plan.results.append(outcome)
                    if plan.run.progress is not None:
                        plan.run.progress.update(plan.per_trial)
            pending = again
    except KeyboardInterrupt:
        # Ctrl-C: nothing more starts, the running trials stop, nothing half-made is renamed.
        executors.exit_on_next_interrupt()
        pool.interrupt()
        raise


class TrialCount:
    """A progress bar that counts whole trials, fed one run's progress units (episodes or steps,
    :func:`progress_unit`): the ``progress`` of a :class:`SweepRun`."""

    def __init__(self, bar: Any, config: ExperimentConfig) -> None:
        self.bar = bar
        self.per_trial = max(1, progress_unit(config)[1])
        self.units = 0

    def update(self, n: int = 1) -> None:
        before = self.units // self.per_trial
        self.units += n
        self.bar.update(self.units // self.per_trial - before)


def _with_ledger(provider_spec: str, options: Any, directory: Path) -> Any:
    """A run that may spend money (live answers) under ``--max-cost-usd`` or ``--max-queries``
    keeps one budget for all its trials and workers: a ledger file in the run directory
    (:mod:`lagrseq.llm.ledger`), in the options' :class:`~lagrseq.llm.options.Limits`."""
    from lagrseq.llm.options import Limits

    limits = find_part(options, Limits)
    if limits is None or not limits.limited or limits.budget_ledger is not None:
        return options
    if not pays(provider_spec, options):
        return options
    directory.mkdir(parents=True, exist_ok=True)
    return replace_part(options, replace(limits, budget_ledger=str(directory / LEDGER_NAME)))


LEDGER_NAME = "budget-ledger.sqlite"
"""The run's shared budget ledger, in its run directory (only when a budget is set)."""


def prepare(
    task: str,
    method: str,
    preset: str,
    config_file: Path | None,
    overrides: list[str],
    provider_spec: str,
    options: Any,
    out: Path,
    seed: int,
    name: str | None = None,
) -> tuple[ExperimentConfig, Path]:
    """What ``lagrseq run`` checks before any trial starts: the output directory, the
    configuration, the installed extras and the provider (a missing key or store fails here,
    nothing sent). Returns the resolved configuration and the run directory."""
    from lagrseq.paths import writable_directory

    if name is not None:
        check_name(name)
    config = check(task, method, preset, config_file, overrides, provider_spec, options)
    writable_directory(out)
    return config, run_directory(out, config, provider_spec, seed, name)


def check(
    task: str, method: str, preset: str, config_file: Path | None, overrides: list[str], provider_spec: str, options: Any,
) -> ExperimentConfig:
    """:func:`prepare`'s checks that write nothing: the configuration, the installed extras and
    the provider. Returns the resolved configuration (a command that runs several
    configurations checks them all before it makes its output folder)."""
    from lagrseq import config as cfg
    from lagrseq.running.wiring import check_provider, missing_dependency

    config = with_provider_model(cfg.load(task, method, preset, config_file, overrides), provider_spec)
    missing = missing_dependency(config)
    if missing:
        raise UsageError(f"{task} {missing}")
    check_provider(provider_spec, config, options)
    return config


def miss_report(results: list[TrialResult], provider_spec: str) -> list[str]:
    """With ``recorded:STORE``: ``answers: N from the store, M from the fallback mock (P% missed
    the store)``; nothing for other providers."""
    if not provider_kind(provider_spec).replays:
        return []
    totals: dict[str, int] = {}
    for result in results:
        for source, count in result.sources:
            totals[source] = totals.get(source, 0) + count
    stored = totals.pop("recorded", 0)
    missed = sum(totals.values())
    share = 100.0 * missed / (stored + missed) if stored + missed else 0.0
    refused = totals.pop("miss", 0)
    fallback = ", ".join(f"{n} from the fallback {source}" for source, n in sorted(totals.items()))
    fallback = fallback or ("none from a fallback" if not refused else "")
    if refused:
        fallback += (", " if fallback else "") + f"{refused} refused (--on-miss refuse: never accepted)"
    return [f"answers: {stored} from the store, {fallback} ({share:.1f}% missed the store)"]


def summary(results: list[TrialResult], directory: Path, provider_spec: str = "") -> str:
    """What ``lagrseq run`` prints at the end: where the logs are, queries and return per trial."""
    ran = [r for r in results if not r.skipped]
    skipped = len(results) - len(ran)
    lines = [f"{len(results)} trial logs in {directory}" + (f" ({skipped} already complete, skipped)" if skipped else "")]
    if ran:
        queries = np.array([r.queries for r in ran], dtype=float)
        returns = np.array([r.total_return for r in ran], dtype=float)
        se = queries.std(ddof=1) / np.sqrt(len(ran)) if len(ran) > 1 else 0.0
        lines.append(
            f"queries per trial {queries.mean():.1f} +- {se:.2f} (s.e.), "
            f"return per trial {returns.mean():.1f}, "
            f"{np.mean([r.seconds for r in ran]):.2f} s per trial"
        )
        if provider_spec:
            lines.extend(miss_report(ran, provider_spec))
    return "\n".join(lines)
