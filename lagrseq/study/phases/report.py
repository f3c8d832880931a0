"""Report: the error log of the runs that failed, then replay of the logs into ``OUT/reports``,
with the open models' screens, the audit section and the failed items."""

from __future__ import annotations

import functools
import time
from typing import TYPE_CHECKING, Any

from lagrseq.errors import UsageError
from lagrseq.progress import Reporter, duration
from lagrseq.study.phases.audits import audit_section
from lagrseq.study.phases.estimate import Forecast
from lagrseq.study.phases.execute import Outcome
from lagrseq.study.phases.failures import item_failures, write_errors_log
from lagrseq.study.phases.plan import Request, SuitePlan
from lagrseq.study.phases.timing import replay_jobs

if TYPE_CHECKING:
    from lagrseq.analysis.replay import Report


def write_errors(planned: SuitePlan, outcome: Outcome, request: Request, progress: Reporter) -> None:
    """``OUT/reproduce-errors.log`` with every failure and the command that reruns each failed
    item (removed when nothing failed); a path planted there meanwhile is one warning."""
    reruns = {key: f.rerun for found in item_failures(outcome.failures, planned.rerun) for key, f in found.items()}
    try:
        write_errors_log(request.out, outcome.failures, reruns)
    except UsageError as exc:  # planted while the runs ran: the report is still made
        progress.warn(f"{exc}; the report is made without it")


def report_suite(planned: SuitePlan, forecast: Forecast, outcome: Outcome, request: Request, progress: Reporter) -> Report:
    """Replay the run logs into ``OUT/reports`` (:func:`lagrseq.analysis.replay.replay`); returns its report."""
    from lagrseq.analysis.replay import replay

    progress.say(f"runs done in {duration(time.perf_counter() - planned.started)}: {planned.runs_dir}")
    progress.bar.set_description("replay")
    sections: list[Any] = []
    if planned.whole:  # the whole suite: the open models' screens, from recorded answers
        from lagrseq.study.screen import report_sections

        sections, line = report_sections()
        progress.say(line)
    relative = functools.partial(planned.rerun, relative=True)
    if planned.audits or planned.on_request:
        ran = [task for task, _, _ in planned.audits]
        sections.append(audit_section(ran, forecast.on_request_seconds, request.jobs, request.executor, relative))
    failed, problems = item_failures(outcome.failures, relative)
    report = replay(
        [planned.runs_dir],
        planned.reports_dir,
        list(request.formats),
        planned.suite,
        provider=request.provider or planned.suite.provider,
        unavailable=planned.runs.unavailable,
        produced_by="lagrseq reproduce" + (" --quick" if request.quick else ""),
        price=request.price,
        jobs=replay_jobs(request.jobs),
        sections=sections,
        failed=failed,
        problems=problems,
    )
    progress.bar.update(max(0.0, progress.bar.total - progress.bar.n))
    return report


def finished_line(elapsed: float, estimated: float) -> str:
    """The last line: how long it all took, against the estimate."""
    if estimated <= 0:
        return f"finished in {duration(elapsed)}"
    return f"finished in {duration(elapsed)}; estimated {duration(estimated)} before starting (actual / estimate = {elapsed / estimated:.2f})"
