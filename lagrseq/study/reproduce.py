"""``lagrseq reproduce``: run the paper's suite, then replay it into a report, in four phases
(:mod:`lagrseq.study.phases`):

1. Plan: every run the suite's items list, each distinct configuration once (Fig. 5(a), Fig. 6(a)
   and Table 2 share runs); items whose task or provider this lagrseq lacks are set aside with a
   one-line reason.
2. Estimate: time a short stretch of every distinct configuration on this machine (logged to a
   scratch file, with the run's own provider where that asks no model; a run whose trials stop
   early, ``run.stop_at``, one trial to its stop) and report the expected wall time before starting.
3. Execute: trials in parallel on local processes or Dask workers through
   :func:`lagrseq.running.runner.run_trials`; trials whose log is complete are skipped, so a rerun resumes.
   Then the frontier items' second phase (:func:`plan_matched_random`): ``random`` at each
   learning policy's query rate, read from its logs, on the same seed and trials; then the audits.
4. Report: :func:`lagrseq.analysis.replay.replay` over the run logs, from the MCAP files alone.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from lagrseq.progress import Reporter, duration
from lagrseq.running import runner
from lagrseq.study.phases.audits import (
    SUITE_AUDITS,
    SuiteAudit,
    audit_items,
    audit_section,
    on_request_line,
    run_suite_audit,
    split_items,
    suite_audits,
)
from lagrseq.study.phases.estimate import Forecast, calibrations, estimate_suite
from lagrseq.study.phases.execute import Outcome, execute, execute_suite, needs_pool, run_failures
from lagrseq.study.phases.failures import (
    AUDIT_ITEM_PREFIX,
    ERRORS_LOG,
    LINE_WIDTH,
    REASON_WIDTH,
    RunFailure,
    audit_item,
    failure_summary,
    item_failures,
    rerun_command,
    without_absolute_paths,
    without_checkout,
    write_errors_log,
)
from lagrseq.study.phases.plan import (
    Plan,
    PlannedRun,
    Request,
    SuitePlan,
    check_providers,
    frontier_items,
    matched_sources,
    plan,
    plan_matched_random,
    plan_suite,
    run_options,
    with_authors_answers,
)
from lagrseq.study.phases.report import finished_line, report_suite, write_errors
from lagrseq.study.phases.timing import (
    CALIBRATION_STEPS,
    EPISODES_CALIBRATION_STEPS,
    LOCKSTEP_CALIBRATION_GROUP,
    LOCKSTEP_CALIBRATION_STEPS,
    STOP_CALIBRATION_STEPS,
    Estimate,
    Timing,
    calibration_keys,
    estimate,
    estimate_phases,
    lockstep_groups,
    replay_jobs,
)

if TYPE_CHECKING:
    from lagrseq.analysis.replay import Report

__all__ = [
    "AUDIT_ITEM_PREFIX", "CALIBRATION_STEPS", "EPISODES_CALIBRATION_STEPS", "ERRORS_LOG", "LINE_WIDTH",
    "LOCKSTEP_CALIBRATION_GROUP", "LOCKSTEP_CALIBRATION_STEPS", "REASON_WIDTH", "STOP_CALIBRATION_STEPS", "SUITE_AUDITS",
    "Estimate", "Forecast", "Outcome", "Plan", "PlannedRun", "Reporter", "Reproduced", "Request", "RunFailure",
    "SuiteAudit", "SuitePlan", "Timing", "audit_item", "audit_items", "audit_section", "calibration_keys",
    "check_providers", "duration", "estimate", "estimate_phases", "execute", "failure_summary", "frontier_items",
    "item_failures", "lockstep_groups", "matched_sources", "needs_pool", "on_request_line", "plan",
    "plan_matched_random", "replay_jobs", "reproduce", "rerun_command", "run_failures", "run_options",
    "run_suite_audit", "split_items", "suite_audits", "with_authors_answers", "without_absolute_paths",
    "without_checkout", "write_errors_log",
]


@dataclass(frozen=True)
class Reproduced:
    """What ``reproduce`` made."""

    report: Report
    """The replay's report: its items, failed items (``failed``) and failed audits (``problems``)."""
    elapsed: float
    """Wall seconds it all took (from the end of the checks)."""
    estimated: float
    """Wall seconds it was expected to take, said before the runs started."""


def reproduce(request: Request, progress: Reporter | None = None) -> Reproduced:
    """``lagrseq reproduce``: plan the suite, say what will run and how long it should take, run
    it with one progress bar (episodes of cube runs, steps of grid runs), then replay the logs into
    ``OUT/reports``.

    A run whose trials fail (or that cannot start) does not stop the others: ``progress.warn``
    gets one short line per failed run (:meth:`RunFailure.line`), the whole text goes to
    ``OUT/reproduce-errors.log`` (:data:`ERRORS_LOG`), and the items it feeds are reported as
    failed, each with its reason and the command that reruns it alone (``report.failed``; a
    failed suite audit: ``report.problems``)."""
    from lagrseq.progress import bar as progress_bar

    progress = progress or Reporter()
    planned = plan_suite(request, progress)
    # One display for every phase (experiments timed, then estimated seconds), and one pool (or
    # Dask cluster): its workers time the experiments side by side, then run the trials.
    with contextlib.ExitStack() as pools, progress_bar(
        calibrations(planned, request.jobs), "experiment", "calibration", progress.quiet
    ) as progress.bar:
        pool = None
        if needs_pool(request.executor, request.jobs, request.scheduler):
            pool = pools.enter_context(runner.make_executor(request.executor, request.jobs, request.scheduler, progress))
        forecast = estimate_suite(planned, request, progress, pool)
        outcome = execute_suite(planned, forecast, request, progress, pool)
        write_errors(planned, outcome, request, progress)
        pools.close()  # the replay's own workers start now: the pool's go first
        report = report_suite(planned, forecast, outcome, request, progress)
    progress.bar = None
    elapsed = time.perf_counter() - planned.started
    progress.say(finished_line(elapsed, forecast.estimate.total))
    return Reproduced(report, elapsed, forecast.estimate.total)
