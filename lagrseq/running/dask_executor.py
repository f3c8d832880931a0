"""Trials on Dask distributed: a ``LocalCluster`` on 127.0.0.1 or an existing scheduler.

The only module that imports dask (the ``dask`` extra); :func:`lagrseq.running.executors.make_executor`
imports it when ``--executor dask`` is asked for. One trial is one Dask task, keyed
``lagrseq-trial-<run digest>-<trial>``; the task function is :func:`lagrseq.running.runner.run_trial_job`,
importable on every worker (workers must have lagrseq installed, the same version).

Pitfalls known from Dask users, and what is done about them:

- Workers are daemonic processes, which may not start child processes: a trial starts none (its
  environment, agents and provider run in the worker's one thread).
- Worker processes are spawned, not forked: the task function is a module-level function of an
  installed package, never a closure or a ``__main__`` function.
- Dask pauses a worker at 80 % of its memory limit and restarts it at 95 %: a local cluster gives
  each worker an equal share of this machine's memory (``memory_limit='auto'``); a trial of the
  paper's tasks needs well under 1 GB.
- torch uses every core per process by default: the DQN configuration pins it to
  ``cpu_threads = 1`` (``[primary]``/``[secondary]``), and local workers are started with
  ``OMP_NUM_THREADS=1``.
- A worker that dies mid-trial (killed, out of memory, a lost node) is replaced and its trial
  rescheduled by Dask, up to ``distributed.scheduler.allowed-failures`` times (default 3), then
  the trial fails with ``KilledWorker``; the dead worker's ``.partial`` file is rewritten by the
  next attempt, or left for ``lagrseq recover`` and rerun by the next ``lagrseq run``.
- A local cluster's workers would outlive a lagrseq process killed outright (its scheduler and
  nannies die with it, the worker processes do not): :class:`ExitWithParent` ends them.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import distributed

from lagrseq.errors import UsageError
from lagrseq.progress import Reporter
from lagrseq.running.executor_base import (
    Job,
    TrialExecutor,
    check_scheduler,
    quiet_resource_tracker,
)

WORKER_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def _check_address(address: str) -> str:
    return check_scheduler(address)


@contextlib.contextmanager
def _interrupts_ignored_by_children() -> Iterator[None]:
    """Worker processes started in here ignore SIGINT (an ignored signal stays ignored across
    exec, and Python then installs no handler of its own): a Ctrl-C, which reaches the whole
    process group, is left to this process, which stops the cluster."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _wait_for_processes(count: int, timeout: float = 60.0) -> None:
    """Until ``count`` worker processes of this process run (they then ignore SIGINT for good,
    so this process need ignore it no longer: a Ctrl-C while the workers import and register
    stops the run at once instead of being lost)."""
    import psutil  # a dependency of distributed

    me = psutil.Process()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        started = 0
        for child in me.children():
            with contextlib.suppress(psutil.Error):
                started += any("spawn_main" in part for part in child.cmdline())
        if started >= count:
            return
        time.sleep(0.01)


class ExitWithParent(distributed.WorkerPlugin):
    """A local cluster's worker ends when the lagrseq process that started it is gone (killed,
    even with SIGKILL, which leaves no time to stop the cluster): it checks every second
    whether it has been handed to another parent. A trial it was running leaves its ``.partial``
    file, as any crash does."""

    name = "lagrseq-exit-with-parent"

    def setup(self, worker: Any) -> None:
        parent = os.getppid()

        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(1.0)
            os._exit(1)

        threading.Thread(target=watch, name="lagrseq-parent-watch", daemon=True).start()


class DaskExecutor(TrialExecutor):
    """``jobs`` single-threaded worker processes on 127.0.0.1, or the workers of ``scheduler``."""

    name = "dask"

    def __init__(self, jobs: int, scheduler: str | None = None, reporter: Reporter | None = None) -> None:
        reporter = reporter or Reporter.silent()
        self.cluster: Any = None
        self.dashboard = ""
        self.submitted: list[Any] = []
        if scheduler is None:
            dashboard = importlib.util.find_spec("bokeh") is not None
            quiet_resource_tracker()
            try:
                # the scheduler alone first (no process: a Ctrl-C meanwhile stops lagrseq at once)
                self.cluster = distributed.LocalCluster(
                    n_workers=0,
                    threads_per_worker=1,
                    processes=True,
                    host="127.0.0.1",
                    dashboard_address="127.0.0.1:0",  # its HTTP server runs without bokeh too
                    memory_limit="auto",
                    silence_logs=logging.CRITICAL,  # a failed trial is reported once, by the runner
                    env=WORKER_ENV,
                )
                with _interrupts_ignored_by_children():  # only until the worker processes exist
                    self.cluster.scale(jobs)
                    _wait_for_processes(jobs)
                self.client = distributed.Client(self.cluster)
                self.client.wait_for_workers(jobs, timeout=120)
            except KeyboardInterrupt:  # Ctrl-C while the workers start: stop what was started
                self.close(wait=False)
                raise
            self.client.register_plugin(ExitWithParent())
            self.workers = jobs
            if dashboard:
                self.dashboard = self.client.dashboard_link
            link = f"dashboard {self.dashboard}" if dashboard else "no dashboard (pip install bokeh for one)"
            reporter.say(f"dask: local cluster of {jobs} worker{'s' if jobs != 1 else ''} on 127.0.0.1, {link}")
        else:
            try:
                self.client = distributed.Client(_check_address(scheduler), timeout=30)
            except OSError as exc:
                raise UsageError(f"no Dask scheduler answered at {scheduler} ({exc}); start one with dask scheduler, or check the address") from None
            except Exception as exc:  # noqa: BLE001 - something else answered there (garbage, another protocol)
                reason = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
                raise UsageError(f"no Dask scheduler answered at {scheduler} (what answered failed: {reason}); check the address") from None
            self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
            reporter.say(f"dask: scheduler {scheduler}, {self.workers} worker{'s' if self.workers != 1 else ''} now")

    def submit(self, fn: Callable[[Any], Any], job: Job) -> Any:
        # pure=False with an explicit key: the key is the trial's, not a hash of the arguments
        future = self.client.submit(fn, job, key=job.key, pure=False)
        self.submitted.append(future)
        return future

    def completed(self, handles: Iterable[Any]) -> Iterator[Any]:
        return iter(distributed.as_completed(list(handles)))

    def result(self, handle: Any) -> Any:
        """The finished task's value or error; the task is then released on the cluster, so a
        later submission of its key (a rerun after a failure) runs it again."""
        try:
            return handle.result()
        finally:
            with contextlib.suppress(ValueError):
                self.submitted.remove(handle)
            handle.release()

    def interrupt(self) -> None:
        """Ctrl-C: cancel every future; a local cluster's workers are stopped at once (their
        ``.partial`` files stay). On an existing cluster Dask cannot stop a running task: those
        trials finish and rename their logs, nothing half-made appears under a final name."""
        with contextlib.suppress(Exception):
            self.client.cancel(self.submitted, force=True)
        self.close(wait=False)

    def close(self, wait: bool = True) -> None:
        with contextlib.suppress(Exception):
            self.client.close(timeout=10 if wait else 2)
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close(timeout=10 if wait else 2)
            self.cluster = None

    def describe(self) -> str:
        return f"dask executor, {self.workers} worker{'s' if self.workers != 1 else ''}"
