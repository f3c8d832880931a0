"""The estimator: a short timed stretch of each distinct configuration on this machine, and
the expected wall seconds of every phase of ``reproduce`` from them."""

from __future__ import annotations

import contextlib
import functools
import json
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

from lagrseq import config as cfg
from lagrseq.config import ExperimentConfig
from lagrseq.registry import TASKS
from lagrseq.running import runner, wiring
from lagrseq.study import probe
from lagrseq.study.phases.plan import Plan, PlannedRun

CALIBRATION_STEPS = 1000
"""Environment steps timed per distinct experiment to estimate the suite's duration (one trial
alone with a step budget)."""
EPISODES_CALIBRATION_STEPS = 5000
"""The same for a trial that ends after a number of episodes (cube stacking): timed whole, up to
this many steps. Its first episodes are the longest (the agent has learned nothing yet), so steps
per episode from its first steps would overstate a whole trial's length several times over."""
LOCKSTEP_CALIBRATION_STEPS = 300
"""Environment steps of each trial when a lockstep group of trials is timed (at most 900
trial-steps for a group of :data:`LOCKSTEP_CALIBRATION_GROUP`). Each distinct configuration is
timed (an asking policy or the provider changes how often a trial asks and is guided), so each
timing is short; ``benchmarks/bench_estimate.py`` prints how close the sums come to the runs'
CPU time."""

STOP_CALIBRATION_STEPS = 2000
"""The step budget of the one trial timed for a run whose trials stop early (``run.stop_at``: at
their first solved episode, ``first_solve``, or first accepted answer, ``first_accepted``; the
run's own ``max_steps`` where lower): the trial runs, with the run's stop, to that point, and the
steps it took are the run's expected trial length (:class:`Timing`)."""


class Timing(NamedTuple):
    """What :func:`_calibrate` measured of one experiment."""

    per_step: float
    """Seconds per step of one trial (a probe: per sample)."""
    steps_per_episode: float
    start: float
    """Seconds of a trial's start (building it) apart from its steps."""
    trial_steps: float = 0.0
    """A run whose trials stop early (``run.stop_at``): the steps its timed trial took to its stop
    (its length where it stopped within :data:`STOP_CALIBRATION_STEPS`, else the run's whole step
    budget). This is one trial's draw: the run's trials reach their first solve at other
    steps (a late trial is many times longer), so the estimate of such a run is as good as that
    draw. 0: the trial runs its budget (:func:`_trial_steps`)."""


def _timed_provider(run: PlannedRun) -> tuple[str, Any]:
    """The provider a calibration of ``run`` asks, and its options: the run's own where it answers
    on this machine with no model to start and no money to spend (a mock profile, a recorded
    store: how often it is right decides how often a trial asks and is guided, a large part of a
    grid trial's cost), else the mock with its defaults (a live or local model is never asked
    for an estimate). An accuracy probe is timed with the mock: one sample would mostly time
    the provider's start."""
    kind = wiring.provider_kind(run.provider)
    if run.kind == "trial" and (kind.synthetic or kind.replays) and not (kind.paid or kind.local_server):
        return run.provider, run.options
    return "mock", None


def _calibration_key(run: PlannedRun) -> tuple[str, ...]:
    """What makes two runs' steps cost alike (their configuration family, timed once): the whole
    configuration (an asking policy, a solution scope or a reward changes how often a trial asks
    and trains: at the same length, the quick suite's grid policies cost 0.4 to 1.4 ms a step)
    and the provider timed, but not the length of a trial with a step budget (a grid trial: its
    steps are timed, not its end) and, for an accuracy probe, only its task (timed with the
    mock: the model and temperature it asks do not change its cost)."""
    provider, options = _timed_provider(run)
    if run.kind == "accuracy":
        return (run.kind, run.config.task.name, provider, repr(options))
    described = run.config.to_dict()
    if run.config.run.episodes == 0:
        described["run"] = {**described["run"], "max_steps": "any"}
    return (run.kind, run.config.task.name, json.dumps(described, sort_keys=True), provider, repr(options))


REPLAY_SECONDS_PER_LOG = 0.013
"""Replay's reading of one trial log (its /episode and /query chunks), CPU seconds in one of
``min(jobs, 8)`` worker processes, which share the logs (with ``jobs`` 1: see
:data:`REPLAY_SECONDS_PER_LOG_ONE_PROCESS`); ``benchmarks/bench_replay.py`` measures it."""
REPLAY_SECONDS_PER_LOG_ONE_PROCESS = 0.007
"""The same in one process: nothing is pickled from a worker."""
REPLAY_SECONDS_PER_ITEM = 0.25
"""Replay's making of one suite item (its numbers, tables and figure), seconds; the figure is
drawn in a worker process meanwhile where there are workers (``jobs`` > 1)."""
REPLAY_DRAW_SECONDS_PER_ITEM = 0.1
"""With one process (``jobs`` 1), drawing an item's figure too, seconds."""
REPLAY_SECONDS_FIXED = 1.5
"""Replay's start: importing pandas and matplotlib, starting its worker processes, the index."""


def replay_jobs(jobs: int) -> int:
    """The processes ``reproduce``'s replay reads the logs with: its ``jobs``, but one where fewer
    than :data:`lagrseq.analysis.loading.WORKERS_MIN_CPUS` of them can run at once (``jobs`` or
    this machine's CPUs): there, workers cost replay more CPU and wall time than they save
    (``benchmarks/bench_replay_jobs.py``)."""
    from lagrseq.analysis.loading import WORKERS_MIN_CPUS, usable_cpus

    return 1 if min(jobs, usable_cpus()) < WORKERS_MIN_CPUS else jobs


@dataclass(frozen=True)
class Estimate:
    """Expected wall seconds of each phase of ``reproduce``, from timed stretches on this machine."""

    runs: float = 0.0
    audit: float = 0.0
    replay: float = 0.0
    calibration: float = 0.0
    """The timing itself (already spent when the estimate is printed, but part of the wall time
    the final line compares with)."""
    per_run: dict[Path, float] = field(default_factory=dict)
    """Each planned run's share of :attr:`runs` (seconds)."""
    audit_per_trial: dict[str, float] = field(default_factory=dict)
    """Per audited task: expected wall seconds of one of its audit trials."""

    @property
    def total(self) -> float:
        return self.calibration + self.runs + self.audit + self.replay


def calibration_keys(the_plan: Plan, jobs: int = 1) -> int:
    """How many distinct experiments :func:`estimate_phases` times (the pending ones)."""
    groups = lockstep_groups(the_plan, jobs)
    return len({(*_calibration_key(run), str(groups.get(run.path, 1))) for run in the_plan.runs if run.pending()})


LOCKSTEP_CALIBRATION_GROUP = 3
"""At most this many trials are timed together for a run whose trials run in lockstep."""


def lockstep_groups(the_plan: Plan, jobs: int) -> dict[Path, int]:
    """How many trials to time together for each pending run whose trials run in lockstep: the
    largest lockstep group its trials are in (:func:`lagrseq.running.runner.lockstep_groups`:
    trials of one task across runs, over ``jobs`` workers; at most
    :data:`LOCKSTEP_CALIBRATION_GROUP`). Lockstep trials share batched training calls, so one
    trial timed alone overstates their cost (the full suite's estimate was 16.0 min for 11.9 min
    with single-trial timings). Runs not in the mapping are timed one trial alone, and so are the
    runs of a task whose steps are slow (its ``calibration_steps``: the simulated arm, whose
    networks are a small part of a step; timing 3 arm trials together took 16 s instead of 5), and
    runs whose trials stop early (``run.stop_at``: one trial is timed to its stop, whose length is
    the estimate's: :data:`STOP_CALIBRATION_STEPS`)."""
    runs = [
        run for run in the_plan.runs
        if run.kind == "trial" and run.pending() and not TASKS.get(run.config.task.name).calibration_steps
        and not run.config.run.stop_at
    ]
    groups = runner.lockstep_groups([(run.config, list(range(run.pending()))) for run in runs], max(1, jobs))
    sizes: dict[Path, int] = {}
    for group in groups:
        if len(group) > 1:
            for index, _ in group:
                path = runs[index].path
                sizes[path] = max(sizes.get(path, 1), min(len(group), LOCKSTEP_CALIBRATION_GROUP))
    return sizes


def _group_of_one_run(run: PlannedRun, jobs: int) -> int:
    """The largest lockstep group of ``run``'s trials alone (an audit's run, which shares its
    groups with the audit's other runs), at most :data:`LOCKSTEP_CALIBRATION_GROUP`."""
    if TASKS.get(run.config.task.name).calibration_steps or run.config.run.stop_at:
        return 1
    groups = runner.lockstep_groups([(run.config, list(range(run.trials)))], max(1, jobs))
    return min(max(len(group) for group in groups), LOCKSTEP_CALIBRATION_GROUP) if groups else 1


def estimate_phases(
    the_plan: Plan, jobs: int, audits: Sequence[tuple[str, ExperimentConfig, int]] = (),
    items: int = 0, on_calibrated: Callable[[], None] | None = None, audit_logs: int = 0, pool: Any = None,
) -> Estimate:
    """Expected seconds of the pending trials, one trial of each suite audit (``audits``: task, a
    run's configuration, trials per run; :attr:`Estimate.audit_per_trial`, which the caller
    multiplies by the pending audit trials) and the replay of ``items`` suite items, from
    a short timed stretch of each distinct configuration on this machine (:func:`_calibrate`: the
    provider of :func:`_timed_provider`, logged to a scratch file, a trial's start apart from its
    steps, after an untimed warm-up that pays the imports). The experiments are timed one
    after the other in this process, or, given the local process ``pool`` the runs will use, in
    its workers side by side (as the runs will share the cores; the workers pay their imports
    once for the calibration and the runs); trials share ``jobs`` workers (:func:`execute`
    submits them all at once), so their time is the work over the workers, or the longest trial
    if that is longer."""
    groups = lockstep_groups(the_plan, jobs)
    planned = {run.path for run in the_plan.runs}
    probes = [
        (task, audit_config, PlannedRun("trial", audit_config, "mock", 0, audit_trials, 0, Path(f"audit-{task}")))
        for task, audit_config, audit_trials in audits
    ]

    def key_of(run: PlannedRun) -> tuple[tuple[str, ...], int]:
        group = groups.get(run.path, 1) if run.path in planned else _group_of_one_run(run, jobs)
        return (*_calibration_key(run), str(group)), group

    todo: dict[tuple[str, ...], tuple[PlannedRun, int]] = {}
    for run in [*(run for run in the_plan.runs if run.pending()), *(probe_run for *_, probe_run in probes)]:
        key, group = key_of(run)
        todo.setdefault(key, (run, group))
    cache = _calibrate_all(todo, pool, on_calibrated)
    timings = {run.path: cache[key_of(run)[0]] for run in the_plan.runs if run.pending()}
    runs, per_run = _runs_seconds(the_plan, timings, jobs)
    audit_per_trial = {
        task: _trial_seconds(audit_config, cache[key_of(probe_run)[0]]) / max(1, jobs)
        for task, audit_config, probe_run in probes
    }
    logs = sum(run.trials if run.kind == "trial" else 1 for run in the_plan.runs) + audit_logs
    return Estimate(runs=runs, replay=replay_seconds(logs, items, jobs), per_run=per_run, audit_per_trial=audit_per_trial)


def _trial_seconds(config: ExperimentConfig, timing: Timing) -> float:
    """One trial's expected seconds: its start and its expected steps."""
    return timing.start + _trial_steps(config, timing) * timing.per_step


def _runs_seconds(the_plan: Plan, timings: Mapping[Path, Timing], jobs: int) -> tuple[float, dict[Path, float]]:
    """Expected wall seconds of the pending runs (``timings``: each one's), and each one's share:
    the accuracy probes one after the other, then the trials over ``jobs`` workers (the work over
    the workers, or the longest trial if that is longer)."""
    serial = work = longest = 0.0
    works: dict[Path, float] = {}
    for run in the_plan.runs:
        if run.path not in timings:
            continue
        timing = timings[run.path]
        if run.kind == "accuracy":
            serial += timing.per_step * run.samples
            works[run.path] = timing.per_step * run.samples
            continue
        trial_seconds = _trial_seconds(run.config, timing)
        works[run.path] = run.pending() * trial_seconds
        work += works[run.path]
        longest = max(longest, trial_seconds)
    parallel = max(work / max(1, jobs), longest)
    per_run = {}
    for run in the_plan.runs:
        if run.path in works:
            per_run[run.path] = works[run.path] if run.kind == "accuracy" else works[run.path] / work * parallel if work else 0.0
    return serial + parallel, per_run


def replay_seconds(logs: int, items: int, jobs: int) -> float:
    """Expected seconds of replay over ``logs`` trial logs into ``items`` suite items."""
    if replay_jobs(jobs) <= 1:
        reading, per_item = REPLAY_SECONDS_PER_LOG_ONE_PROCESS * logs, REPLAY_SECONDS_PER_ITEM + REPLAY_DRAW_SECONDS_PER_ITEM
    else:
        reading, per_item = REPLAY_SECONDS_PER_LOG * logs / min(jobs, 8), REPLAY_SECONDS_PER_ITEM
    return REPLAY_SECONDS_FIXED + reading + per_item * items


@dataclass(frozen=True)
class CalibrationJob:
    """One experiment to time (:func:`_calibrate`) in a worker process."""

    kind: str
    config: dict[str, Any]
    seed: int
    group: int
    provider: str = "mock"
    options: Any = None
    trials: int = 1
    """The run's trials: the timed trials take their numbers in turn (a recorded store holds
    answers for those trials only)."""


def calibration_job(job: CalibrationJob) -> Timing:
    """:func:`_calibrate` as a task of a process pool (a module-level function: spawned workers
    import it)."""
    run = PlannedRun(job.kind, cfg.from_dict(job.config), job.provider, job.seed, job.trials, 1, Path("calibration"), options=job.options)
    return _calibrate(run, job.group)


def _calibrate_all(
    todo: dict[tuple[str, ...], tuple[PlannedRun, int]], pool: Any, on_calibrated: Callable[[], None] | None
) -> dict[tuple[str, ...], Timing]:
    """Each experiment of ``todo`` (key -> a run and its lockstep group) timed: in the workers of a
    local process ``pool`` (:class:`lagrseq.running.executors.LocalExecutor`), else here, one
    after the other; ``on_calibrated`` is told of each as it ends."""
    from concurrent.futures import as_completed

    from lagrseq.running.executors import LocalExecutor

    timed: dict[tuple[str, ...], Timing] = {}
    if not isinstance(pool, LocalExecutor) or len(todo) <= 1:
        for key, (run, group) in todo.items():
            timed[key] = _calibrate(run, group)
            if on_calibrated is not None:
                on_calibrated()
        return timed
    futures = {
        pool.pool.submit(calibration_job, CalibrationJob(
            run.kind, run.config.to_dict(), run.seed, group, *_timed_provider(run), trials=run.trials,
        )): key
        for key, (run, group) in todo.items()
    }
    try:
        for future in as_completed(futures):
            timed[futures[future]] = future.result()
            if on_calibrated is not None:
                on_calibrated()
    except KeyboardInterrupt:
        runner.exit_on_next_interrupt()
        pool.interrupt()
        raise
    return timed


def _trial_steps(config: ExperimentConfig, timing: Timing) -> float:
    """A trial's expected steps: its step budget (a grid trial), its episodes at the timed steps per
    episode (a cube trial), or, where it stops early (``run.stop_at``), the steps the timed trial
    took (:attr:`Timing.trial_steps`), never more than its budget."""
    episodes, max_steps = config.run.episodes, config.run.max_steps
    if config.run.stop_at and timing.trial_steps > 0:
        return min(timing.trial_steps, float(max_steps)) if max_steps else timing.trial_steps
    steps_per_episode = timing.steps_per_episode
    if episodes == 0:  # no episode limit: the step budget alone ends a trial (grid tasks)
        return float(max_steps)
    steps = episodes * steps_per_episode
    return min(steps, max_steps) if max_steps else steps


def estimate(the_plan: Plan, jobs: int) -> float:
    """Expected seconds for the pending trials (see :func:`estimate_phases`)."""
    return estimate_phases(the_plan, jobs).runs


WARMUP_STEPS = 100
"""Untimed steps before the first calibration of a task and method in a process: imports (torch,
pybullet), first allocations, caches. Later calibrations of that task and method in the process
(a worker times many experiments) start warm."""
_WARM: set[tuple[str, str]] = set()


def _calibrate(run: PlannedRun, group: int = 1) -> Timing:
    """(seconds per step, steps per episode, seconds of a trial's start) or, for a probe,
    (seconds per sample, 0, 0), timed with logging to a scratch file (the log is part of the
    cost) and the provider of :func:`_timed_provider`, after an untimed warm-up (:data:`WARMUP_STEPS`):
    a cold process pays imports and first calls once, a trial's worker pays them once for many
    trials. ``group`` > 1: that many trials timed in
    lockstep, as the run will step them (seconds per step of one trial). A run whose trials stop
    early (``run.stop_at``: the first solve, the first accepted answer) is timed one trial, with its
    stop, to that point or :data:`STOP_CALIBRATION_STEPS` steps (:attr:`Timing.trial_steps`). A timing that fails
    with the run's provider (a store without the answers the run will miss on: the run says so
    itself) is taken again with the mock."""
    provider, options = _timed_provider(run)
    try:
        return _timed(run, group, provider, options)
    except Exception:  # noqa: BLE001 - an estimate only; the run reports its own errors
        if provider != "mock":
            with contextlib.suppress(Exception):
                return _timed(run, group, "mock", None)
        return UNTIMED  # its run fails too, and is reported as one failed item like any other


UNTIMED = Timing(0.0, 1.0, 0.0)
"""The timing of an experiment whose timed stretch raised (a plugin task's env that fails): it
adds nothing to the estimate, and its run, which fails the same way, is a failed item."""


def _timed(run: PlannedRun, group: int, provider: str, options: Any) -> Timing:
    with tempfile.TemporaryDirectory(prefix="lagrseq-calibration-") as scratch:
        path = Path(scratch) / "calibration.mcap"
        if run.kind == "accuracy":
            started = time.perf_counter()
            probe.run_accuracy_probe(run.config, 1, run.seed, provider, path)
            return Timing(time.perf_counter() - started, 0.0, 0.0)
        stops = bool(run.config.run.stop_at)
        group = 1 if stops else group
        slow = TASKS.get(run.config.task.name).calibration_steps
        if (run.config.task.name, run.config.method) not in _WARM:
            warm = replace(run.config, run=replace(run.config.run, max_steps=5 if slow else WARMUP_STEPS))
            runner.run_one(warm, 0, run.seed, provider, Path(scratch) / "warm-up.mcap", provider_options=options)
            _WARM.add((run.config.task.name, run.config.method))
        steps = slow or (
            STOP_CALIBRATION_STEPS if stops
            else LOCKSTEP_CALIBRATION_STEPS if group > 1 else EPISODES_CALIBRATION_STEPS if run.config.run.episodes else CALIBRATION_STEPS
        )
        if run.config.run.max_steps:  # never more steps than a trial has: its own length is timed whole
            steps = min(steps, run.config.run.max_steps)
        config = replace(run.config, run=replace(run.config.run, max_steps=steps))
        ready: list[float] = []

        def on_ready() -> None:
            ready.append(time.perf_counter())

        started = time.perf_counter()
        if group > 1:
            outcomes = runner.run_in_lockstep([
                functools.partial(
                    runner.run_one, config, trial % max(1, run.trials), run.seed, provider,
                    Path(scratch) / f"calibration-{trial}.mcap", provider_options=options, on_ready=on_ready,
                )
                for trial in range(group)
            ])
            failed = [outcome for outcome in outcomes if isinstance(outcome, BaseException)]
            if failed:
                raise failed[0]
            results = [outcome for outcome in outcomes if not isinstance(outcome, BaseException)]
        else:
            results = [runner.run_one(config, 0, run.seed, provider, path, provider_options=options, on_ready=on_ready)]
        seconds = time.perf_counter() - started
    # the trials' starts (lockstep: each is built before the first batched step, one after the
    # other) apart from their steps: a cube trial's start is a large part of a short trial
    start = max(ready) - started if ready else 0.0
    taken = sum(result.steps for result in results)
    steps = max(taken, 1)
    trial_steps = 0.0
    if stops:  # stopped before the budget: it reached its stop; else it may run the whole of its own
        budget = config.run.max_steps
        trial_steps = float(taken) if taken < budget else float(run.config.run.max_steps or taken)
    return Timing(
        (seconds - start) / steps, steps / max(sum(result.episodes for result in results), 1), start / len(results), trial_steps
    )
