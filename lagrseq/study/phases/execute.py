"""Execute: the planned runs' trials, in this process or through one warm pool, with one
progress bar: the suite's runs, then random at the frontier policies' matched query rates, then
the audits."""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lagrseq.errors import LagrseqError, TrialsFailed
from lagrseq.logs.reader import is_complete
from lagrseq.loop.experiment import TrialResult
from lagrseq.progress import Reporter
from lagrseq.registry import EXECUTORS
from lagrseq.running import runner
from lagrseq.study import probe
from lagrseq.study.phases.audits import run_suite_audit
from lagrseq.study.phases.failures import RunFailure, describe_config, short_name
from lagrseq.study.phases.plan import Plan, PlannedRun, Request, SuitePlan, plan_matched_random

if TYPE_CHECKING:
    from lagrseq.study.phases.estimate import Forecast


class _Scaled:
    """A progress bar fed in other units: ``update(n)`` moves it by ``n * scale``."""

    def __init__(self, bar: Any, scale: float) -> None:
        self.bar = bar
        self.scale = scale

    def update(self, n: float = 1) -> None:
        if self.bar is not None and n:
            self.bar.update(n * self.scale)

    def set_description(self, text: str) -> None:
        if self.bar is not None and hasattr(self.bar, "set_description"):
            self.bar.set_description(text)


class _RunProgress:
    """Feeds one run's episode updates into the suite's bar, never past the run's share; with
    ``scale``, a unit moves the bar by ``scale`` (estimated seconds per unit)."""

    def __init__(self, bar: Any, units: int, scale: float = 1.0) -> None:
        self.bar = bar
        self.left = units
        self.scale = scale

    def update(self, n: int = 1) -> None:
        n = min(n, self.left)
        if n > 0 and self.bar is not None:
            self.bar.update(n * self.scale if self.scale != 1.0 else n)
        self.left -= n

    def finish(self) -> None:
        self.update(self.left)


def execute(
    the_plan: Plan,
    jobs: int,
    bar: Any = None,
    progress: Reporter | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    retries: int = 0,
    seconds: dict[Path, float] | None = None,
    pool: Any = None,
    failures: list[RunFailure] | None = None,
    label: str = "",
) -> list[TrialResult]:
    """Run every planned run (complete trials are skipped): the accuracy probes in this process,
    then the trials of every run through one warm process pool or one Dask cluster
    (``executor``, ``scheduler``: see :func:`lagrseq.running.executors.make_executor`), all submitted at
    once so that no worker waits for the last trial of one run before the next run starts.
    Without a pool (``jobs = 1``) the runs go one after the other, ``progress`` told of each
    (:meth:`~lagrseq.progress.Reporter.on_run`: the run's name and ``label``).
    ``seconds`` (run path -> estimated seconds): the bar counts estimated seconds, not units.
    ``pool``: an executor already started, kept warm across the phases.
    ``failures``: where runs whose trials failed (or that could not start) are added, while the
    other runs go on; without it the first such failure is raised (:class:`TrialsFailed`) at the
    end of its phase."""

    def one(run: PlannedRun) -> list[TrialResult]:
        try:
            return _execute_run(run, bar, progress, retries, _scale(run, seconds), label)
        except LagrseqError as caught:  # failed trials, an accuracy probe's provider, a store that cannot be read
            if failures is None:
                raise
            failures.extend(_failed(run, caught))
        return []

    results: list[TrialResult] = []
    for run in the_plan.runs:
        if run.kind == "accuracy":
            results += one(run)
    trial_runs = [run for run in the_plan.runs if run.kind != "accuracy"]
    with contextlib.ExitStack() as stack:
        if pool is None and needs_pool(executor, jobs, scheduler):
            pool = stack.enter_context(runner.make_executor(executor, jobs, scheduler, progress))
        if pool is None:
            for run in trial_runs:
                results += one(run)
            return results
        return results + _sweep(trial_runs, jobs, bar, pool, retries, seconds, failures)


def _scale(run: PlannedRun, seconds: dict[Path, float] | None) -> float:
    """How far one progress unit of ``run`` moves the bar: 1, or its estimated seconds per unit."""
    if seconds is None:
        return 1.0
    return seconds.get(run.path, 0.0) / max(1, run.units())


def _failed(run: PlannedRun, caught: LagrseqError) -> list[RunFailure]:
    """What ``caught`` says about ``run``: its failed trials, or the run that could not start."""
    if isinstance(caught, TrialsFailed):
        return run_failures(caught, [run])
    error = " ".join(str(caught).split())
    total = 1 if run.kind == "accuracy" else run.trials
    return [
        RunFailure(
            describe_config(run.config, run.provider), run.path, total, total, (f"{run.describe()} failed: {error}",),
            error, runner.rerun_advice(caught), tuple(run.items), short=short_name(run.config, run.provider),
        )
    ]


def _sweep(
    trial_runs: list[PlannedRun], jobs: int, bar: Any, pool: Any, retries: int, seconds: dict[Path, float] | None,
    failures: list[RunFailure] | None,
) -> list[TrialResult]:
    """The trials of ``trial_runs`` submitted at once to ``pool``, each run moving its share of ``bar``."""
    if bar is not None and hasattr(bar, "set_description") and trial_runs:
        bar.set_description(f"{len(trial_runs)} runs on {pool.describe()}")
    shares = [_RunProgress(bar, run.units(), _scale(run, seconds)) for run in trial_runs]
    sweep = [
        runner.SweepRun(
            run.config, run.trials, run.seed, run.provider, run.path, run.options, progress=share,
            seconds=seconds.get(run.path, 0.0) / max(1, run.pending()) if seconds is not None else None,
        )
        for run, share in zip(trial_runs, shares, strict=True)
    ]
    results: list[TrialResult] = []
    try:
        for outcome in runner.run_sweep(sweep, jobs, pool, retries=retries, keep_going=failures is not None):
            results += outcome
    except TrialsFailed as caught:
        if failures is None:
            raise
        failures.extend(run_failures(caught, trial_runs))
    for share in shares:
        share.finish()
    return results


def run_failures(caught: TrialsFailed, runs: Sequence[PlannedRun]) -> list[RunFailure]:
    """What ``caught`` says about each of ``runs`` (matched by directory)."""
    by_path = {run.path: run for run in runs}
    out = []
    for failed in caught.runs:
        run = by_path.get(failed.directory)
        if run is None:  # not one of ours: nothing to attribute it to
            raise caught
        failures = failed.failures
        out.append(
            RunFailure(
                describe_config(run.config, run.provider), run.path, len(failures), failed.total,
                tuple(f.describe() for f in failures), failures[0].error, failed.advice, tuple(run.items),
                short=short_name(run.config, run.provider),
            )
        )
    if not out:
        raise caught
    return out


def needs_pool(executor: str, jobs: int, scheduler: str | None) -> bool:
    """Whether trials run through an executor (a process pool, Dask) rather than in this process."""
    return not EXECUTORS.get(executor).runner_pool or scheduler is not None or jobs > 1


def _execute_run(
    run: PlannedRun,
    bar: Any,
    reporter: Reporter | None,
    retries: int = 0,
    scale: float = 1.0,
    label: str = "",
) -> list[TrialResult]:
    """One planned run in this process: an accuracy probe, or its trials one after the other."""
    if reporter is not None:
        reporter.on_run(run.describe() + label)
    progress = _RunProgress(bar, run.units(), scale)
    results: list[TrialResult] = []
    if run.kind == "accuracy":
        if not is_complete(run.path):
            results.append(
                probe.run_accuracy_probe(run.config, run.samples, run.seed, run.provider, run.path, provider_options=run.options)
            )
    else:
        results = runner.run_trials(
            run.config, run.trials, run.seed, run.provider, run.path, progress=progress, retries=retries,
            provider_options=run.options,
        )
    progress.finish()
    return results


@dataclass(frozen=True)
class Outcome:
    """The execute phase's result."""

    failures: tuple[RunFailure, ...]
    """The runs whose trials failed or that could not start, in the order they failed."""


def execute_suite(planned: SuitePlan, forecast: Forecast, request: Request, progress: Reporter, pool: Any) -> Outcome:
    """The suite's runs; then random at the frontier policies' matched query rates (planned now
    that the policies' logs exist); then the audits. A failed run does not stop the others: each
    phase's failed runs are said as it ends, one short line each (:meth:`RunFailure.line`)."""
    guess, bar = forecast.estimate, progress.bar
    failures: list[RunFailure] = []
    options: dict[str, Any] = dict(executor=request.executor, scheduler=request.scheduler, retries=request.retries, pool=pool, failures=failures)
    execute(planned.runs, request.jobs, bar, progress, seconds=guess.per_run, **options)
    told = _tell(progress, failures, 0)
    matched = plan_matched_random(planned.runs, planned.matched_items, planned.runs_dir)
    if matched.runs:
        pending = sum(run.pending() for run in matched.runs)
        progress.say(f"random at the frontier policies' matched query rates: {len(matched.runs)} runs, {pending} trials to run")
        if pending:
            seconds = {run.path: guess.per_run.get(run.source, 0.0) for run in matched.runs if run.source}
            execute(matched, request.jobs, bar, progress, seconds=seconds, label=" (matched random)", **options)
            told = _tell(progress, failures, told)
    for task, _, _ in planned.audits:
        bar.set_description(f"{task} audit")
        scaled = _Scaled(bar, guess.audit_per_trial.get(task, 0.0))
        run_suite_audit(task, planned.runs_dir, request.quick, request.jobs, planned.seed, progress, scaled, pool, failures)
        told = _tell(progress, failures, told)
    return Outcome(tuple(failures))


def _tell(progress: Reporter, failures: list[RunFailure], told: int) -> int:
    """Warn of the failed runs from index ``told`` on, one short line each; returns how many are told."""
    for failure in failures[told:]:
        progress.warn(failure.line())
    return len(failures)
