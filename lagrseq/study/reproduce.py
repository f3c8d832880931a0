"""``lagrseq reproduce``: run the paper's suite, then replay it into a report.

1. Plan: every run the suite's items list, each distinct configuration once (Fig. 5(a), Fig. 6(a)
   and Table 2 share runs); items whose task or provider this lagrseq lacks are set aside with a
   one-line reason.
2. Estimate: time a short stretch of every distinct configuration on this machine (logged to a
   scratch file, with the run's own provider where that asks no model; a run whose trials stop
   early, ``run.stop_at``, one trial to its stop) and report the expected wall time before starting.
3. Run: trials in parallel on local processes or Dask workers through
   :func:`lagrseq.running.runner.run_trials`; trials whose log is complete are skipped, so a rerun resumes.
   Then the frontier items' second phase (:func:`plan_matched_random`): ``random`` at each
   learning policy's query rate, read from its logs, on the same seed and trials.
4. Replay: :func:`lagrseq.analysis.replay.replay` over the run logs, from the MCAP files alone.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import shlex
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

from lagrseq import config as cfg
from lagrseq import outputs
from lagrseq.config import ExperimentConfig
from lagrseq.errors import ConfigError, LagrseqError, TrialsFailed, UsageError
from lagrseq.logs.reader import is_complete
from lagrseq.loop.experiment import TrialResult
from lagrseq.registry import EXECUTORS, PROVIDERS, TASKS
from lagrseq.running import runner, wiring
from lagrseq.study import probe
from lagrseq.suite import RunSpec, Suite, is_authors_provider, miss_variant

CALIBRATION_STEPS = 1000
"""Environment steps timed per distinct experiment to estimate the suite's duration (one trial
alone with a step budget)."""
EPISODES_CALIBRATION_STEPS = 5000
"""The same for a trial that ends after a number of episodes (cube stacking): timed whole, up to
this many steps. Its first episodes are the longest (the agent has learned nothing yet), so steps
per episode from its first 1,000 steps made a trial 4.5x longer than it is (91 steps an episode
against 24 over a whole trial of 2,454 steps, 18 ms)."""
LOCKSTEP_CALIBRATION_STEPS = 300
"""Environment steps of each trial when a lockstep group of trials is timed (at most 900
trial-steps for a group of :data:`LOCKSTEP_CALIBRATION_GROUP`). Each distinct configuration is
timed (an asking policy or the provider changes how often a trial asks and is guided), so each
timing is short; the sums over the quick suite's 16 image-completion and 16 object-arrangement
runs came within 7% of their CPU time (docs/performance.md, "Seventh round")."""

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


@dataclass
class PlannedRun:
    """One distinct run of the suite."""

    kind: str
    config: ExperimentConfig
    provider: str
    seed: int
    trials: int
    samples: int
    path: Path
    """Run directory (trials) or log file (accuracy probe)."""
    items: list[str] = field(default_factory=list)
    options: Any = None
    """The provider kind's options (None: their defaults; runs on the authors' answers: misses
    go to the mock)."""
    source: Path | None = None
    """A frontier's matched-rate random run: the run whose query rate it matches."""
    full_horizon: list[str] = field(default_factory=list)
    """The items in which this run is a full-length copy (``full_horizon_trials``) of a run whose
    trials stop at the first solve: not compared with random at its query rate there."""

    def pending(self) -> int:
        """Trials (or probe files) whose log is not complete yet."""
        if self.kind == "accuracy":
            return 0 if is_complete(self.path) else 1
        return sum(not is_complete(runner.trial_path(self.path, t)) for t in range(self.trials))

    def units(self) -> int:
        """Progress units: one per probe, else what ``runner.progress_unit`` counts (episodes of
        cube trials, environment steps of grid trials) over all trials."""
        if self.kind == "accuracy":
            return 1
        return self.trials * runner.progress_unit(self.config)[1]

    def describe(self) -> str:
        name = f"{self.config.task.name} {self.config.method}"
        if self.kind == "accuracy":
            name = f"{self.config.task.name} accuracy probe"
        return name


@dataclass
class Plan:
    runs: list[PlannedRun]
    not_run: dict[str, str]
    """Suite item id -> why none of its runs can be made here."""
    unavailable: dict[str, str]
    """Provider spec -> why it is not available."""
    set_aside: dict[str, str] = field(default_factory=dict)
    """Suite item id -> which of its runs cannot be made here and why, for items with others that
    can (e.g. a recorded store's file not found: the item and the file, one line)."""


ERRORS_LOG = "reproduce-errors.log"
"""``OUT/reproduce-errors.log``: the whole text of every failure of the latest ``reproduce`` into
OUT (removed by a run in which nothing failed). The terminal gets one short line per run."""
LINE_WIDTH = 300
"""At most this many characters in a failed run's line on the terminal."""
REASON_WIDTH = 200
"""At most this many characters in a failed item's reason on the report."""
_ABSOLUTE = re.compile(r"(?<![\w.~/-])/(?!/)[^\s;,()'\"`<>|]+")


def _clip(text: str, width: int) -> str:
    one = " ".join(text.split())
    return one if len(one) <= width else one[: max(0, width - 1)].rstrip() + "…"


def without_absolute_paths(text: str) -> str:
    """``text`` with every absolute path shortened to its file or folder name (a report's bytes
    must not depend on where its inputs sat)."""
    return _ABSOLUTE.sub(lambda m: Path(m.group(0).rstrip(".")).name + ("." if m.group(0).endswith(".") else ""), text)


@dataclass(frozen=True)
class RunFailure:
    """A run of the suite (or of one of its audits) some of whose trials failed, or that could
    not start: what ``reproduce`` says about it on the terminal, in the report and in
    :data:`ERRORS_LOG`."""

    what: str
    """The run as people name it: task, method, preset, provider, config digest."""
    path: Path
    """Its run directory (or probe log)."""
    failed: int
    total: int
    """Trials that failed, of those it had to run."""
    errors: tuple[str, ...]
    """One whole text per failed trial (``trial N (seed S, config D) failed: ...``)."""
    error: str
    """The first failure's error (whole)."""
    advice: str
    """What to do, by the cause (:func:`lagrseq.running.runner.rerun_advice`)."""
    items: tuple[str, ...] = ()
    """The suite items it feeds."""
    audit: str = ""
    """The task whose suite audit it belongs to ("" for a suite item's run)."""
    short: str = ""
    """The run's name on the terminal (default: :attr:`what`)."""

    @property
    def owner(self) -> str:
        return f"{self.audit} audit" if self.audit else ",".join(self.items)

    def reason(self) -> str:
        """One short line, with no absolute path (for the report)."""
        return _clip(without_absolute_paths(f"{self.failed} of {self.total} trials of {self.what} failed: {self.error}"), REASON_WIDTH)

    def line(self) -> str:
        """One line of at most :data:`LINE_WIDTH` characters (for the terminal): who, which run,
        the error cut short (at least 60 characters of it) and what to do; the whole text is in
        :data:`ERRORS_LOG`, which the summary line names."""
        head = f"failed: {self.owner}: {self.failed} of {self.total} trials of "
        tail = f"; {self.advice}"
        what = _clip(without_absolute_paths(self.short or self.what), max(20, LINE_WIDTH - len(head) - len(tail) - 2 - 60))
        room = LINE_WIDTH - len(head) - len(what) - 2 - len(tail)
        return _clip(f"{head}{what}: {_clip(self.error, max(room, 20))}{tail}", LINE_WIDTH)

    def log_text(self, out: Path) -> str:
        """Its block of :data:`ERRORS_LOG`: everything, paths relative to ``out`` where inside it."""
        try:
            where = self.path.relative_to(out).as_posix()
        except ValueError:
            where = str(self.path)
        lines = [
            f"== {self.owner}: {self.what}",
            f"run: {where}; {self.failed} of {self.total} trials failed",
            f"what to do: {self.advice}",
            *self.errors,
            "",
        ]
        return "\n".join(lines)


def _describe_config(config: ExperimentConfig, provider: str) -> str:
    return f"{config.task.name} {config.method} --preset {config.preset} on {provider} (config {config.digest()})"


def _short_name(config: ExperimentConfig, provider: str) -> str:
    return f"{config.task.name} {config.method} on {provider}"


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
                _describe_config(run.config, run.provider), run.path, len(failures), failed.total,
                tuple(f.describe() for f in failures), failures[0].error, failed.advice, tuple(run.items),
                short=_short_name(run.config, run.provider),
            )
        )
    if not out:
        raise caught
    return out


def item_failures(failures: Sequence[RunFailure], rerun: Callable[[list[str]], str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The suite items the failed runs feed (item id -> :class:`~lagrseq.analysis.items.ItemFailure`,
    in the order first failed) and the audits that failed ("TASK audit" -> the same), each with
    the first failed run's reason, every distinct advice and ``rerun([item id])``, the command that
    reruns it alone (an audit: ``--items audit-TASK``, :func:`audit_item`)."""
    from lagrseq.analysis.items import ItemFailure

    by_item: dict[str, list[RunFailure]] = {}
    by_audit: dict[str, list[RunFailure]] = {}
    for failure in failures:
        if failure.audit:
            by_audit.setdefault(f"{failure.audit} audit", []).append(failure)
        for item in failure.items:
            by_item.setdefault(item, []).append(failure)

    def made(runs: list[RunFailure], command: str) -> ItemFailure:
        advice = "; ".join(dict.fromkeys(f.advice for f in runs))
        return ItemFailure(runs[0].reason(), advice, command, len(runs), tuple(str(f.path) for f in runs))

    return (
        {item: made(runs, rerun([item])) for item, runs in by_item.items()},
        {audit: made(runs, rerun([audit_item(runs[0].audit)])) for audit, runs in by_audit.items()},
    )


def rerun_command(
    items: Sequence[str],
    quick: bool,
    suite_path: Path | None,
    provider: str | None,
    out: Path,
    seed: int | None,
    authors_caches: Path | None,
    relative: bool = False,
) -> str:
    """The ``lagrseq reproduce`` command that reruns ``items`` alone (none: the whole suite), with the user's flags that
    change what runs or where it goes (``relative``: paths relative to this directory, for a
    report, which must hold no absolute path)."""

    def shown(path: Path) -> str:
        text = os.path.relpath(path) if relative and path.is_absolute() else str(path)
        return shlex.quote(text)

    words = ["lagrseq reproduce"] + (["--quick"] if quick else []) + (["--items", ",".join(items)] if items else [])
    if suite_path is not None:
        words += ["--suite", shown(suite_path)]
    if provider is not None:
        words += ["--provider", shlex.quote(provider)]
    if seed is not None:
        words += ["--seed", str(seed)]
    if authors_caches is not None:
        words += ["--authors-caches", shown(authors_caches)]
    if out != Path("lagrseq-out"):  # the command line's default (lagrseq.cli.DEFAULT_REPRODUCE_OUT)
        words += ["--out", shown(out)]
    return " ".join(words)


def write_errors_log(out: Path, failures: Sequence[RunFailure], reruns: Mapping[str, str] | None = None) -> Path:
    """``OUT/reproduce-errors.log`` with every failure's whole text (secrets blanked), then the
    command that reruns each failed item (``reruns``: item id or "TASK audit" -> command); a
    stale one is removed when nothing failed."""
    from lagrseq.keys import redact_key_like

    path = out / ERRORS_LOG
    if not failures:
        if os.path.isfile(path) and not os.path.islink(path):  # a folder or FIFO there is not ours
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        return path
    header = [
        f"lagrseq reproduce: {len(failures)} failed run{'s' if len(failures) != 1 else ''} "
        "(each: who, the run, what to do, then every failed trial's whole error)",
        "",
    ]
    text = "\n".join(header) + "\n".join(f.log_text(out) for f in failures)
    if reruns:
        text += "\n".join(["== to rerun each alone", *(f"{key}: {command}" for key, command in reruns.items()), ""])
    outputs.write_text(path, redact_key_like(without_checkout(text)), "--out")  # every key form blanked there
    return path


def without_checkout(text: str) -> str:
    """``text`` with the folder holding lagrseq (a traceback's file names) written relative to it:
    a log must not tell where the checkout lies."""
    from lagrseq.paths import source_checkout

    folder = str(source_checkout())
    return text.replace(folder + os.sep, "") if len(folder) > 1 else text


def failure_summary(failed: Mapping[str, Any], problems: Mapping[str, Any], items_total: int, out: Path) -> str:
    """The one line ``reproduce`` ends with when something failed: ``3 of 23 items failed: table3
    (2 runs), ...; details in OUT/reproduce-errors.log`` (``failed``: item id -> its
    :class:`~lagrseq.analysis.items.ItemFailure`; ``problems``: the audits that failed)."""

    def runs(n: int) -> str:
        return f"{n} run{'s' if n != 1 else ''}"

    parts = []
    if failed:
        parts.append(f"{len(failed)} of {items_total} items failed: " + ", ".join(f"{key} ({runs(f.runs)})" for key, f in failed.items()))
    if problems:
        parts.append(("also " if failed else "") + ", ".join(f"the {key} ({runs(f.runs)})" for key, f in problems.items()) + " failed")
    return "; ".join(parts) + f"; details in {out / ERRORS_LOG}"


def _provider_problem(spec: str) -> str | None:
    try:
        parsed = wiring.parse_provider(spec)
        if PROVIDERS.get(parsed.kind).local_server:  # the extra and the model file, checked without starting a server
            wiring.local_settings(parsed.argument, wiring.LocalOptions())
    except UsageError as exc:
        return f"provider not available: {exc}"
    return None


def plan(suite: Suite, quick: bool, provider: str | None, runs_dir: Path, seed: int) -> Plan:
    """The distinct runs of ``suite`` (``provider`` replaces the suite's default provider)."""
    default = provider or suite.provider
    planned: dict[Path, PlannedRun] = {}
    not_run: dict[str, str] = {}
    unavailable: dict[str, str] = {}
    set_aside: dict[str, str] = {}
    for item in suite.items:
        reasons: list[str] = []
        files: list[str] = []
        made = 0
        asked = [spec for spec in item.runs if spec.length(quick)[0] > 0]  # quick_full_horizon_trials = 0: no copy
        for spec in asked:
            spec_provider = spec.provider_spec(default)
            config, reason = _resolve(spec, quick, spec_provider, unavailable)
            if config is None:
                missing = wiring.missing_recorded_file(spec_provider)
                if missing is None:
                    reasons.append(reason)
                elif missing not in files:
                    files.append(missing)
                continue
            made += 1
            trials, _, _ = spec.length(quick)
            samples = spec.samples if not quick else spec.quick_samples
            options = run_options(spec, spec_provider)
            if spec.kind == "accuracy":
                path = probe.probe_path(runs_dir, config, spec_provider, seed, samples)
            else:
                variant = miss_variant(spec_provider, getattr(options, "on_miss", None))
                path = runner.run_directory(runs_dir, config, spec_provider, seed, variant=variant)
            run = planned.get(path)
            if run is None:
                run = planned[path] = PlannedRun(
                    spec.kind, config, spec_provider, seed, trials, samples, path, options=options
                )
            elif run.options != options:
                raise ConfigError(
                    f"suite item {item.id!r}: run {spec.label!r} is the same run as item {run.items[0]!r}'s but "
                    f"answers store misses otherwise ({_miss_rule(options)} vs {_miss_rule(run.options)}); "
                    "give both the same on_miss"
                )
            run.trials = max(run.trials, trials)
            if item.id not in run.items:
                run.items.append(item.id)
            if spec.full_horizon and item.id not in run.full_horizon:
                run.full_horizon.append(item.id)
        missed = len(asked) - made
        if files:  # one reason for all the files an item needs and this machine lacks
            reasons.append(
                f"recorded answers not found here or in a lagrseq source checkout: {', '.join(files)} ({wiring.MISSING_RECORDED_FIX})"
            )
        if made == 0:
            not_run[item.id] = "; ".join(sorted(set(reasons)))
        elif missed:
            set_aside[item.id] = f"{missed} of {len(asked)} runs not run: " + "; ".join(sorted(set(reasons)))
    return Plan(list(planned.values()), not_run, unavailable, set_aside)


def run_options(spec: RunSpec, provider: str) -> Any:
    """The provider options of a suite run on ``provider``: runs on the authors' answers answer
    store misses as their ``on_miss`` says (an item's ``recorded_on_miss`` rows), by default with
    the mock (counted beside each number, no verdict where it decided); a run whose suite entry
    declares ``on_miss`` answers them as it says; else None (the kind's defaults: a miss stops the
    run)."""
    if is_authors_provider(provider):
        return wiring.provider_options(provider, {"on_miss": spec.on_miss or "mock"})
    if spec.on_miss is not None and wiring.provider_kind(provider).replays:
        return wiring.provider_options(provider, {"on_miss": spec.on_miss})
    return None


def _miss_rule(options: Any) -> str:
    return f"on_miss = {getattr(options, 'on_miss', None) or 'error (default)'}"


def frontier_items(suite: Suite) -> set[str]:
    """The ids of the suite's frontier items (``render = "frontier"``)."""
    return {item.id for item in suite.items if item.render == "frontier"}


def matched_sources(the_plan: Plan, items: set[str]) -> list[PlannedRun]:
    """The planned runs of the frontier ``items`` that the protocol compares with ``random`` at
    their own query rate (:func:`lagrseq.frontier_protocol.wants_match`): learning policies, not on
    the authors' answers with mock fallbacks (those points get no verdict), and not an item's
    full-length copies of runs stopped at the first solve (``full_horizon_trials``: as
    ``lagrseq frontier --full-horizon-trials``, whose full group has no matched random); the
    stopped runs' matched random stops at the first solve too (it keeps ``run.stop_at``:
    :func:`lagrseq.study.frontier.matched_random_config`)."""
    from lagrseq.frontier_protocol import wants_match

    out = []
    for run in the_plan.runs:
        compared = items & (set(run.items) - set(run.full_horizon))
        if run.kind != "trial" or run.config.method != "lagr-seq" or not compared:
            continue
        if run.options is not None and run.options.on_miss == "mock":
            continue
        if wants_match(run.config.secondary.policy, ()):
            out.append(run)
    return out


def plan_matched_random(the_plan: Plan, items: set[str], runs_dir: Path) -> Plan:
    """The suite's second phase for its frontier ``items`` (issue 20): for each run of
    :func:`matched_sources` whose trials are complete, its query rate from its logs (queries /
    decisions, :func:`lagrseq.frontier_protocol.matched_probability`) and a run of ``random`` at that
    rate with otherwise the same configuration, provider, seed and trials (so its trials pair with
    the policy's), as ``lagrseq frontier`` runs it. None where the rate is 0 or 1 (random at rate 1
    is always) or the run is already planned (the suite's own random); a run whose trials are not
    all complete gets none (a rerun resumes it first)."""
    from lagrseq.frontier_protocol import matched_probability
    from lagrseq.study import frontier

    planned: dict[Path, PlannedRun] = {}
    existing = {run.path for run in the_plan.runs}
    for run in matched_sources(the_plan, items):
        if run.pending():
            continue
        queries, decisions = frontier.rate_counts(run.path, run.trials)
        if queries == 0 or decisions == 0:
            continue
        probability = matched_probability(queries, decisions)
        if probability >= 1.0:
            continue
        config = frontier.matched_random_config(run.config, probability)
        path = runner.run_directory(runs_dir, config, run.provider, run.seed, variant=miss_variant(run.provider, getattr(run.options, "on_miss", None)))
        if path in existing:
            continue
        match = planned.get(path)
        if match is None:
            match = planned[path] = PlannedRun(
                "trial", config, run.provider, run.seed, run.trials, 0, path, options=run.options, source=run.path
            )
        match.trials = max(match.trials, run.trials)
        match.items += [
            item for item in run.items if item in items and item not in run.full_horizon and item not in match.items
        ]
    return Plan(list(planned.values()), {}, {})


def _resolve(
    spec: RunSpec, quick: bool, provider: str, unavailable: dict[str, str]
) -> tuple[ExperimentConfig | None, str]:
    """The run's configuration, or None and why it cannot run here (its task or provider)."""
    try:
        config = spec.resolve(quick)
    except ConfigError as exc:
        if spec.task not in cfg.tasks():
            return None, f"task {spec.task} not available"
        return None, str(exc)
    missing = wiring.missing_dependency(config)
    if missing:
        return None, f"{spec.task} {missing}"
    problem = _provider_problem(provider)
    if problem:
        unavailable[provider] = problem
        return None, problem
    return config, ""


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
    mock: the model and temperature it asks do not change its cost). Issue 35: the quick suite
    timed 81 configurations for 77 runs."""
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
:data:`REPLAY_SECONDS_PER_LOG_ONE_PROCESS`). Measured on the quick suite's 874 logs on a 2-core
machine (``benchmarks/bench_replay.py``; docs/performance.md, "Replay")."""
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
    this machine's CPUs): on 2 cores, workers cost replay 1.38x the CPU time and 1.24x the wall
    time on the quick suite's logs (docs/performance.md, "Issue 35")."""
    from lagrseq.analysis.loading import WORKERS_MIN_CPUS, usable_cpus

    return 1 if min(jobs, usable_cpus()) < WORKERS_MIN_CPUS else jobs


@dataclass
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
        (task, audit_config, audit_trials, PlannedRun("trial", audit_config, "mock", 0, audit_trials, 0, Path(f"audit-{task}")))
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

    def calibrated(run: PlannedRun) -> Timing:
        return cache[key_of(run)[0]]

    serial = work = longest = 0.0
    works: dict[Path, float] = {}
    logs = 0
    for run in the_plan.runs:
        pending = run.pending()
        logs += run.trials if run.kind == "trial" else 1
        if pending == 0:
            continue
        timing = calibrated(run)
        per_unit, start = timing.per_step, timing.start
        if run.kind == "accuracy":
            serial += per_unit * run.samples
            works[run.path] = per_unit * run.samples
            continue
        trial_seconds = start + _trial_steps(run.config, timing) * per_unit
        works[run.path] = pending * trial_seconds
        work += works[run.path]
        longest = max(longest, trial_seconds)
    parallel = max(work / max(1, jobs), longest)
    out = Estimate(runs=serial + parallel)
    for run in the_plan.runs:
        if run.path in works:
            share = works[run.path] if run.kind == "accuracy" else works[run.path] / work * parallel if work else 0.0
            out.per_run[run.path] = share
    for task, audit_config, _, probe_run in probes:
        timing = calibrated(probe_run)
        out.audit_per_trial[task] = (timing.start + _trial_steps(audit_config, timing) * timing.per_step) / max(1, jobs)
    logs += audit_logs
    if replay_jobs(jobs) <= 1:
        reading, per_item = REPLAY_SECONDS_PER_LOG_ONE_PROCESS * logs, REPLAY_SECONDS_PER_ITEM + REPLAY_DRAW_SECONDS_PER_ITEM
    else:
        reading, per_item = REPLAY_SECONDS_PER_LOG * logs / min(jobs, 8), REPLAY_SECONDS_PER_ITEM
    out.replay = REPLAY_SECONDS_FIXED + reading + per_item * items
    return out


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
    on_run: Callable[[PlannedRun], None] | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    say: Callable[[str], None] | None = None,
    retries: int = 0,
    seconds: dict[Path, float] | None = None,
    pool: Any = None,
    failures: list[RunFailure] | None = None,
) -> list[TrialResult]:
    """Run every planned run (complete trials are skipped): the accuracy probes in this process,
    then the trials of every run through one warm process pool or one Dask cluster
    (``executor``, ``scheduler``: see :func:`lagrseq.running.executors.make_executor`), all submitted at
    once so that no worker waits for the last trial of one run before the next run starts.
    Without a pool (``jobs = 1``) the runs go one after the other, ``on_run`` told of each.
    ``seconds`` (run path -> estimated seconds): the bar counts estimated seconds, not units.
    ``pool``: an executor already started (:func:`start_pool`), kept warm across the phases.
    ``failures``: where runs whose trials failed (or that could not start) are added, while the
    other runs go on; without it the first such failure is raised (:class:`TrialsFailed`) at the
    end of its phase."""

    def scale(run: PlannedRun) -> float:
        if seconds is None:
            return 1.0
        return seconds.get(run.path, 0.0) / max(1, run.units())

    def one(run: PlannedRun) -> list[TrialResult]:
        try:
            return _execute_run(run, bar, on_run, retries, scale(run))
        except TrialsFailed as caught:
            if failures is None:
                raise
            failures.extend(run_failures(caught, [run]))
        except LagrseqError as caught:  # an accuracy probe's provider, a store that cannot be read
            if failures is None:
                raise
            error = " ".join(str(caught).split())
            total = 1 if run.kind == "accuracy" else run.trials
            failures.append(
                RunFailure(
                    _describe_config(run.config, run.provider), run.path, total, total, (f"{run.describe()} failed: {error}",),
                    error, runner.rerun_advice(caught), tuple(run.items), short=_short_name(run.config, run.provider),
                )
            )
        return []

    results: list[TrialResult] = []
    for run in the_plan.runs:
        if run.kind == "accuracy":
            results += one(run)
    trial_runs = [run for run in the_plan.runs if run.kind != "accuracy"]
    with contextlib.ExitStack() as stack:
        if pool is None and needs_pool(executor, jobs, scheduler):
            pool = stack.enter_context(runner.make_executor(executor, jobs, scheduler, say))
        if pool is None:
            for run in trial_runs:
                results += one(run)
            return results
        if bar is not None and hasattr(bar, "set_description") and trial_runs:
            bar.set_description(f"{len(trial_runs)} runs on {pool.describe()}")
        shares = [_RunProgress(bar, run.units(), scale(run)) for run in trial_runs]
        sweep = [
            runner.SweepRun(
                run.config, run.trials, run.seed, run.provider, run.path, run.options, progress=share,
                seconds=seconds.get(run.path, 0.0) / max(1, run.pending()) if seconds is not None else None,
            )
            for run, share in zip(trial_runs, shares, strict=True)
        ]
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


def needs_pool(executor: str, jobs: int, scheduler: str | None) -> bool:
    """Whether trials run through an executor (a process pool, Dask) rather than in this process."""
    return not EXECUTORS.get(executor).runner_pool or scheduler is not None or jobs > 1


def _execute_run(
    run: PlannedRun,
    bar: Any,
    on_run: Callable[[PlannedRun], None] | None,
    retries: int = 0,
    scale: float = 1.0,
) -> list[TrialResult]:
    """One planned run in this process: an accuracy probe, or its trials one after the other."""
    if on_run is not None:
        on_run(run)
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


def duration(seconds: float) -> str:
    """A duration as people read it: seconds, minutes or hours."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def reproduce(
    suite_path: Path | None,
    items: list[str] | None,
    quick: bool,
    provider: str | None,
    out: Path,
    jobs: int,
    seed: int | None,
    formats: list[str],
    price: Callable[[str, int, int], float | None] | None = None,
    quiet: bool = False,
    say: Callable[[str], None] = print,
    executor: str = "local",
    scheduler: str | None = None,
    retries: int = 0,
    authors_caches: Path | None = None,
    warn: Callable[[str], None] | None = None,
) -> tuple[Any, float]:
    """``lagrseq reproduce``: plan the suite, say what will run and how long it should take, run
    it with one progress bar (episodes of cube runs, steps of grid runs), then replay the logs into
    ``out/reports``. Returns the replay report and the seconds it all took.

    A run whose trials fail (or that cannot start) does not stop the others: ``warn`` (default
    ``say``) gets one short line per failed run (:meth:`RunFailure.line`), the whole text goes to
    ``out/reproduce-errors.log`` (:data:`ERRORS_LOG`), and the items it feeds are reported as
    failed, each with its reason and the command that reruns it alone (``report.failed``; a
    failed suite audit: ``report.problems``)."""
    from lagrseq.analysis.replay import replay
    from lagrseq.paths import writable_directory
    from lagrseq.progress import bar as progress_bar
    from lagrseq.suite import load_suite

    suite = load_suite(suite_path)
    whole = suite_path is None and items is None  # the packaged suite, every item: its audits too
    requested: list[str] = []  # the audits named in --items (audit-TASK)
    if items is not None:
        if not items:
            raise UsageError("--items is empty; give suite item ids, e.g. --items fig6a,table2 (or leave --items out for all)")
        items, requested = split_items(suite, items)
        suite = suite.select(items)
    asked_seed = seed
    seed = suite.seed if seed is None else seed
    if provider is not None:
        wiring.parse_provider(provider)
    if scheduler is not None and not EXECUTORS.get(executor).takes_scheduler:
        raise UsageError("--scheduler applies to --executor dask only")
    if scheduler is not None:
        from lagrseq.running.executors import check_scheduler

        check_scheduler(scheduler)
    writable_directory(out)
    for name in (ERRORS_LOG, "reports/index.html", "reports/index.md"):  # a link, folder or FIFO there: refused before anything runs
        outputs.check(out / name, "--out")
    runs_dir, reports_dir = writable_directory(out / "runs"), writable_directory(out / "reports", "--out")
    started = time.perf_counter()
    planned_suite = suite
    if authors_caches is not None:
        planned_suite = with_authors_answers(suite, authors_caches, out, say)
    the_plan = plan(planned_suite, quick, provider, runs_dir, seed)
    check_providers(the_plan, provider)
    rerun = functools.partial(
        rerun_command, quick=quick, suite_path=suite_path, provider=provider, out=out, seed=asked_seed,
        authors_caches=authors_caches,
    )
    # a resumed suite: the matched-rate random runs of policies already complete join this phase
    # (and its estimate); the others run once their policies' logs exist (below)
    matched_items = frontier_items(planned_suite)
    the_plan.runs += plan_matched_random(the_plan, matched_items, runs_dir).runs
    for item_id, reason in the_plan.not_run.items():
        say(f"{item_id}: not run: {reason}")
    for item_id, reason in the_plan.set_aside.items():
        say(f"{item_id}: {reason}")
    # The plan's counts are the suite's own runs; the matched-rate random runs are counted apart,
    # by the policies they follow, so that a first run and a rerun print the same plan (a rerun
    # has them planned already, a first run makes them once their policies' runs are complete).
    own = [run for run in the_plan.runs if run.source is None]
    matched_now = [run for run in the_plan.runs if run.source is not None]
    pending = sum(run.pending() for run in own)
    trials = sum(run.trials if run.kind == "trial" else 1 for run in own)
    to_match = matched_sources(Plan(own, {}, {}), matched_items)
    match_trials = sum(run.trials for run in to_match)
    match_complete = sum(run.trials - run.pending() for run in matched_now)
    audits = suite_audits(runs_dir, quick, seed, None if whole else requested)
    # the whole suite: the audits it leaves to a request are timed too, for the report's line
    on_request = suite_audits(runs_dir, quick, seed, [t for t, a in SUITE_AUDITS.items() if not a.in_suite]) if whole else []
    audit_pending = {
        task: sum(not is_complete(runner.trial_path(r.path, t)) for r in runs for t in range(trials))
        for task, runs, trials in [*audits, *on_request]
    }
    # One display for every phase: calibration (experiments timed), then estimated seconds of
    # runs, audits and replay, with rate and ETA.
    # One pool (or Dask cluster) for every phase: its workers time the experiments side by side
    # and then run the trials, paying their imports once.
    with contextlib.ExitStack() as stack, progress_bar(
        max(1, calibration_keys(the_plan, jobs) + sum(map(bool, audit_pending.values()))), "experiment", "calibration", quiet
    ) as bar:
        pool = stack.enter_context(runner.make_executor(executor, jobs, scheduler, say)) if needs_pool(executor, jobs, scheduler) else None
        guess = estimate_phases(
            the_plan, jobs,
            [(task, runs[0].config, trials) for task, runs, trials in [*audits, *on_request] if runs and audit_pending[task]],
            len(suite.items), on_calibrated=lambda: bar.update(1), audit_logs=sum(len(runs) * n for _, runs, n in audits),
            pool=pool,
        )
        guess.audit = sum(guess.audit_per_trial.get(task, 0.0) * audit_pending[task] for task, _, _ in audits)
        on_request_seconds = {
            task: guess.audit_per_trial[task] * audit_pending[task] if task in guess.audit_per_trial else (0.0 if not audit_pending[task] else None)
            for task, _, _ in on_request
        }
        # the frontier's matched-rate random runs of policies still to run: each about as long as
        # its policy's run
        guess.runs += sum(guess.per_run.get(run.path, 0.0) for run in matched_sources(the_plan, matched_items))
        guess.calibration = time.perf_counter() - started
        say(
            f"{'quick' if quick else 'full'} suite: {len(own)} runs, {trials} trial logs, "
            f"{pending} to run ({trials - pending} already complete)"
            + (
                f", then up to {len(to_match)} run{'s' if len(to_match) != 1 else ''} of random at the frontier policies' matched query rates "
                f"({match_trials} trial logs, {match_complete} already complete)"
                if to_match else ""
            )
            + "; expected about "
            f"{duration(guess.total)} on {jobs} {EXECUTORS.get(executor).workers[jobs > 1]} "
            f"(calibration {duration(guess.calibration)} done, runs {duration(guess.runs)}, audits {duration(guess.audit)}, "
            f"replay {duration(guess.replay)}; "
            f"timed on this machine; LLM latency of live providers not included)"
        )
        for task, seconds in on_request_seconds.items():
            say(f"{task} audit: not in the suite; {on_request_line(rerun([audit_item(task)]), seconds, jobs, executor)}")
        bar.unit = "s"  # the unit and format first: reset redraws the bar
        bar.bar_format = "{desc}{percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} estimated s [{elapsed}<{remaining}, {rate_fmt}]"
        bar.set_description("runs", refresh=False)
        bar.reset(total=max(guess.total - guess.calibration, 1e-9))
        failures: list[RunFailure] = []
        told = 0

        def tell() -> None:  # the phase's failed runs, one short line each
            nonlocal told
            for failure in failures[told:]:
                (warn or say)(failure.line())
            told = len(failures)

        execute(
            the_plan, jobs, bar, on_run=lambda run: bar.set_description(run.describe()),
            executor=executor, scheduler=scheduler, say=say, retries=retries, seconds=guess.per_run, pool=pool,
            failures=failures,
        )
        tell()
        matched = plan_matched_random(the_plan, matched_items, runs_dir)
        if matched.runs:
            pending_matched = sum(run.pending() for run in matched.runs)
            say(
                f"random at the frontier policies' matched query rates: {len(matched.runs)} runs, "
                f"{pending_matched} trials to run"
            )
            if pending_matched:
                execute(
                    matched, jobs, bar, on_run=lambda run: bar.set_description(f"{run.describe()} (matched random)"),
                    executor=executor, scheduler=scheduler, say=say, retries=retries,
                    seconds={run.path: guess.per_run.get(run.source, 0.0) for run in matched.runs if run.source}, pool=pool,
                    failures=failures,
                )
                tell()
        for task, _, _ in audits:
            bar.set_description(f"{task} audit")
            run_suite_audit(
                task, runs_dir, quick, jobs, seed, quiet, say, _Scaled(bar, guess.audit_per_trial.get(task, 0.0)), pool,
                failures=failures,
            )
            tell()
        try:
            write_errors_log(out, failures, {key: f.rerun for found in item_failures(failures, rerun) for key, f in found.items()})
        except UsageError as exc:  # planted while the runs ran: the report is still made
            (warn or say)(f"{exc}; the report is made without it")
        if pool is not None:  # the replay's own workers start now: these go first
            stack.pop_all().close()
        say(f"runs done in {duration(time.perf_counter() - started)}: {runs_dir}")
        bar.set_description("replay")
        sections: list[Any] = []
        if whole:  # the whole suite: the open models' screens, from recorded answers
            from lagrseq.study.screen import report_sections

            sections, line = report_sections()
            say(line)
        if audits or on_request:
            sections.append(audit_section(
                [task for task, _, _ in audits], on_request_seconds, jobs, executor, functools.partial(rerun, relative=True),
            ))
        failed, problems = item_failures(failures, functools.partial(rerun, relative=True))
        report = replay(
            [runs_dir],
            reports_dir,
            formats,
            suite,
            provider=provider or suite.provider,
            unavailable=the_plan.unavailable,
            produced_by="lagrseq reproduce" + (" --quick" if quick else ""),
            price=price,
            jobs=replay_jobs(jobs),
            sections=sections,
            failed=failed,
            problems=problems,
        )
        bar.update(max(0.0, bar.total - bar.n))
    elapsed = time.perf_counter() - started
    say(
        f"finished in {duration(elapsed)}; estimated {duration(guess.total)} before starting "
        f"(actual / estimate = {elapsed / guess.total:.2f})" if guess.total > 0 else f"finished in {duration(elapsed)}"
    )
    return report, elapsed


def check_providers(the_plan: Plan, provider: str | None) -> None:
    """``--provider`` given: the runs that use it get it built once before any trial starts (a
    missing store or API key is one line, nothing run); a provider the user did not choose only
    sets its items aside (``Plan.not_run``)."""
    if provider is None:
        return
    for run in the_plan.runs:
        if run.provider == provider:
            wiring.check_provider(run.provider, run.config, run.options)
            return


def with_authors_answers(suite: Suite, caches: Path, out: Path, say: Callable[[str], None] = print) -> Suite:
    """``reproduce --authors-caches DIR``: import every authors' cache found in DIR into
    ``OUT/authors-answers`` and add a recorded-GPT run to every item they cover. Replay finds
    those runs in the logs by their provider (no suite change is needed to rebuild them)."""
    from lagrseq.study import authors
    from lagrseq.suite import with_recorded

    found = authors.find_caches(caches, warn=lambda line: say(f"warning: {line}"))
    for line in authors.import_caches(found, out, warn=lambda line: say(f"note: {line}")):
        say(f"authors' answers: {line}")
    covers = {cache.covers for cache in found}
    return with_recorded(suite, authors.provider_spec(out), covers)


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
(:func:`audit_item`). The whole suite runs the cube audit; the grid audits run on request (issue
35: at full length they were two thirds of the full suite's 35 minutes; the quick suite's reduced
ones go with them, so that ``--quick`` previews what the full suite runs). The grid tasks' quick
audits are reduced (2 trials of 200 steps, the upstream preset's fields switched to the paper's
values only: indicative, labelled so on their tables)."""

AUDIT_ITEM_PREFIX = "audit-"


def audit_item(task: str) -> str:
    """The ``--items`` id that runs ``task``'s audit alone (``audit-TASK``: the stem of its tables)."""
    return f"{AUDIT_ITEM_PREFIX}{task}"


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


def _audit_plan(task: str, runs_dir: Path, quick: bool, seed: int, say: Callable[[str], None]) -> tuple[list[Any], int]:
    from lagrseq.study.audit import plan as audit_plan

    chosen = SUITE_AUDITS[task]
    trials, episodes, max_steps = chosen.quick if quick else chosen.full
    runs = audit_plan(task, chosen.provider, trials, episodes, max_steps, runs_dir, seed, say, chosen.quick_presets if quick else None)
    return runs, trials


def suite_audits(
    runs_dir: Path, quick: bool, seed: int, tasks: Sequence[str] | None = None
) -> list[tuple[str, list[Any], int]]:
    """(task, planned audit runs, trials per run) of the audits of ``tasks`` (default: those the
    whole suite runs, :attr:`SuiteAudit.in_suite`) whose task is here."""
    chosen = [task for task, audit in SUITE_AUDITS.items() if audit.in_suite] if tasks is None else tasks
    here = cfg.tasks()
    return [(task, *_audit_plan(task, runs_dir, quick, seed, lambda line: None)) for task in chosen if task in here]


def run_suite_audit(
    task: str, runs_dir: Path, quick: bool, jobs: int, seed: int, quiet: bool, say: Callable[[str], None], bar: Any = None,
    pool: Any = None, failures: list[RunFailure] | None = None,
) -> None:
    """The audit of ``task`` (``lagrseq audit TASK``) at the suite's length, into the suite's runs,
    so that replay adds its tables and figures (a preset run the suite also makes is shared).
    ``bar``: the display to move by one per trial (default: a bar of its own, in trials);
    ``pool``: an executor already started (else one of ``jobs`` local processes); ``failures``:
    where its failed runs are added while the others go on (else :class:`TrialsFailed` is raised)."""
    if failures is None:
        _run_suite_audit(task, runs_dir, quick, jobs, seed, quiet, say, bar, pool, None)
        return
    try:
        _run_suite_audit(task, runs_dir, quick, jobs, seed, quiet, say, bar, pool, failures)
    except LagrseqError as caught:  # the audit could not be planned or started at all
        error = " ".join(str(caught).split())
        failures.append(
            RunFailure(f"the {task} audit", runs_dir, 1, 1, (f"the {task} audit failed: {error}",), error, runner.rerun_advice(caught), audit=task)
        )


def _run_suite_audit(
    task: str, runs_dir: Path, quick: bool, jobs: int, seed: int, quiet: bool, say: Callable[[str], None], bar: Any,
    pool: Any, failures: list[RunFailure] | None,
) -> None:
    from lagrseq.progress import bar as progress_bar

    chosen = SUITE_AUDITS[task]
    runs, trials = _audit_plan(task, runs_dir, quick, seed, say)
    _, _, max_steps = chosen.quick if quick else chosen.full
    together = sum(1 for r in runs if r.field and " + " in r.field)
    say(
        f"{task} audit: {len(runs)} runs of {trials} trials"
        + (f" of {max_steps} steps" if max_steps >= 0 else "")
        + (" (reduced: upstream -> paper only)" if quick and chosen.quick_presets != ("upstream", "paper") else "")
        + f", one field switched each{f' and {together} interaction runs' if together else ''} (lagrseq audit)"
    )
    with contextlib.ExitStack() as stack:
        if bar is None:
            bar = stack.enter_context(progress_bar(len(runs) * trials, "trial", quiet=quiet))
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
                        _describe_config(audited.config, audited.provider), failed.directory, len(found), failed.total,
                        tuple(f.describe() for f in found), found[0].error, failed.advice, audit=task,
                        short=_short_name(audited.config, audited.provider),
                    )
                )

