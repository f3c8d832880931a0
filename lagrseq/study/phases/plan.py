"""Plan: the distinct runs of the suite, the frontier's matched-rate random runs, the authors'
recorded answers as a source."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq import outputs
from lagrseq.config import ExperimentConfig
from lagrseq.errors import ConfigError, UsageError
from lagrseq.logs.reader import is_complete
from lagrseq.progress import Reporter
from lagrseq.registry import EXECUTORS, PROVIDERS
from lagrseq.running import runner, wiring
from lagrseq.study import probe
from lagrseq.study.phases import audits
from lagrseq.study.phases.failures import ERRORS_LOG, rerun_command
from lagrseq.suite import RunSpec, Suite, is_authors_provider, miss_variant


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


def matched_sources(the_plan: Plan, items: AbstractSet[str]) -> list[PlannedRun]:
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


def plan_matched_random(the_plan: Plan, items: AbstractSet[str], runs_dir: Path) -> Plan:
    """The suite's second phase for its frontier ``items``: for each run of
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


def with_authors_answers(suite: Suite, caches: Path, out: Path, progress: Reporter | None = None) -> Suite:
    """``reproduce --authors-caches DIR``: import every authors' cache found in DIR into
    ``OUT/authors-answers`` and add a recorded-GPT run to every item they cover. Replay finds
    those runs in the logs by their provider (no suite change is needed to rebuild them)."""
    from lagrseq.study import authors
    from lagrseq.suite import with_recorded

    progress = progress or Reporter()
    found = authors.find_caches(caches, progress)
    for line in authors.import_caches(found, out, progress):
        progress.say(f"authors' answers: {line}")
    covers = {cache.covers for cache in found}
    return with_recorded(suite, authors.provider_spec(out), covers)


@dataclass(frozen=True)
class Request:
    """What ``lagrseq reproduce`` is asked to do: its command line's options."""

    suite_path: Path | None = None
    """The suite file (None: the packaged suite)."""
    items: Sequence[str] | None = None
    """``--items``: suite item ids and ``audit-TASK`` ids (None: every item)."""
    quick: bool = False
    provider: str | None = None
    """Replaces the suite's default provider."""
    out: Path = Path("lagrseq-out")
    jobs: int = 1
    seed: int | None = None
    """None: the suite's seed."""
    formats: Sequence[str] = ("png",)
    price: Callable[[str, int, int], float | None] | None = None
    """(model, prompt tokens, completion tokens) -> USD, for replay's costs tables."""
    executor: str = "local"
    scheduler: str | None = None
    retries: int = 0
    authors_caches: Path | None = None


@dataclass(frozen=True)
class SuitePlan:
    """The plan phase's result: what runs, where, and what the report needs to name."""

    suite: Suite
    """The suite as asked (its items, for the report)."""
    runs: Plan
    """The distinct runs of the suite (on the authors' answers too, with ``--authors-caches``) and
    the matched-rate random runs whose policies' logs are already complete."""
    matched_items: frozenset[str]
    """The frontier items whose learning policies get random at their query rate."""
    audits: list[tuple[str, list[Any], int]]
    """(task, planned runs, trials per run) of the audits this reproduce runs."""
    on_request: list[tuple[str, list[Any], int]]
    """The same for the audits the whole suite leaves to a request (timed for the report's line)."""
    audit_pending: dict[str, int]
    """Per audited task: trials whose log is not complete."""
    whole: bool
    """The packaged suite, every item: its audits and the open models' screens too."""
    seed: int
    runs_dir: Path
    reports_dir: Path
    rerun: Callable[..., str]
    """Item ids -> the ``lagrseq reproduce`` command that reruns them alone (:func:`rerun_command`)."""
    started: float
    """``time.perf_counter()`` when the work began (after the checks)."""


def plan_suite(request: Request, progress: Reporter) -> SuitePlan:
    """Check the request, import the authors' caches, plan the suite's runs, the matched-rate
    random runs that can be planned now and the audits; say which items are not run and why."""
    from lagrseq.paths import writable_directory

    suite, whole, requested = _asked_suite(request)
    seed = suite.seed if request.seed is None else request.seed
    writable_directory(request.out)
    for name in (ERRORS_LOG, "reports/index.html", "reports/index.md"):  # a link, folder or FIFO there: refused before anything runs
        outputs.check(request.out / name, "--out")
    runs_dir, reports_dir = writable_directory(request.out / "runs"), writable_directory(request.out / "reports", "--out")
    started = time.perf_counter()
    planned_suite = suite
    if request.authors_caches is not None:
        planned_suite = with_authors_answers(suite, request.authors_caches, request.out, progress)
    the_plan = plan(planned_suite, request.quick, request.provider, runs_dir, seed)
    check_providers(the_plan, request.provider)
    # a resumed suite: the matched-rate random runs of policies already complete join this phase
    # (and its estimate); the others run once their policies' logs exist (the execute phase)
    matched_items = frontier_items(planned_suite)
    the_plan.runs += plan_matched_random(the_plan, matched_items, runs_dir).runs
    for item_id, reason in the_plan.not_run.items():
        progress.say(f"{item_id}: not run: {reason}")
    for item_id, reason in the_plan.set_aside.items():
        progress.say(f"{item_id}: {reason}")
    ran = audits.suite_audits(runs_dir, request.quick, seed, None if whole else requested)
    # the whole suite: the audits it leaves to a request are timed too, for the report's line
    left = [task for task, audit in audits.SUITE_AUDITS.items() if not audit.in_suite]
    on_request = audits.suite_audits(runs_dir, request.quick, seed, left) if whole else []
    audit_pending = {
        task: sum(not is_complete(runner.trial_path(r.path, t)) for r in runs for t in range(trials))
        for task, runs, trials in [*ran, *on_request]
    }
    rerun = functools.partial(
        rerun_command, quick=request.quick, suite_path=request.suite_path, provider=request.provider, out=request.out,
        seed=request.seed, authors_caches=request.authors_caches,
    )
    return SuitePlan(
        suite, the_plan, frozenset(matched_items), ran, on_request, audit_pending, whole, seed, runs_dir, reports_dir,
        rerun, started,
    )


def _asked_suite(request: Request) -> tuple[Suite, bool, list[str]]:
    """The suite with the items asked for, whether it is the whole packaged suite, and the audits
    named in ``--items`` (``audit-TASK``); a provider or scheduler that cannot be used is refused
    here, before anything is written."""
    from lagrseq.suite import load_suite

    suite = load_suite(request.suite_path)
    whole = request.suite_path is None and request.items is None  # the packaged suite, every item: its audits too
    requested: list[str] = []
    if request.items is not None:
        if not request.items:
            raise UsageError("--items is empty; give suite item ids, e.g. --items fig6a,table2 (or leave --items out for all)")
        items, requested = audits.split_items(suite, request.items)
        suite = suite.select(items)
    if request.provider is not None:
        wiring.parse_provider(request.provider)
    if request.scheduler is not None and not EXECUTORS.get(request.executor).takes_scheduler:
        raise UsageError("--scheduler applies to --executor dask only")
    if request.scheduler is not None:
        from lagrseq.running.executors import check_scheduler

        check_scheduler(request.scheduler)
    return suite, whole, requested
