"""Several trials of one run: paths, resume, a process pool, progress, and Ctrl-C.

A run writes ``OUT/<task>/<method>/<name>/trial-NNN.mcap``, one file per trial. A rerun skips a
trial whose log is complete, but only if that log was made with the same configuration, seed and
provider (``--name`` lets two configurations meet in one directory: that is refused). Trials run
in this process (``jobs=1``) or in a pool of spawned worker processes; Ctrl-C cancels the trials
not started, stops the running ones (their flushed episodes stay in ``.partial`` files that
``lagrseq recover`` turns into valid logs) and raises KeyboardInterrupt; a second Ctrl-C exits at
once.
"""

from __future__ import annotations

import contextlib
import gc
import json
import multiprocessing
import os
import platform
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq import __version__
from lagrseq.config import ExperimentConfig
from lagrseq.errors import UsageError
from lagrseq.experiment import TrialResult, run_trial
from lagrseq.logs.reader import is_complete, read_info
from lagrseq.logs.sink import McapSink, NullSink, Sink
from lagrseq.wiring import (
    ProviderOptions,
    parse_provider,
    trial_parts,
    view_topics,
    with_provider_model,
)


def run_metadata(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    provider_options: ProviderOptions | None = None,
) -> dict[str, str]:
    """The ``lagrseq.run`` metadata record: everything replay needs to know about the trial."""
    return {
        "provider_options": (provider_options or ProviderOptions()).to_json(),
        "config": config.to_json(),
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


def run_one(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    path: Path,
    log: bool = True,
    on_episode: Callable[[int], None] | None = None,
    provider_options: ProviderOptions | None = None,
) -> TrialResult:
    """Build trial ``trial``'s parts and run it into ``path`` (``log=False``: no file, for
    benchmarks). ``on_episode(length)`` is called after every episode."""
    config = with_provider_model(config, provider_spec)  # live:MODEL asks MODEL, and the log says so

    def open_sink() -> Sink:
        if not log:
            return NullSink()
        metadata = run_metadata(config, trial, seed, provider_spec, provider_options)
        return McapSink(path, metadata, extra_topics=view_topics(config))

    parts = trial_parts(config, trial, seed, provider_spec, open_sink, provider_options)
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


def check_name(name: str) -> str:
    """A run directory name given with ``--name``: one path component, inside ``--out``."""
    if not name or name in (".", "..") or any(ch in name for ch in "/\\\0") or Path(name).is_absolute():
        raise UsageError(
            f"--name {name!r} is not a plain directory name; give one name without '/', '\\', '..' "
            "(the run directory is always OUT/<task>/<method>/NAME)"
        )
    return name


def run_directory(out: Path, config: ExperimentConfig, provider_spec: str, seed: int, name: str | None = None) -> Path:
    """``OUT/<task>/<method>/<name>``; the default name tells preset, provider, seed and a digest
    of the whole configuration, so runs that differ in any field never share a directory."""
    if name is None:
        name = f"{config.preset}-{provider_slug(provider_spec)}-seed{seed}-{config.digest()}"
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


def check_resumable(path: Path, config: ExperimentConfig, seed: int, provider_spec: str, trial: int) -> None:
    """A complete log may stand for trial ``trial`` of this run only if it was made with the
    same configuration, seed and provider; otherwise the rerun is refused."""
    from lagrseq import config as cfg
    from lagrseq.errors import ConfigError

    info = read_info(path)
    wanted = json.loads(config.to_json())
    logged = info.config
    with contextlib.suppress(ConfigError):  # a log made before a field existed holds its default
        logged = json.loads(cfg.from_dict(logged).to_json())
    differences = _differences(logged, wanted)
    for key, value in (("seed", str(seed)), ("provider", provider_spec), ("trial", str(trial))):
        if info.run.get(key) != value:
            differences.append(f"{key}: {json.dumps(info.run.get(key))} -> {json.dumps(value)}")
    if differences:
        shown = "; ".join(differences[:3]) + (f"; and {len(differences) - 3} more" if len(differences) > 3 else "")
        raise UsageError(
            f"{path} was made by another run ({shown}); give another --name or --out, or remove "
            f"{path.parent} to start over"
        )


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
def _ignore_interrupts() -> None:
    """Workers leave Ctrl-C to the parent, which stops them (SIGINT reaches the whole process
    group; a worker that handled it itself would race the parent's cancellation)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def process_pool(jobs: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``jobs`` worker processes, spawned rather than forked (forking a process that
    runs threads, the progress bar's or torch's, can deadlock). Leaving it normally waits for
    the trials; leaving it on an error or Ctrl-C stops them at once."""
    pool = ProcessPoolExecutor(
        max_workers=jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_interrupts
    )
    try:
        yield pool
    except KeyboardInterrupt:
        exit_on_next_interrupt()
        stop_pool(pool)
        raise
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_trial_job(args: tuple[Any, ...]) -> TrialResult:
    config_dict, trial, seed, provider_spec, path, options = args
    from lagrseq.config import from_dict

    return run_one(from_dict(config_dict), trial, seed, provider_spec, Path(path), provider_options=options)


def stop_pool(pool: Executor) -> None:
    """Stop the worker processes now and cancel every trial not started: a running trial's
    ``.partial`` file keeps its flushed episodes (``lagrseq recover``). The workers are taken
    before ``shutdown``, which forgets them."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(timeout=5)


def exit_on_next_interrupt() -> None:
    """Cleaning up after a Ctrl-C: from now on a Ctrl-C ends the process at once with status
    130, whatever it is doing. The process is on its way out anyway."""
    with contextlib.suppress(ValueError):  # not the main thread: nothing to install
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))


def run_trials(
    config: ExperimentConfig,
    trials: int,
    seed: int,
    provider_spec: str,
    directory: Path,
    jobs: int = 1,
    progress: Any = None,
    provider_options: ProviderOptions | None = None,
    pool: Executor | None = None,
) -> list[TrialResult]:
    """Run trials 0..trials-1 into ``directory``; trials whose log is complete (and made by this
    very run) are skipped. ``pool``: an executor to reuse (``reproduce`` keeps one warm)."""
    parse_provider(provider_spec)
    unit, per_trial = progress_unit(config)
    results: list[TrialResult] = []
    todo: list[int] = []
    for trial in range(trials):
        path = trial_path(directory, trial)
        if is_complete(path):
            check_resumable(path, config, seed, provider_spec, trial)
            results.append(TrialResult(path, trial, 0, 0, 0, 0.0, 0.0, skipped=True))
            if progress is not None:
                progress.update(per_trial)
        else:
            todo.append(trial)
    if pool is None and (jobs <= 1 or len(todo) <= 1):
        on_episode = None
        if progress is not None:
            on_episode = (lambda steps: progress.update(steps)) if unit == "step" else (lambda _: progress.update(1))
        for trial in todo:
            path = trial_path(directory, trial)
            results.append(run_one(config, trial, seed, provider_spec, path, on_episode=on_episode, provider_options=provider_options))
        return sorted(results, key=lambda r: r.trial)
    with contextlib.ExitStack() as stack:
        if pool is None:
            pool = stack.enter_context(process_pool(jobs))
        futures: list[Future[TrialResult]] = []
        try:
            for trial in todo:
                job = (config.to_dict(), trial, seed, provider_spec, str(trial_path(directory, trial)), provider_options)
                futures.append(pool.submit(_run_trial_job, job))
            for future in as_completed(futures):
                results.append(future.result())
                if progress is not None:
                    progress.update(per_trial)
        except KeyboardInterrupt:
            # Ctrl-C: nothing more starts, the running trials stop, nothing half-made is renamed.
            exit_on_next_interrupt()
            stop_pool(pool)
            raise
        except BaseException:
            # A failed trial: the queued ones never start, the running ones finish their logs.
            for future in futures:
                future.cancel()
            raise
    return sorted(results, key=lambda r: r.trial)


def with_episodes(config: ExperimentConfig, episodes: int) -> ExperimentConfig:
    """A copy of ``config`` with another episode count."""
    return replace(config, run=replace(config.run, episodes=episodes))



def prepare(
    task: str,
    method: str,
    preset: str,
    config_file: Path | None,
    overrides: list[str],
    provider_spec: str,
    options: ProviderOptions,
    out: Path,
    seed: int,
    name: str | None = None,
) -> tuple[ExperimentConfig, Path]:
    """What ``lagrseq run`` checks before any trial starts: the output directory, the
    configuration, the installed extras and the provider (a missing key or store fails here,
    nothing sent). Returns the resolved configuration and the run directory."""
    from lagrseq import config as cfg
    from lagrseq.paths import writable_directory
    from lagrseq.wiring import check_provider, missing_dependency

    provider = parse_provider(provider_spec)
    if options.on_miss != "error" and provider.kind != "recorded":
        raise UsageError(f"--on-miss {options.on_miss} applies to --provider recorded:STORE only")
    if name is not None:
        check_name(name)
    config = with_provider_model(cfg.load(task, method, preset, config_file, overrides), provider_spec)
    missing = missing_dependency(config)
    if missing:
        raise UsageError(f"{task} {missing}")
    check_provider(provider_spec, config, options)
    writable_directory(out)
    return config, run_directory(out, config, provider_spec, seed, name)


def miss_report(results: list[TrialResult], provider_spec: str) -> list[str]:
    """With ``recorded:STORE``: ``answers: N from the store, M from the fallback mock (P% missed
    the store)``; nothing for other providers."""
    if parse_provider(provider_spec).kind != "recorded":
        return []
    totals: dict[str, int] = {}
    for result in results:
        for source, count in result.sources:
            totals[source] = totals.get(source, 0) + count
    stored = totals.pop("recorded", 0)
    missed = sum(totals.values())
    share = 100.0 * missed / (stored + missed) if stored + missed else 0.0
    fallback = ", ".join(f"{n} from the fallback {source}" for source, n in sorted(totals.items())) or "none from a fallback"
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
