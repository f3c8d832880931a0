"""The suite's paper-vs-code audits: which run with the suite, how to run the others, their
report section."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq.errors import ConfigError, LagrseqError, TrialsFailed
from lagrseq.progress import Reporter, duration
from lagrseq.registry import EXECUTORS
from lagrseq.running import runner
from lagrseq.study.phases.failures import (
    RunFailure,
    audit_item,
    describe_config,
    short_name,
)
from lagrseq.suite import Suite


@dataclass(frozen=True)
class SuiteAudit:
    """One task's audit in the paper's suite: its provider (the one the task's query table uses,
    so that the scoreboard's gap can be attributed) and, per mode (``--quick`` or full), trials per
    run, episodes (0: the preset's) and steps per trial (-1: the preset's)."""

    provider: str
    quick: tuple[int, int, int]
    full: tuple[int, int, int]
    quick_presets: tuple[str, ...] = ("upstream", "paper")
    """The directions the quick audit switches fields in (the full audit: both)."""
    in_suite: bool = True
    """Whether ``reproduce`` runs it with the whole suite (full and ``--quick``); else it runs on
    request only, as the suite item :func:`audit_item` (``--items audit-TASK``) or with
    ``lagrseq audit TASK``, and the report's audit section says how and about how long."""


SUITE_AUDITS = {
    "cube-stacking": SuiteAudit("mock:authors-t0", (3, 100, -1), (10, 100, -1)),
    "image-completion": SuiteAudit("mock:authors-gpt4", (2, 0, 200), (10, 0, -1), ("upstream",), in_suite=False),
    "object-arrangement": SuiteAudit("mock", (2, 0, 200), (10, 0, -1), ("upstream",), in_suite=False),
}
"""The paper-vs-code audits of the packaged suite, each also a suite item of its own
(:func:`audit_item`). The whole suite runs the cube audit; the grid audits run on request (at
full length they would take most of the full suite's time; the quick suite's reduced ones go
with them, so that ``--quick`` previews what the full suite runs). The grid tasks' quick
audits are reduced (2 trials of 200 steps, the upstream preset's fields switched to the paper's
values only: indicative, labelled so on their tables)."""

def audit_items() -> dict[str, str]:
    """``--items`` id -> task, for every audit of :data:`SUITE_AUDITS` whose task is here."""
    return {audit_item(task): task for task in SUITE_AUDITS if task in cfg.tasks()}


def split_items(suite: Suite, items: Sequence[str]) -> tuple[list[str], list[str]]:
    """``--items`` as (the suite's items, the audits' tasks): an id of the suite is its item, an
    ``audit-TASK`` id (:func:`audit_items`) is that audit; anything else is one line naming the
    ids there are."""
    known = {item.id for item in suite.items}
    audits = audit_items()
    unknown = [i for i in items if i not in known and i not in audits]
    if unknown:
        raise ConfigError(
            f"unknown suite item {unknown[0]!r}; items are: {', '.join(sorted(known))}; "
            f"audits (run on request): {', '.join(sorted(audits))}"
        )
    return [i for i in items if i in known], [audits[i] for i in items if i not in known]


def _audit_time(seconds: float | None, jobs: int, executor: str) -> str:
    if seconds is None:
        return "not estimated here"
    if seconds == 0:
        return "its logs are already complete"
    return f"about {duration(seconds)} on this machine with {jobs} {EXECUTORS.get(executor).workers[jobs > 1]}, estimated before the runs"


def on_request_line(command: str, seconds: float | None, jobs: int, executor: str) -> str:
    """How to run an audit the suite leaves to a request, and about how long it takes here."""
    return f"run it with `{command}` ({_audit_time(seconds, jobs, executor)})"


def audit_section(
    ran: Sequence[str], on_request: Mapping[str, float | None], jobs: int, executor: str,
    rerun: Callable[[list[str]], str],
) -> tuple[str, Any, None]:
    """The report's audit section (stem ``audits``, no figure): one row per audit, run in this
    ``reproduce`` (its tables follow) or left to a request (``on_request``: task -> estimated
    wall seconds here, None where not timed), with the command that runs it alone
    (``rerun([audit-TASK])``) and about how long it takes."""
    import pandas as pd

    from lagrseq.analysis.tables import Table

    columns = ("audit", "in this report", "how to run it alone", "about how long")
    rows: list[tuple[str, ...]] = []
    records: list[dict[str, Any]] = []
    for task in [*ran, *on_request]:
        command = rerun([audit_item(task)])
        if task in on_request:
            seconds = on_request[task]
            status = (
                f"run on request earlier into this folder: tables {audit_item(task)} below" if seconds == 0
                else f"not run: on request (not in the default suite); a table {audit_item(task)} below, if any, "
                "holds only the one-field switches the suite's own runs make"
            )
            took = _audit_time(seconds, jobs, executor)
        else:
            seconds = None
            status = f"run here: tables {audit_item(task)} below"
            took = "part of this run"
        rows.append((task, status, f"`{command}` (or `lagrseq audit {task}`)", took))
        records.append({"audit": task, "run": task not in on_request, "command": command, "estimated_seconds": seconds})
    title = "Audits of paper vs code (what each deviation does): which this report holds, and how to run the others"
    return "audits", Table(title, columns, tuple(rows), pd.DataFrame(records, columns=["audit", "run", "command", "estimated_seconds"])), None


def _audit_plan(task: str, runs_dir: Path, quick: bool, seed: int, progress: Reporter) -> tuple[list[Any], int]:
    from lagrseq.study.audit import plan as audit_plan

    chosen = SUITE_AUDITS[task]
    trials, episodes, max_steps = chosen.quick if quick else chosen.full
    runs = audit_plan(task, chosen.provider, trials, episodes, max_steps, runs_dir, seed, progress, chosen.quick_presets if quick else None)
    return runs, trials


def suite_audits(
    runs_dir: Path, quick: bool, seed: int, tasks: Sequence[str] | None = None
) -> list[tuple[str, list[Any], int]]:
    """(task, planned audit runs, trials per run) of the audits of ``tasks`` (default: those the
    whole suite runs, :attr:`SuiteAudit.in_suite`) whose task is here."""
    chosen = [task for task, audit in SUITE_AUDITS.items() if audit.in_suite] if tasks is None else tasks
    here = cfg.tasks()
    return [(task, *_audit_plan(task, runs_dir, quick, seed, Reporter.silent())) for task in chosen if task in here]


def run_suite_audit(
    task: str, runs_dir: Path, quick: bool, jobs: int, seed: int, progress: Reporter, bar: Any = None,
    pool: Any = None, failures: list[RunFailure] | None = None,
) -> None:
    """The audit of ``task`` (``lagrseq audit TASK``) at the suite's length, into the suite's runs,
    so that replay adds its tables and figures (a preset run the suite also makes is shared).
    ``progress``: where its plan line goes (its ``quiet``: no bar of its own);
    ``bar``: the display to move by one per trial (default: a bar of its own, in trials);
    ``pool``: an executor already started (else one of ``jobs`` local processes); ``failures``:
    where its failed runs are added while the others go on (else :class:`TrialsFailed` is raised)."""
    if failures is None:
        _run_suite_audit(task, runs_dir, quick, jobs, seed, progress, bar, pool, None)
        return
    try:
        _run_suite_audit(task, runs_dir, quick, jobs, seed, progress, bar, pool, failures)
    except LagrseqError as caught:  # the audit could not be planned or started at all
        error = " ".join(str(caught).split())
        failures.append(
            RunFailure(f"the {task} audit", runs_dir, 1, 1, (f"the {task} audit failed: {error}",), error, runner.rerun_advice(caught), audit=task)
        )


def _run_suite_audit(
    task: str, runs_dir: Path, quick: bool, jobs: int, seed: int, progress: Reporter, bar: Any,
    pool: Any, failures: list[RunFailure] | None,
) -> None:
    from lagrseq.progress import bar as progress_bar

    chosen = SUITE_AUDITS[task]
    runs, trials = _audit_plan(task, runs_dir, quick, seed, progress)
    _, _, max_steps = chosen.quick if quick else chosen.full
    together = sum(1 for r in runs if r.field and " + " in r.field)
    progress.say(
        f"{task} audit: {len(runs)} runs of {trials} trials"
        + (f" of {max_steps} steps" if max_steps >= 0 else "")
        + (" (reduced: upstream -> paper only)" if quick and chosen.quick_presets != ("upstream", "paper") else "")
        + f", one field switched each{f' and {together} interaction runs' if together else ''} (lagrseq audit)"
    )
    with contextlib.ExitStack() as stack:
        if bar is None:
            bar = stack.enter_context(progress_bar(len(runs) * trials, "trial", quiet=progress.quiet))
        sweep = [runner.SweepRun(r.config, trials, seed, r.provider, r.path, progress=runner.TrialCount(bar, r.config)) for r in runs]
        try:
            runner.run_sweep(sweep, jobs, pool, keep_going=failures is not None)
        except TrialsFailed as caught:
            if failures is None:
                raise
            by_path = {r.path: r for r in runs}
            for failed in caught.runs:
                audited = by_path[failed.directory]
                found = failed.failures
                failures.append(
                    RunFailure(
                        describe_config(audited.config, audited.provider), failed.directory, len(found), failed.total,
                        tuple(f.describe() for f in found), found[0].error, failed.advice, audit=task,
                        short=short_name(audited.config, audited.provider),
                    )
                )
