"""The executor interface: what the runner needs of any executor, and what its workers run.

A trial is one task: :class:`TrialJob` in, a ``TrialResult`` out; or several trials of one run
(:class:`GroupJob`) that step in lockstep, one ``TrialResult`` or error per trial out. The executors themselves
(``lagrseq.running.executors``: the local process pool; ``lagrseq.running.dask_executor``) implement
:class:`TrialExecutor`; they import this module, never each other.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from lagrseq.errors import UsageError
from lagrseq.lifetime import die_with_parent


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
    """The run's provider options (its kind's options dataclass, or None: their defaults)."""
    key: str
    """Deterministic task key: ``lagrseq-trial-<run digest>-<trial>``; a resubmission of the same
    trial of the same run gets the same key (Dask then recognises it)."""
    render_dir: str | None = None
    """Arm tasks: where ``--render`` writes the trial's frames and GIFs (None: nowhere)."""
    notes: dict[str, str] | None = None
    """More entries for the trial's run metadata (``lagrseq frontier --tune``'s choice)."""
    executor: str = "local"
    """The registered name of the executor running it (its log names the executor's origin)."""


@dataclass(frozen=True)
class GroupJob:
    """Several trials (of one run or of several runs of one task) as one task: they run in
    lockstep in one process, their networks trained in batched calls
    (:mod:`lagrseq.agents.lockstep`). A trial's log does not depend on the group it ran in; the
    outcome is one ``TrialResult`` or error per trial."""

    jobs: tuple[TrialJob, ...]
    key: str
    """``lagrseq-group-<digest of its trials' task keys>-<trials>`` (:func:`group_key`)."""


Job = TrialJob | GroupJob


def group_key(jobs: Sequence[TrialJob]) -> str:
    """A group's task name: unique to its trials and their attempts (their task keys)."""
    digest = hashlib.sha256("\0".join(job.key for job in jobs).encode()).hexdigest()[:12]
    return f"lagrseq-group-{digest}-{len(jobs):03d}"


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

    def submit(self, fn: Callable[[Any], Any], job: Job) -> Any:
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
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):  # Ctrl-C, SIGTERM
            exit_on_next_interrupt()
            self.interrupt()
        else:
            self.close()


def _ignore_interrupts() -> None:
    """Workers leave Ctrl-C to the parent, which stops them (SIGINT reaches the whole process
    group; a worker that handled it itself would race the parent's cancellation), and die with
    their parent (:func:`die_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()


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


SCHEDULER_SCHEMES = ("tcp", "tls", "ucx")


def check_scheduler(address: str) -> str:
    """``--scheduler``: ``tcp://HOST:PORT`` (or tls, ucx), the port 1 to 65535; checked before
    anything starts (Dask itself would fail deep inside with a traceback)."""
    import re

    match = re.fullmatch(r"([a-z]+)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([0-9]{1,5})", address)
    if match is None or match.group(1) not in SCHEDULER_SCHEMES or not 1 <= int(match.group(3)) <= 65535:
        raise UsageError(f"--scheduler {address!r} is not a Dask scheduler address; give tcp://HOST:PORT (a port in 1..65535)")
    return address
