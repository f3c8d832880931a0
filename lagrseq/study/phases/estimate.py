"""Estimate: time every distinct experiment of the plan on this machine (:mod:`.timing`), then
say what will run and how long it should take, and turn the bar from experiments timed into
estimated seconds."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

from lagrseq.progress import Reporter, duration
from lagrseq.registry import EXECUTORS
from lagrseq.study.phases.audits import audit_item, on_request_line
from lagrseq.study.phases.plan import Plan, Request, SuitePlan, matched_sources
from lagrseq.study.phases.timing import Estimate, calibration_keys, estimate_phases


@dataclass(frozen=True)
class Forecast:
    """The estimate phase's result."""

    estimate: Estimate
    """Expected seconds of each phase (calibration already spent)."""
    on_request_seconds: dict[str, float | None]
    """Per audit the whole suite leaves to a request: expected wall seconds here (0: its logs are
    complete; None: not timed)."""


def calibrations(planned: SuitePlan, jobs: int) -> int:
    """The calibration bar's length: the experiments to time and the audits with trials to run."""
    return max(1, calibration_keys(planned.runs, jobs) + sum(map(bool, planned.audit_pending.values())))


def estimate_suite(planned: SuitePlan, request: Request, progress: Reporter, pool: Any) -> Forecast:
    """Time the plan's experiments (in ``pool``'s workers where there is one), say the plan and
    its expected duration, then count the bar in estimated seconds."""
    the_plan, pending, jobs = planned.runs, planned.audit_pending, request.jobs
    timed_audits = [
        (task, runs[0].config, trials) for task, runs, trials in [*planned.audits, *planned.on_request] if runs and pending[task]
    ]
    guess = estimate_phases(
        the_plan, jobs, timed_audits, len(planned.suite.items), on_calibrated=progress.on_calibrated,
        audit_logs=sum(len(runs) * n for _, runs, n in planned.audits), pool=pool,
    )
    per_trial = guess.audit_per_trial
    on_request_seconds = {
        task: per_trial[task] * pending[task] if task in per_trial else (0.0 if not pending[task] else None)
        for task, _, _ in planned.on_request
    }
    guess = replace(
        guess,
        audit=sum(per_trial.get(task, 0.0) * pending[task] for task, _, _ in planned.audits),
        # the frontier's matched-rate random runs of policies still to run: each about as long as
        # its policy's run
        runs=guess.runs + sum(guess.per_run.get(run.path, 0.0) for run in matched_sources(the_plan, planned.matched_items)),
        calibration=time.perf_counter() - planned.started,
    )
    progress.say(_plan_line(planned, request, guess))
    for task, seconds in on_request_seconds.items():
        command = planned.rerun([audit_item(task)])
        progress.say(f"{task} audit: not in the suite; {on_request_line(command, seconds, jobs, request.executor)}")
    _count_seconds(progress.bar, guess)
    return Forecast(guess, on_request_seconds)


def _plan_line(planned: SuitePlan, request: Request, guess: Estimate) -> str:
    """What will run and about how long it takes. The counts are the suite's own runs; the
    matched-rate random runs are counted apart, by the policies they follow, so that a first run
    and a rerun print the same plan (a rerun has them planned already, a first run makes them once
    their policies' runs are complete)."""
    own = [run for run in planned.runs.runs if run.source is None]
    matched_now = [run for run in planned.runs.runs if run.source is not None]
    pending = sum(run.pending() for run in own)
    trials = sum(run.trials if run.kind == "trial" else 1 for run in own)
    to_match = matched_sources(Plan(own, {}, {}), planned.matched_items)
    match_trials = sum(run.trials for run in to_match)
    match_complete = sum(run.trials - run.pending() for run in matched_now)
    jobs = request.jobs
    return (
        f"{'quick' if request.quick else 'full'} suite: {len(own)} runs, {trials} trial logs, "
        f"{pending} to run ({trials - pending} already complete)"
        + (
            f", then up to {len(to_match)} run{'s' if len(to_match) != 1 else ''} of random at the frontier policies' matched query rates "
            f"({match_trials} trial logs, {match_complete} already complete)"
            if to_match else ""
        )
        + "; expected about "
        f"{duration(guess.total)} on {jobs} {EXECUTORS.get(request.executor).workers[jobs > 1]} "
        f"(calibration {duration(guess.calibration)} done, runs {duration(guess.runs)}, audits {duration(guess.audit)}, "
        f"replay {duration(guess.replay)}; "
        f"timed on this machine; LLM latency of live providers not included)"
    )


def _count_seconds(bar: Any, guess: Estimate) -> None:
    """The one display of every phase, from here on in estimated seconds of runs, audits and
    replay, with rate and ETA."""
    bar.unit = "s"  # the unit and format first: reset redraws the bar
    bar.bar_format = "{desc}{percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} estimated s [{elapsed}<{remaining}, {rate_fmt}]"
    bar.set_description("runs", refresh=False)
    bar.reset(total=max(guess.total - guess.calibration, 1e-9))
