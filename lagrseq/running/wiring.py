"""Wiring: turns a configuration into the parts of a trial, through the registries.

``trial_parts`` builds everything one trial of ``lagrseq.loop.experiment.run_trial`` runs on; the
``make_*`` factories build one part each from the resolved configuration. A task is reached only
through its registered :class:`~lagrseq.registry.TaskSpec` (a built-in task's in
``lagrseq.builtin_tasks``, a plugin's in its package), so this module names no concrete task.
Provider specs (``mock``, ``mock:PROFILE``, ``recorded:STORE``, ``live[:MODEL]``) are parsed here
and only here.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Hashable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq import seeding
from lagrseq.agents.schedules import EpsilonSchedule
from lagrseq.config import (
    DQNConfig,
    ExperimentConfig,
    NeuralSecondaryConfig,
    RunConfig,
    TabularConfig,
)
from lagrseq.errors import ConfigError, UsageError
from lagrseq.llm.base import Provider
from lagrseq.llm.mock import MockProvider
from lagrseq.llm.options import LiveOptions, LocalOptions, RecordedOptions
from lagrseq.logs.events import Sink, View
from lagrseq.logs.task_fields import TaskFields, of_spec
from lagrseq.loop.adapters import (
    DQNPrimary,
    NeuralSeq,
    PrimaryAgent,
    TabularPrimary,
)
from lagrseq.loop.experiment import Guide, TrialParts
from lagrseq.loop.policies import Always, AskingPolicy, make_policy
from lagrseq.loop.seq import TabularSecondary
from lagrseq.paths import expand_user, input_path, source_checkout
from lagrseq.registry import (
    CALIBRATED_MISS,
    POLICIES,
    PROVIDERS,
    TASKS,
    ProviderKind,
    ProviderSpec,
    build_options,
    options_type,
    task_profiles,
)
from lagrseq.seeding import Stream
from lagrseq.tasks.base import Task, expect


def provider_help() -> str:
    """Every ``--provider`` form, from the provider registry."""
    return ", ".join(kind.usage for kind in PROVIDERS.specs())


# ------------------------------------------------------------------------------------------
# Providers
# ------------------------------------------------------------------------------------------
REFUSING = "refuses"
"""``--provider mock:refuses``: a model that is never right, on any task."""
REFUSAL = "I am sorry, I cannot complete this pattern."
REFUSING_HELP = (
    "answers every prompt of every task with a refusal, so no answer is ever accepted: what SEQ "
    "does when asking never pays, and the states a never-right model meets (to record a real "
    "one's answers for them with lagrseq record --from-runs)"
)


def mock_profiles() -> tuple[str, ...]:
    """Names accepted by ``--provider mock:PROFILE``: every task's profiles, and refuses."""
    names: list[str] = []
    for task in TASKS.specs():
        names += [p for p in task_profiles(task) if p not in names]
    return (*names, REFUSING)


def parse_provider(spec: str) -> ProviderSpec:
    """Split ``kind[:argument]`` and check it with its kind's registered check."""
    kind, _, argument = spec.partition(":")
    found = PROVIDERS.find(kind)
    if found is None:
        raise UsageError(f"unknown provider {spec!r}; expected {provider_help()}")
    parsed = ProviderSpec(kind, argument)
    if found.check_spec is not None:
        found.check_spec(parsed)
    return parsed


def provider_kind(spec: str | ProviderSpec) -> ProviderKind:
    """The registered kind of a ``--provider`` value."""
    return PROVIDERS.get((parse_provider(spec) if isinstance(spec, str) else spec).kind)


def check_mock_spec(spec: ProviderSpec) -> None:
    if spec.argument and spec.argument not in mock_profiles():
        raise UsageError(f"unknown mock profile {spec.argument!r}; expected one of: {', '.join(mock_profiles())}")


def check_recorded_spec(spec: ProviderSpec) -> None:
    if not spec.argument:
        raise UsageError("provider 'recorded' needs a store: recorded:STORE (a directory) or recorded:FILE.jsonl")
    if spec.argument.endswith(".jsonl"):
        recorded_file(spec.argument)  # a JSONL export that is not there: one line now, not per trial


MISSING_RECORDED_FIX = (
    "a non-editable install ships no recorded_llm/: run from a clone of the repository, or copy its recorded_llm/ folder into this directory"
)


def missing_recorded_file(spec: str) -> str | None:
    """The JSONL file of a ``recorded:FILE.jsonl`` spec when it is found neither here nor in the
    source checkout (:func:`recorded_file`), as written; None for any other spec."""
    kind = PROVIDERS.find(spec.partition(":")[0])
    argument = spec.partition(":")[2]
    if kind is None or not kind.replays or not argument.endswith(".jsonl"):
        return None
    try:
        recorded_file(argument)
    except UsageError:
        return argument
    return None


def recorded_file(argument: str) -> Path:
    """The JSONL export of ``recorded:FILE.jsonl``: FILE as given, or, for a relative path that is
    not there, FILE in the source checkout lagrseq runs from (the packaged suite's
    ``recorded_llm/`` files, found from any directory with an editable install). Only where the
    answers are read from: logs and reports keep ``argument`` as written."""
    path = expand_user(argument, "recorded answers")
    if path.exists():
        return input_path(path, "recorded answers", "file")  # a FIFO or a directory: one line
    checkout = source_checkout() / argument
    if not path.is_absolute() and checkout.is_file():
        return checkout
    raise UsageError(
        f"recorded answers {argument!r}: no such JSONL file here or in a lagrseq source checkout (relative paths are "
        f"looked up in both; {MISSING_RECORDED_FIX})"
    )


def provider_options(spec: str, given: dict[str, Any], elsewhere: tuple[str, ...] = ()) -> Any:
    """The options of ``spec``'s kind from the command line's provider flags (field name ->
    parsed value, None: not given); a flag its kind does not read is refused (one line) unless
    the command uses it ``elsewhere`` itself. None for a kind without options."""
    return build_options(provider_kind(spec), given, elsewhere)


def default_options(spec: str) -> Any:
    """The options of ``spec``'s kind with every field at its default (None: it has none)."""
    return build_options(provider_kind(spec), {})


def with_provider_model(config: ExperimentConfig, spec: str) -> ExperimentConfig:
    """The configuration naming the model ``spec`` asks (``live:MODEL``, a local model): the
    configuration, and so every log, says so."""
    provider = parse_provider(spec)
    kind = PROVIDERS.get(provider.kind)
    return config if kind.with_model is None else kind.with_model(config, provider)  # type: ignore[no-any-return]


def live_model(config: ExperimentConfig, provider: ProviderSpec) -> ExperimentConfig:
    """``live:MODEL`` asks MODEL."""
    if provider.argument and provider.argument != config.llm.model:
        return replace(config, llm=replace(config.llm, model=provider.argument))
    return config


def local_model(config: ExperimentConfig, provider: ProviderSpec) -> ExperimentConfig:
    """The local model is asked by its own name (logs and keys say so)."""
    from lagrseq.llm.local import model_name

    return replace(config, llm=replace(config.llm, model=model_name(provider.argument)))


def make_provider(
    spec: str,
    config: ExperimentConfig,
    rng: np.random.Generator,
    options: Any = None,
) -> Provider:
    """The provider of one trial. ``rng`` is the trial's LLM stream: the mock samples from it,
    the live provider draws its retry jitter from it, and a recorded store's sample choice is
    seeded by its first draw. ``options``: its kind's options (None: their defaults)."""
    provider = parse_provider(spec)
    return PROVIDERS.get(provider.kind).make(provider, config, rng, options if options is not None else default_options(spec))  # type: ignore[no-any-return]


def make_mock(provider: ProviderSpec, config: ExperimentConfig, rng: np.random.Generator, options: None) -> Provider:
    return MockProvider(extrapolator(config, provider.argument or "ideal"), rng, name=str(provider))


def make_live_provider(provider: ProviderSpec, config: ExperimentConfig, rng: np.random.Generator, options: LiveOptions) -> Provider:
    return make_live(options, rng, budgeted=True, on_retry=_say)  # type: ignore[no-any-return]


def make_local_provider(provider: ProviderSpec, config: ExperimentConfig, rng: np.random.Generator, options: LocalOptions) -> Provider:
    return make_local(provider.argument, options, rng)


def make_recorded(provider: ProviderSpec, config: ExperimentConfig, rng: np.random.Generator, options: RecordedOptions) -> Provider:
    """Answers from a store (or a JSONL export); ``--on-miss`` answers what it lacks."""
    from lagrseq.llm.recorded import RecordedProvider, RecordingProvider
    from lagrseq.llm.store import RecordStore, endpoint_of

    endpoint = endpoint_of(options.live.base_url)
    asks_live = options.pays
    if provider.argument.endswith(".jsonl"):  # a JSONL export, read into memory (once per process)
        from lagrseq.llm.recorded import JsonlRecordedProvider

        if asks_live:
            raise UsageError("--on-miss live records into a store directory; a JSONL export is read only (import it with lagrseq cache import)")
        seed = int(rng.integers(2**63))
        replay = JsonlRecordedProvider(recorded_file(provider.argument), endpoint, seed)
        try:
            replay.fallback = _miss_fallback(config, rng, options, replay.store, replay.endpoint, seed)
        except BaseException:
            replay.close()
            raise
        return replay
    store = RecordStore(provider.argument, create=asks_live)
    run_seed = int(rng.integers(2**63))
    if asks_live:
        # A miss is asked live and recorded (one sample), so the next run finds it.
        return RecordingProvider(store, make_live(options.live, rng, budgeted=True, on_retry=_say), endpoint, "new", 1, run_seed)
    try:
        fallback = _miss_fallback(config, rng, options, store, endpoint, run_seed)
    except BaseException:
        store.close()
        raise
    return RecordedProvider(store, endpoint, run_seed, fallback)


def _miss_fallback(
    config: ExperimentConfig, rng: np.random.Generator, options: RecordedOptions, store: Any, endpoint: str, run_seed: int
) -> Provider | None:
    """What answers a query a recorded store lacks: the rule-based mock (``mock``), a refusal
    that is never accepted (``refuse``), a draw at the store's own acceptance rate for prompts of
    its kind, fixed per prompt and run seed (``calibrated``), or nothing (``error``: the miss stops
    the run)."""
    from lagrseq.llm.recorded import RefusingProvider

    if options.on_miss == "mock":
        return MockProvider(extrapolator(config), rng, name="mock")
    if options.on_miss == "refuse":
        return RefusingProvider()
    if options.on_miss == CALIBRATED_MISS:
        from lagrseq.llm.calibrated import CalibratedMissProvider

        calibration = miss_calibration(config)
        return CalibratedMissProvider(fitted_rates(store, calibration), calibration, endpoint, run_seed)
    return None


def miss_calibration(config: ExperimentConfig) -> Any:
    """The task's :class:`~lagrseq.llm.calibrated.MissCalibration`; UsageError (one line) for a
    task that has none."""
    spec = TASKS.get(config.task.name)
    if spec.miss_calibration is None:
        able = ", ".join(t.name for t in TASKS.specs() if t.miss_calibration is not None) or "none"
        raise UsageError(
            f"--on-miss calibrated needs a task whose prompts have kinds to fit acceptance rates on ({able}); "
            f"{config.task.name} has none: use --on-miss refuse or mock"
        )
    return spec.miss_calibration(config)


_FITS: dict[tuple[str, str, int, str], Any] = {}
"""Fitted rates per (store, task, store size, calibration), once per process (a store's answers
are read and judged once, not once per trial)."""


def fitted_rates(store: Any, calibration: Any) -> Any:
    """The acceptance rates per kind of ``store``'s answers of the calibration's task
    (:func:`lagrseq.llm.calibrated.fit`); UsageError (one line) when the store holds none."""
    from lagrseq.llm.calibrated import fit

    key = (str(getattr(store, "directory", id(store))), calibration.task, len(store), calibration.about)
    found = _FITS.get(key)
    if found is None:
        found = fit(store.entries(), calibration)
        if found.answers == 0:
            raise UsageError(
                f"--on-miss calibrated: store {getattr(store, 'directory', store)} holds no answers of task "
                f"{calibration.task} to fit acceptance rates on; use --on-miss refuse or mock, or record answers first"
            )
        _FITS[key] = found
    return found


def pays(spec: str, options: Any = None) -> bool:
    """Whether answers of ``spec`` may cost money: a paid kind, or options that say their
    answers may (a store whose misses are asked live, ``--on-miss live``)."""
    return provider_kind(spec).paid or bool(getattr(options, "pays", False))


def _say(message: str) -> None:
    """Retries and notes of a live provider during a run go to stderr (redacted at the source)."""
    from lagrseq.text import shown

    print(f"lagrseq: {shown(message.strip())}", file=sys.stderr)


def check_provider(spec: str, config: ExperimentConfig, options: Any = None) -> None:
    """Fail before any trial starts (nothing is sent): a missing API key or store, a paid source
    under a policy that peeks at every answer; then the kind's own check (default: build the
    provider once and close it). ``options``: the kind's (None: their defaults)."""
    options = options if options is not None else default_options(spec)
    provider = parse_provider(spec)
    kind = PROVIDERS.get(provider.kind)
    wanted = options_type(kind)
    if (options is None) != (wanted is None) or (wanted is not None and not isinstance(options, wanted)):
        raise UsageError(f"--provider {provider.kind} takes {'no options' if wanted is None else wanted.__name__}, not {type(options).__name__}")
    if pays(spec, options) and config.method == "lagr-seq" and POLICIES.get(config.secondary.policy).peeks:
        raise UsageError(
            f"secondary.policy = {config.secondary.policy} looks at every answer before deciding, so it would pay for "
            "answers it does not use; run it on recorded:STORE (--on-miss mock|error) or mock"
        )
    if kind.check is not None:
        kind.check(provider, config, options)
        return
    kind.make(provider, config, np.random.default_rng(0), options).close()


def check_local(provider: ProviderSpec, config: ExperimentConfig, options: LocalOptions) -> None:
    """A local server is not started here: its model file and the extra are checked."""
    local_settings(provider.argument, options)


def local_settings(argument: str, options: LocalOptions, port: int = 0) -> Any:
    """The local server's settings for ``local[:MODEL]``; raises UsageError (one line) when the
    extra is missing or the model file is not there."""
    from lagrseq.llm.local import ServerSettings, missing_extra, resolve_model

    problem = missing_extra()
    if problem:
        raise UsageError(problem)
    model, name = resolve_model(argument)
    return ServerSettings(model=model, model_name=name, port=port, n_ctx=options.n_ctx, n_threads=options.threads)


def local_live(options: LocalOptions, base_url: str) -> LiveOptions:
    """How the live provider asks a local llama.cpp server at ``base_url``: no API key, the
    local run's timeouts and limits."""
    return LiveOptions(base_url=base_url, server="llama.cpp", http=options.http, limits=options.limits)


def make_local(argument: str, options: LocalOptions, rng: np.random.Generator) -> Provider:
    """A llama.cpp server started for this provider (stopped by its ``close``), asked through the
    live provider as ``--server llama.cpp`` with no API key."""
    from lagrseq.llm.local import LocalProvider, LocalServer, Supervisor
    from lagrseq.progress import Reporter

    reporter = Reporter(_say)
    server = LocalServer(local_settings(argument, options), reporter=reporter).start()
    supervisor = Supervisor(server, reporter)  # a server dying mid-run: restarted once, then one line
    try:
        inner = make_live(local_live(options, server.base_url), rng, budgeted=True, on_retry=supervisor.on_retry, environ={}, local_model=server.settings.model_name)
    except BaseException:
        supervisor.close()
        server.stop()
        raise
    return LocalProvider(server, inner, supervisor)  # type: ignore[return-value]


def make_live(
    options: LiveOptions,
    rng: np.random.Generator,
    budgeted: bool = False,
    on_retry: Callable[[str], None] | None = None,
    environ: dict[str, str] | None = None,
    local_model: str | None = None,
) -> Any:
    """The live provider of ``options``, behind a budget guard when asked (one budget per call).
    ``environ``: where the API key is looked up (default the process environment; ``{}`` for a
    local server, which is sent no key). ``local_model``: a model served on this machine, priced
    at zero (so ``--max-cost-usd`` holds without a price table)."""
    from lagrseq.llm.budget import Budget, BudgetedProvider
    from lagrseq.llm.live import LiveProvider, LiveSettings

    prices = load_prices(options.price_table)
    if local_model is not None:
        from lagrseq.llm.pricing import Price, PriceTable

        prices = PriceTable([*prices.prices.values(), Price(local_model, 0.0, 0.0, None, "served locally by llama.cpp: no charge", "2026-12-01")])
    settings = LiveSettings(
        base_url=options.base_url,
        api_key_env=options.api_key_env,
        server=options.server,
        read_timeout_s=options.http.read_timeout_s,
        request_deadline_s=options.http.request_deadline_s,
        max_response_bytes=options.http.max_response_bytes,
    )
    live = LiveProvider(settings, rng=rng, prices=prices, on_retry=on_retry, environ=environ)
    if not budgeted:
        return live
    limits = options.limits
    if limits.budget_ledger is not None:
        from lagrseq.llm.ledger import SharedBudget

        shared = SharedBudget(limits.budget_ledger, limits.max_cost_usd, limits.max_queries)
        return BudgetedProvider(live, shared, prices)
    return BudgetedProvider(live, Budget(limits.max_cost_usd, limits.max_queries), prices)


def load_prices(price_table: str | Path | None) -> Any:
    """The built-in price table, with ``price_table`` (a TOML file) over it."""
    from lagrseq.llm.pricing import PriceTable, read_price_table

    return read_price_table(price_table) if price_table else PriceTable()


def extrapolator(config: ExperimentConfig, profile: str = "ideal") -> Callable[[str, float, np.random.Generator], str]:
    """What the mock provider answers with: the task's rule-based extrapolator (``ideal``) or a
    calibrated profile of it (the task's registered ``extrapolator``). The mock itself stays
    task-free: it reads the same prompt text a real LLM would see."""
    if profile == REFUSING:
        return lambda prompt, temperature, rng: REFUSAL
    spec = TASKS.get(config.task.name)
    own = task_mock_profiles(spec)
    if profile not in own:  # a profile belongs to its task: another task's never reaches this one's extrapolator
        others = sorted({p for task in TASKS.specs() if task.name != spec.name for p in task_profiles(task)} - set(own))
        elsewhere = f" ({profile} is another task's)" if profile in others else ""
        raise UsageError(
            f"mock profile {profile!r} is not one of task {spec.name}'s{elsewhere}; "
            f"expected --provider mock or mock:PROFILE with PROFILE one of: {', '.join(own)}"
        )
    return spec.extrapolator(config, profile)  # type: ignore[no-any-return]


def task_mock_profiles(spec: Any) -> tuple[str, ...]:
    """The ``--provider mock:PROFILE`` profiles a task takes: ``ideal``, its own, ``refuses``."""
    return tuple(dict.fromkeys(("ideal", *task_profiles(spec), REFUSING)))


# ------------------------------------------------------------------------------------------
# Tasks, envs, agents
# ------------------------------------------------------------------------------------------
def make_task(config: ExperimentConfig) -> Task:
    """The task of ``config`` (its registered ``make_task``)."""
    return TASKS.get(config.task.name).make_task(config)  # type: ignore[no-any-return]


def make_env(config: ExperimentConfig, render_dir: Path | None = None) -> Any:
    """The task's env (its registered ``make_env``; imported there: ``lagrseq replay`` never needs
    gymnasium): a Gymnasium env, or for cube stacking its dynamics alone (the same ``reset``,
    ``step`` and ``close``). ``render_dir``: arm tasks write PNG frames and a GIF per episode
    there (``--render``)."""
    return TASKS.get(config.task.name).make_env(config, render_dir)


def make_schedule(section: Any, run: RunConfig) -> EpsilonSchedule:
    """The epsilon schedule of an agent section, counted in episodes or steps."""
    length = run.max_steps if section.epsilon_unit == "step" else run.episodes
    if section.epsilon_schedule == "linear" and section.epsilon_decay <= 0 and length == 0:
        unit = "max_steps" if section.epsilon_unit == "step" else "episodes"
        raise ConfigError(
            f"a linear epsilon schedule with epsilon_decay = 0 runs over half of run.{unit}, "
            f"which is 0 (no limit); set epsilon_decay to its length in {section.epsilon_unit}s"
        )
    return EpsilonSchedule(
        section.epsilon_schedule,
        section.epsilon_start,
        section.epsilon_min,
        section.epsilon_decay,
        length,
        section.epsilon_unit,
        section.epsilon_warmup,
    )


def make_primary(config: ExperimentConfig, task: Task, env: Any, seed: int, trial: int) -> PrimaryAgent:
    if isinstance(config.primary, DQNConfig):
        return DQNPrimary(config.primary, env, seed, trial)
    section = expect(config.primary, TabularConfig, "primary")
    return TabularPrimary(section, task, state_key(config, task, section.state_index))  # type: ignore[arg-type]


def state_key(config: ExperimentConfig, task: Task, index: str) -> Callable[[Any], Hashable] | None:
    """The tabular agent's Q-table row of a pattern under ``primary.state_index``: None for
    ``exact`` (one row per pattern), else the task's registered ``state_keys`` entry (the
    released cube code's ``upstream-aliased`` rows); ConfigError (one line) for a task without it."""
    if index == "exact":
        return None
    make = TASKS.get(config.task.name).state_keys.get(index)
    if make is None:
        able = ", ".join(t.name for t in TASKS.specs() if index in t.state_keys) or "no task"
        raise ConfigError(f"primary.state_index = {index!r} is a state index of {able}, not of {config.task.name}; use exact")
    return make(task)  # type: ignore[no-any-return]


def make_secondary(config: ExperimentConfig, task: Task, seed: int, trial: int) -> AskingPolicy | None:
    """The asking policy: ``secondary.policy`` for ``lagr-seq`` (``seq``: the paper's SEQ agent),
    always for ``lagr``, None for ``baseline`` (it never reaches a decision)."""
    if config.method == "baseline":
        return None
    if config.method == "lagr":
        return Always()
    section = config.secondary

    def seq_agent() -> Any:
        if isinstance(section, NeuralSecondaryConfig):
            return NeuralSeq(section, pattern_cells(config, task), seed, trial)
        return TabularSecondary(section.learning_rate)

    return make_policy(section, seq_agent)


def pattern_cells(config: ExperimentConfig, task: Task) -> int:
    """The length of a flattened pattern, which the neural SEQ agent reads: the task's
    ``cells`` (the grid tasks' rows x columns); ConfigError (one line) for a task without it."""
    cells = getattr(task, "cells", None)
    if not isinstance(cells, (int, np.integer)) or cells < 1:
        raise ConfigError(
            f"[secondary] is a {type(config.secondary).__name__}, whose neural SEQ agent reads a pattern of "
            f"task.cells cells; task {config.task.name} has no cells: use a tabular [secondary] section"
        )
    return int(cells)


def missing_dependency(config: ExperimentConfig) -> str:
    """Why ``config`` cannot run with the installed extras ("" when it can): the task's
    registered check (the arm's pybullet, airo-models or grpcio), then torch for the DQN agents
    and the neural SEQ agent (the ``dqn`` extra)."""
    check = TASKS.get(config.task.name).missing_dependency
    return (check(config) if check is not None else "") or torch_dependency(config)


def torch_dependency(config: ExperimentConfig) -> str:
    """The DQN agents and the neural SEQ agent need torch (the ``dqn`` extra), whatever the task."""
    import importlib.util

    needs_torch = isinstance(config.primary, DQNConfig) or (
        config.method == "lagr-seq" and isinstance(config.secondary, NeuralSecondaryConfig) and config.secondary.policy == "seq"
    )
    if needs_torch and importlib.util.find_spec("torch") is None:
        return "needs torch, which is not installed (pip install 'lagrseq[dqn]')"
    return ""


# ------------------------------------------------------------------------------------------
# Pictures (Foxglove views), per task
# ------------------------------------------------------------------------------------------
def view_topics(config: ExperimentConfig) -> dict[str, tuple[str, str, bytes]] | None:
    """The picture topics of ``config``'s task for the sink (None: the task has none)."""
    topics = TASKS.get(config.task.name).view_topics
    return None if topics is None else topics(config)


def step_views(config: ExperimentConfig, env: Any) -> Callable[[dict[str, Any], int], list[View]] | None:
    """The pictures written after every step (the task's registered ``views``), from the step's
    info: the state for Foxglove, and for arm tasks the robot's joints and camera."""
    views = TASKS.get(config.task.name).views
    return None if views is None else views(config, env)


def trial_parts(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    open_sink: Callable[[], Sink],
    provider_options: Any = None,
    render_dir: Path | None = None,
) -> TrialParts:
    """Everything trial ``trial`` of a run with seed ``seed`` runs on; each random stream is
    spawned from (seed, trial, component), so a trial is the same whatever else runs. The sink
    is opened last, so a part that cannot be built leaves no file behind."""
    task = make_task(config)
    env = make_env(config, None if render_dir is None else Path(render_dir) / f"trial-{trial:03d}")
    primary = make_primary(config, task, env, seed, trial)
    secondary = make_secondary(config, task, seed, trial)
    provider = make_provider(provider_spec, config, seeding.generator(seed, trial, Stream.LLM), provider_options)
    return TrialParts(
        config=config,
        trial=trial,
        task=task,
        env=env,
        primary=primary,
        secondary=secondary,
        provider=provider,
        sink=open_sink(),
        primary_epsilon=make_schedule(config.primary, config.run),
        secondary_epsilon=make_schedule(config.secondary, config.run),
        env_seed=seeding.integer_seed(seed, trial, Stream.ENV),
        primary_rng=seeding.generator(seed, trial, Stream.PRIMARY),
        secondary_rng=seeding.generator(seed, trial, Stream.SECONDARY),
        guidance_rng=seeding.generator(seed, trial, Stream.GUIDANCE),
        views=step_views(config, env),
        guide=make_guide(config, task, env),
        task_fields=task_fields(config),
    )


def task_fields(config: ExperimentConfig) -> TaskFields | None:
    """The record types of ``config``'s task when it logs fields of its own (its TaskSpec's
    ``episode_fields``, ``step_fields``); None when it declares none."""
    return of_spec(TASKS.get(config.task.name))


def make_guide(config: ExperimentConfig, task: Task, env: Any) -> Guide | None:
    """pi_LLM of the task's env (its registered ``guide``; None: the task's guidance where the
    env is)."""
    guide = TASKS.get(config.task.name).guide
    return None if guide is None else guide(config, task, env)  # type: ignore[no-any-return]


