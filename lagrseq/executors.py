"""Where the trials of a sweep run: the executor interface and the local process pool.

A trial is one task: :class:`TrialJob` (the configuration as a plain dict, seed, trial index,
provider, log path) in, a :class:`~lagrseq.experiment.TrialResult` (a few numbers and the path)
out; the MCAP file is written under the run directory as ``NAME.partial`` and renamed when
complete. Two executors run such tasks:

- ``local`` (default): a pool of spawned worker processes on this machine
  (:class:`LocalExecutor`);
- ``dask``: Dask distributed, a ``LocalCluster`` on 127.0.0.1 or an existing scheduler
  (:mod:`lagrseq.dask_executor`, imported only when asked for, so dask stays an optional extra).

Both give the same logs: a trial's events depend only on its job, never on where it ran. The
runner (:func:`lagrseq.runner.run_trials`) drives either through :meth:`TrialExecutor.submit`,
:meth:`TrialExecutor.completed` and, on Ctrl-C, :meth:`TrialExecutor.interrupt`.
"""

from __future__ import annotations

import contextlib
import hashlib
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any

from lagrseq.errors import UsageError

EXECUTORS = ("local", "dask")
"""Accepted by ``--executor``."""

DASK_MISSING = "--executor dask needs dask distributed, which is not installed: pip install 'lagrseq[dask]'"


@dataclass(frozen=True)
class TrialJob:
    """Everything a worker needs to run one trial (plain data: it crosses process boundaries)."""

    config: dict[str, Any]
    """The resolved configuration (``ExperimentConfig.to_dict()``)."""
    trial: int
    seed: int
    provider_spec: str
    path: str
    """The trial's final log path (written as ``path + '.partial'`` until complete)."""
    options: Any
    """The run's :class:`lagrseq.wiring.ProviderOptions` (or None)."""
    key: str
    """Deterministic task key: ``lagrseq-trial-<run digest>-<trial>``; a resubmission of the same
    trial of the same run gets the same key (Dask then recognises it)."""
    render_dir: str | None = None
    """Arm tasks: where ``--render`` writes the trial's frames and GIFs (None: nowhere)."""
    notes: dict[str, str] | None = None
    """More entries for the trial's run metadata (``lagrseq frontier --tune``'s choice)."""


def run_digest(config_json: str, seed: int, provider_spec: str, directory: str) -> str:
    """12 hex digits naming one run: its configuration, seed, provider and directory."""
    text = "\0".join((config_json, str(seed), provider_spec, os.path.abspath(directory)))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def task_key(digest: str, trial: int, attempt: int = 0) -> str:
    return f"lagrseq-trial-{digest}-{trial:03d}" + (f"-retry{attempt}" if attempt else "")


class TrialExecutor:
    """What the runner needs of an executor. ``submit`` returns a handle; ``completed`` yields
    handles as they finish; ``result`` returns a finished handle's value or raises its error."""

    name = "executor"
    workers = 1

    def submit(self, fn: Callable[[TrialJob], Any], job: TrialJob) -> Any:
        raise NotImplementedError  # abstract

    def completed(self, handles: Iterable[Any]) -> Iterator[Any]:
        raise NotImplementedError  # abstract

    def result(self, handle: Any) -> Any:
        raise NotImplementedError  # abstract

    def interrupt(self) -> None:
        """Ctrl-C: stop the running trials now (their ``.partial`` files stay) and drop the rest."""
        raise NotImplementedError  # abstract

    def close(self) -> None:
        """Release the workers (waits for running trials)."""

    def describe(self) -> str:
        return f"{self.name} executor, {self.workers} worker{'s' if self.workers != 1 else ''}"

    def __enter__(self) -> TrialExecutor:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is KeyboardInterrupt:
            exit_on_next_interrupt()
            self.interrupt()
        else:
            self.close()


# ------------------------------------------------------------------------------------------
# The local process pool
# ------------------------------------------------------------------------------------------
def _ignore_interrupts() -> None:
    """Workers leave Ctrl-C to the parent, which stops them (SIGINT reaches the whole process
    group; a worker that handled it itself would race the parent's cancellation), and die with
    their parent (:func:`die_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()


PR_SET_PDEATHSIG = 1


def die_with_parent(poll_s: float = 1.0) -> None:
    """End this process when the process that started it dies, however it dies (SIGKILL
    included), so no worker outlives a stopped run; with no worker left, multiprocessing's
    resource tracker (which reads until every holder of its pipe is gone) ends too.

    Linux: the kernel sends SIGKILL at the parent's death (``prctl(PR_SET_PDEATHSIG)``); the
    parent may have died before the call, so the parent is checked once after it. Elsewhere, and
    as a second line on Linux, a daemon thread polls ``os.getppid()`` every ``poll_s``."""
    import threading

    parent = os.getppid()
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent or parent == 1:
        os._exit(143)

    def watch() -> None:
        import time

        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(143)

    threading.Thread(target=watch, name="lagrseq-parent-watch", daemon=True).start()


def exit_on_next_interrupt() -> None:
    """Cleaning up after a Ctrl-C (or SIGTERM): from now on a Ctrl-C ends the process at once
    with status 130, a SIGTERM with 143, whatever it is doing. The process is on its way out."""
    with contextlib.suppress(ValueError):  # not the main thread: nothing to install
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))
        signal.signal(signal.SIGTERM, lambda *_: os._exit(143))


TRACKER_QUIET = "ignore:resource_tracker:UserWarning"
"""A warnings filter for multiprocessing's resource tracker (see :func:`quiet_resource_tracker`)."""


def quiet_resource_tracker() -> None:
    """After a Ctrl-C the process leaves at once (``os._exit``), without releasing its pool's
    semaphores; the resource tracker, a helper process, then releases them and would add
    ``UserWarning: resource_tracker: There appear to be N leaked semaphore objects`` (two lines)
    to stderr after the one interrupt line. The tracker gets this process's ``-W`` options when
    it starts, so the filter is added before the first pool makes it start."""
    if TRACKER_QUIET not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_QUIET)


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
        self.workers = jobs
        quiet_resource_tracker()
        self.pool = ProcessPoolExecutor(
            max_workers=jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_ignore_interrupts
        )

    def submit(self, fn: Callable[[TrialJob], Any], job: TrialJob) -> Future[Any]:
        return self.pool.submit(fn, job)

    def completed(self, handles: Iterable[Future[Any]]) -> Iterator[Future[Any]]:
        return as_completed(list(handles))

    def result(self, handle: Future[Any]) -> Any:
        return handle.result()

    def interrupt(self) -> None:
        stop_pool(self.pool)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


SCHEDULER_SCHEMES = ("tcp", "tls", "ucx")


def check_scheduler(address: str) -> str:
    """``--scheduler``: ``tcp://HOST:PORT`` (or tls, ucx), the port 1 to 65535; checked before
    anything starts (Dask itself would fail deep inside with a traceback)."""
    import re

    match = re.fullmatch(r"([a-z]+)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([0-9]{1,5})", address)
    if match is None or match.group(1) not in SCHEDULER_SCHEMES or not 1 <= int(match.group(3)) <= 65535:
        raise UsageError(f"--scheduler {address!r} is not a Dask scheduler address; give tcp://HOST:PORT (a port in 1..65535)")
    return address


def make_executor(kind: str, jobs: int, scheduler: str | None = None, say: Callable[[str], None] | None = None) -> TrialExecutor:
    """The executor ``--executor kind`` names (``scheduler``: an existing Dask scheduler's
    address). ``say`` receives one line about a started cluster (its dashboard)."""
    if kind not in EXECUTORS:
        raise UsageError(f"unknown executor {kind!r}; expected one of: {', '.join(EXECUTORS)}")
    if scheduler is not None and kind != "dask":
        raise UsageError("--scheduler applies to --executor dask only")
    if scheduler is not None:
        check_scheduler(scheduler)
    if kind == "local":
        return LocalExecutor(jobs)
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise UsageError(DASK_MISSING)
    from lagrseq.dask_executor import DaskExecutor

    return DaskExecutor(jobs, scheduler, say)
