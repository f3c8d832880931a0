"""Where the trials of a sweep run: the executor interface and the local process pool.

A trial is one task: :class:`TrialJob` (the configuration as a plain dict, seed, trial index,
provider, log path) in, a :class:`~lagrseq.loop.experiment.TrialResult` (a few numbers and the path)
out; the MCAP file is written under the run directory as ``NAME.partial`` and renamed when
complete. Two executors run such tasks:

- ``local`` (default): a pool of spawned worker processes on this machine
  (:class:`LocalExecutor`);
- ``dask``: Dask distributed, a ``LocalCluster`` on 127.0.0.1 or an existing scheduler
  (:mod:`lagrseq.running.dask_executor`, imported only when asked for, so dask stays an optional extra).

Both give the same logs: a trial's events depend only on its job, never on where it ran. The
runner (:func:`lagrseq.running.runner.run_trials`) drives either through :meth:`TrialExecutor.submit`,
:meth:`TrialExecutor.completed` and, on Ctrl-C, :meth:`TrialExecutor.interrupt`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Any

from lagrseq.errors import UsageError
from lagrseq.progress import Reporter
from lagrseq.registry import EXECUTORS as REGISTRY
from lagrseq.running.executor_base import (
    SCHEDULER_SCHEMES,
    TRACKER_QUIET,
    GroupJob,
    Job,
    TrialExecutor,
    TrialJob,
    _ignore_interrupts,
    check_scheduler,
    exit_on_next_interrupt,
    group_key,
    quiet_resource_tracker,
    run_digest,
    task_key,
)

if TYPE_CHECKING:
    from concurrent.futures import Future, ProcessPoolExecutor

__all__ = [
    "SCHEDULER_SCHEMES", "TRACKER_QUIET", "GroupJob", "Job", "LocalExecutor", "TrialExecutor", "TrialJob",
    "_ignore_interrupts", "check_scheduler", "exit_on_next_interrupt", "group_key", "make_executor", "quiet_resource_tracker", "run_digest",
    "stop_pool", "task_key",
]


def __getattr__(name: str) -> Any:
    if name == "EXECUTORS":  # read lazily: plugins add executors
        return REGISTRY.names()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

DASK_MISSING = "--executor dask needs dask distributed, which is not installed: pip install 'lagrseq[dask]'"


def stop_pool(pool: ProcessPoolExecutor) -> None:
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


class LocalExecutor(TrialExecutor):
    """A pool of ``jobs`` worker processes, spawned rather than forked (forking a process that
    runs threads, the progress bar's or torch's, can deadlock)."""

    name = "local"

    def __init__(self, jobs: int) -> None:
        # imported only here: a run of --jobs 1 never starts a pool (multiprocessing's imports cost
        # a few per cent of a short run's start-up)
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        self.workers = jobs
        quiet_resource_tracker()
        self.pool = ProcessPoolExecutor(
            max_workers=jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_interrupts
        )

    def submit(self, fn: Callable[[Any], Any], job: Job) -> Future[Any]:
        return self.pool.submit(fn, job)

    def completed(self, handles: Iterable[Future[Any]]) -> Iterator[Future[Any]]:
        from concurrent.futures import as_completed

        return as_completed(list(handles))

    def result(self, handle: Future[Any]) -> Any:
        return handle.result()

    def interrupt(self) -> None:
        stop_pool(self.pool)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


def make_executor(kind: str, jobs: int, scheduler: str | None = None, reporter: Reporter | None = None) -> TrialExecutor:
    """The executor ``--executor kind`` names (its registered factory; ``scheduler``: an existing
    Dask scheduler's address). ``reporter`` is told one line about a started cluster (its
    dashboard); None: nothing is said."""
    spec = REGISTRY.get(kind)
    if scheduler is not None and not spec.takes_scheduler:
        raise UsageError(f"--scheduler applies to --executor {' or '.join(s.name for s in REGISTRY.specs() if s.takes_scheduler)} only")
    if scheduler is not None:
        check_scheduler(scheduler)
    executor = spec.make(jobs, scheduler, reporter or Reporter.silent())
    with contextlib.suppress(AttributeError, TypeError):  # its logs name the executor by its registered name
        if getattr(executor, "name", None) != kind:
            executor.name = kind
    return executor  # type: ignore[no-any-return]


def make_local(jobs: int, scheduler: str | None = None, reporter: Reporter | None = None) -> TrialExecutor:
    return LocalExecutor(jobs)


def make_dask(jobs: int, scheduler: str | None = None, reporter: Reporter | None = None) -> TrialExecutor:
    """Dask distributed (imported only now: dask is an optional extra)."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise UsageError(DASK_MISSING)
    from lagrseq.running.dask_executor import DaskExecutor

    return DaskExecutor(jobs, scheduler, reporter)
