"""Wiring: the only place that knows the concrete tasks, envs, agents and providers.

``trial_parts`` builds everything one trial of ``lagrseq.experiment.run_trial`` runs on; the
``make_*`` factories build one part each from the resolved configuration. Provider specs
(``mock``, ``mock:PROFILE``, ``recorded:STORE``, ``live[:MODEL]``) are parsed here and only here.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from lagrseq import seeding
from lagrseq.adapters import (
    DQNPrimary,
    NeuralSeq,
    PrimaryAgent,
    TabularPrimary,
    TabularSeq,
)
from lagrseq.agents.schedules import EpsilonSchedule
from lagrseq.config import (
    ArmEnvConfig,
    ArmTaskConfig,
    ArrangementEnvConfig,
    ArrangementTaskConfig,
    CubeEnvConfig,
    CubeTaskConfig,
    DQNConfig,
    ExperimentConfig,
    ImageEnvConfig,
    ImageTaskConfig,
    NeuralSecondaryConfig,
    RunConfig,
    TabularConfig,
)
from lagrseq.errors import ConfigError, UsageError
from lagrseq.experiment import TrialParts
from lagrseq.llm.base import Provider
from lagrseq.llm.mock import MockProvider
from lagrseq.llm.servers import DEFAULT_BASE_URL, base_url_problem
from lagrseq.logs import foxglove
from lagrseq.logs.events import Sink, View
from lagrseq.paths import expand_user, input_path
from lagrseq.policies import Always, AskingPolicy, make_policy
from lagrseq.seeding import Stream
from lagrseq.tasks import cube, grid, grid_profiles
from lagrseq.tasks.arrangement import arm_arrangement, object_arrangement
from lagrseq.tasks.base import Task
from lagrseq.tasks.image import image_completion

PROVIDER_KINDS = ("mock", "recorded", "live", "local")
ON_MISS = ("error", "mock", "live", "refuse")
PROVIDER_HELP = "mock, mock:PROFILE, recorded:STORE, live, live:MODEL, local or local:MODEL.gguf"


# ------------------------------------------------------------------------------------------
# Providers
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProviderSpec:
    """A parsed ``--provider`` value: ``kind[:argument]``."""

    kind: str
    """mock | recorded | live | local"""
    argument: str = ""
    """The mock's profile, the recorded store's directory (or JSONL file), the live model, or
    the local model's GGUF file."""

    def __str__(self) -> str:
        return f"{self.kind}:{self.argument}" if self.argument else self.kind


REFUSING = "refuses"
"""``--provider mock:refuses``: a model that is never right, on any task."""
REFUSAL = "I am sorry, I cannot complete this pattern."
REFUSING_HELP = (
    "answers every prompt of every task with a refusal, so no answer is ever accepted: what SEQ "
    "does when asking never pays, and the states a never-right model meets (to record a real "
    "one's answers for them with lagrseq record --from-runs)"
)


def mock_profiles() -> tuple[str, ...]:
    """Names accepted by ``--provider mock:PROFILE`` (cube profiles, grid profiles, refuses)."""
    return (*cube.PROFILES, *grid_profiles.PROFILES, REFUSING)


def parse_provider(spec: str) -> ProviderSpec:
    """Split ``kind[:argument]`` and check it: ``mock``, ``mock:PROFILE``, ``recorded:STORE``,
    ``live`` or ``live:MODEL``."""
    kind, _, argument = spec.partition(":")
    if kind not in PROVIDER_KINDS:
        raise UsageError(f"unknown provider {spec!r}; expected {PROVIDER_HELP}")
    if kind == "mock" and argument and argument not in mock_profiles():
        raise UsageError(f"unknown mock profile {argument!r}; expected one of: {', '.join(mock_profiles())}")
    if kind == "recorded" and not argument:
        raise UsageError("provider 'recorded' needs a store: recorded:STORE (a directory) or recorded:FILE.jsonl")
    if kind == "recorded" and argument.endswith(".jsonl"):
        recorded_file(argument)  # a JSONL export that is not there: one line now, not per trial
    return ProviderSpec(kind, argument)


def recorded_file(argument: str) -> Path:
    """The JSONL export of ``recorded:FILE.jsonl``: FILE as given, or, for a relative path that is
    not there, FILE in the source checkout lagrseq runs from (the packaged suite's
    ``recorded_llm/`` files)."""
    path = expand_user(argument, "recorded answers")
    if path.exists():
        return input_path(path, "recorded answers", "file")  # a FIFO or a directory: one line
    checkout = Path(__file__).resolve().parents[1] / argument
    if not path.is_absolute() and checkout.is_file():
        return checkout
    raise UsageError(f"recorded answers {argument!r}: no such JSONL file (relative paths are looked up here and in the lagrseq source checkout)")


@dataclass(frozen=True)
class ProviderOptions:
    """How a provider other than the plain mock is set up: where answers come from, not what the
    experiment is, so these are command-line options rather than config fields. They are written
    into each trial's metadata. The API key is never here, only the name of its variable."""

    base_url: str = DEFAULT_BASE_URL
    """API root of the live server; its host is also part of every recorded key."""
    api_key_env: str = "OPENAI_API_KEY"
    """Environment variable holding the API key."""
    server: str = "openai"
    """Kind of OpenAI-compatible server (whether it honours ``n``)."""
    on_miss: str = "error"
    """recorded:STORE only: what answers a query the store lacks (error | mock | live | refuse)."""
    price_table: str | None = None
    """TOML file of prices over the built-in table."""
    max_cost_usd: float | None = None
    """Live answers: stop before a request that could pass this many US dollars (per run with a
    ``budget_ledger``: every trial and worker together; else per provider)."""
    max_queries: int | None = None
    """Live answers: stop before a request that would pass this many answers (as above)."""
    read_timeout_s: float = 120.0
    """Seconds to wait for the next bytes of a response."""
    request_deadline_s: float = 300.0
    """Most seconds one request may take, from sending to the last byte (retried like a timeout)."""
    max_response_bytes: int = 4 * 1024 * 1024
    """Largest response body read, decompressed (a larger one fails at once, not retried)."""
    budget_ledger: str | None = None
    """SQLite file holding one budget for every trial and worker of a run (set by the runner when
    a limit is given; not part of the metadata: it says where, not what)."""
    local_n_ctx: int = 2048
    """local[:MODEL] only: the llama.cpp server's context size in tokens."""
    local_threads: int = 0
    """local[:MODEL] only: the llama.cpp server's threads (0: half the cores, at least 1)."""

    def __post_init__(self) -> None:
        if self.on_miss not in ON_MISS:
            raise UsageError(f"--on-miss {self.on_miss!r}; expected one of {', '.join(ON_MISS)}")
        problem = base_url_problem(self.base_url)
        if problem is not None:
            raise UsageError(problem)

    def to_json(self) -> str:
        fields = asdict(self)
        fields.pop("budget_ledger")
        return json.dumps(fields, sort_keys=True)


def with_provider_model(config: ExperimentConfig, spec: str) -> ExperimentConfig:
    """``live:MODEL`` asks MODEL: the configuration (and so every log) says so."""
    provider = parse_provider(spec)
    if provider.kind == "live" and provider.argument and provider.argument != config.llm.model:
        return replace(config, llm=replace(config.llm, model=provider.argument))
    if provider.kind == "local":  # the local model is asked by its own name (logs and keys say so)
        from lagrseq.llm.local import model_name

        return replace(config, llm=replace(config.llm, model=model_name(provider.argument)))
    return config


def make_provider(
    spec: str,
    config: ExperimentConfig,
    rng: np.random.Generator,
    options: ProviderOptions | None = None,
) -> Provider:
    """The provider of one trial. ``rng`` is the trial's LLM stream: the mock samples from it,
    the live provider draws its retry jitter from it, and a recorded store's sample choice is
    seeded by its first draw."""
    from lagrseq.llm.recorded import RecordedProvider, RecordingProvider
    from lagrseq.llm.store import RecordStore, endpoint_of

    provider = parse_provider(spec)
    options = options or ProviderOptions()
    if provider.kind == "mock":
        return MockProvider(extrapolator(config, provider.argument or "ideal"), rng, name=spec)
    if provider.kind == "live":
        return make_live(options, rng, budgeted=True, on_retry=_say)
    if provider.kind == "local":
        return make_local(provider.argument, options, rng)
    endpoint = endpoint_of(options.base_url)
    if provider.argument.endswith(".jsonl"):  # a JSONL export, replayed from a temporary store
        from lagrseq.llm.recorded import JsonlRecordedProvider

        if options.on_miss == "live":
            raise UsageError("--on-miss live records into a store directory; a JSONL export is read only (import it with lagrseq cache import)")
        seed = int(rng.integers(2**63))
        return JsonlRecordedProvider(recorded_file(provider.argument), endpoint, seed, _miss_fallback(config, rng, options))
    store = RecordStore(provider.argument, create=options.on_miss == "live")
    run_seed = int(rng.integers(2**63))
    if options.on_miss == "live":
        # A miss is asked live and recorded (one sample), so the next run finds it.
        return RecordingProvider(store, make_live(options, rng, budgeted=True, on_retry=_say), endpoint, "new", 1, run_seed)
    return RecordedProvider(store, endpoint, run_seed, _miss_fallback(config, rng, options))


def _miss_fallback(config: ExperimentConfig, rng: np.random.Generator, options: ProviderOptions) -> Provider | None:
    """What answers a query a recorded store lacks: the rule-based mock (``mock``), a refusal
    that is never accepted (``refuse``), or nothing (``error``: the miss stops the run)."""
    from lagrseq.llm.recorded import RefusingProvider

    if options.on_miss == "mock":
        return MockProvider(extrapolator(config), rng, name="mock")
    if options.on_miss == "refuse":
        return RefusingProvider()
    return None


def _say(message: str) -> None:
    """Retries and notes of a live provider during a run go to stderr (redacted at the source)."""
    print(f"lagrseq: {message.strip()}", file=sys.stderr)


def check_provider(spec: str, config: ExperimentConfig, options: ProviderOptions | None = None) -> None:
    """Build the provider once and close it, so that a missing API key or store fails before any
    trial starts (nothing is sent). A local server is not started here: its model file and the
    extra are checked."""
    options = options or ProviderOptions()
    if parse_provider(spec).kind == "local":
        local_settings(parse_provider(spec).argument, options)
        return
    paid = parse_provider(spec).kind == "live" or options.on_miss == "live"
    if paid and config.method == "lagr-seq" and config.secondary.policy == "oracle":
        raise UsageError(
            "secondary.policy = oracle looks at every answer before deciding, so it would pay for "
            "answers it does not use; run it on recorded:STORE (--on-miss mock|error) or mock"
        )
    make_provider(spec, config, np.random.default_rng(0), options).close()


def local_settings(argument: str, options: ProviderOptions, port: int = 0) -> Any:
    """The local server's settings for ``local[:MODEL]``; raises UsageError (one line) when the
    extra is missing or the model file is not there."""
    from lagrseq.llm.local import ServerSettings, missing_extra, resolve_model

    problem = missing_extra()
    if problem:
        raise UsageError(problem)
    model, name = resolve_model(argument)
    return ServerSettings(model=model, model_name=name, port=port, n_ctx=options.local_n_ctx, n_threads=options.local_threads)


def make_local(argument: str, options: ProviderOptions, rng: np.random.Generator) -> Provider:
    """A llama.cpp server started for this provider (stopped by its ``close``), asked through the
    live provider as ``--server llama.cpp`` with no API key."""
    from lagrseq.llm.local import LocalProvider, LocalServer, Supervisor

    server = LocalServer(local_settings(argument, options), on_line=_say).start()
    supervisor = Supervisor(server, _say)  # a server dying mid-run: restarted once, then one line
    try:
        local = replace(options, base_url=server.base_url, server="llama.cpp")
        inner = make_live(local, rng, budgeted=True, on_retry=supervisor.on_retry, environ={}, local_model=server.settings.model_name)
    except BaseException:
        supervisor.close()
        server.stop()
        raise
    return LocalProvider(server, inner, supervisor)  # type: ignore[return-value]


def make_live(
    options: ProviderOptions,
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
        read_timeout_s=options.read_timeout_s,
        request_deadline_s=options.request_deadline_s,
        max_response_bytes=options.max_response_bytes,
    )
    live = LiveProvider(settings, rng=rng, prices=prices, on_retry=on_retry, environ=environ)
    if not budgeted:
        return live
    if options.budget_ledger is not None:
        from lagrseq.llm.ledger import SharedBudget

        shared = SharedBudget(options.budget_ledger, options.max_cost_usd, options.max_queries)
        return BudgetedProvider(live, shared, prices)
    return BudgetedProvider(live, Budget(options.max_cost_usd, options.max_queries), prices)


def load_prices(price_table: str | Path | None) -> Any:
    """The built-in price table, with ``price_table`` (a TOML file) over it."""
    from lagrseq.llm.pricing import PriceTable, read_price_table

    return read_price_table(price_table) if price_table else PriceTable()


def extrapolator(config: ExperimentConfig, profile: str = "ideal") -> Callable[[str, float, np.random.Generator], str]:
    """What the mock provider answers with: the task's rule-based extrapolator (``ideal``) or a
    calibrated profile of it (``cube.PROFILES``). The mock itself stays task-free: it reads the
    same prompt text a real LLM would see."""
    if profile == REFUSING:
        return lambda prompt, temperature, rng: REFUSAL
    task = make_task(config)
    if isinstance(task, cube.CubeStacking):
        if profile in grid_profiles.PROFILES:
            raise UsageError(f"mock profile {profile!r} is calibrated for the grid tasks; cube stacking has: {', '.join(cube.PROFILES)}")
        return cube.profile_extrapolator(task, profile)
    if profile in grid_profiles.PROFILES and isinstance(task, grid.GridTask):
        return grid_profiles.profile_extrapolator(task, profile, config.lagr.threshold)
    if profile != "ideal":
        raise UsageError(
            f"mock profile {profile!r} is calibrated for cube stacking only; "
            f"{config.task.name} has the ideal mock (--provider mock) and: {', '.join(grid_profiles.PROFILES)}"
        )
    return grid.extrapolate


# ------------------------------------------------------------------------------------------
# Tasks, envs, agents
# ------------------------------------------------------------------------------------------
_Section = TypeVar("_Section")


def _expect(value: Any, cls: type[_Section], section: str) -> _Section:
    """``value`` as the section class this task needs (configs from ``config.load`` always are)."""
    if not isinstance(value, cls):
        raise ConfigError(
            f"[{section}] is a {type(value).__name__}, this task needs a {cls.__name__}; "
            "build configurations with lagrseq.config.load"
        )
    return value


def make_task(config: ExperimentConfig) -> Task:
    task = config.task
    if isinstance(task, CubeTaskConfig):
        return cube.CubeStacking(task.stack_size)  # type: ignore[return-value]
    if isinstance(task, ImageTaskConfig):
        return image_completion(task.target, task.goal_threshold, task.prompt_matrix, task.guidance)
    if isinstance(task, ArrangementTaskConfig):
        return object_arrangement(task.target, task.goal_threshold, task.prompt_matrix, task.guidance)
    if isinstance(task, ArmTaskConfig):
        return arm_arrangement(task.target, task.goal_threshold, task.prompt_matrix, task.guidance)
    raise UsageError(f"unknown task {task.name!r}")  # pragma: no cover


def make_env(config: ExperimentConfig, render_dir: Path | None = None) -> Any:
    """The task's gymnasium env (imported here: ``lagrseq replay`` never needs gymnasium).
    ``render_dir``: arm tasks write PNG frames and a GIF per episode there (``--render``)."""
    task = config.task
    if isinstance(task, ArmTaskConfig):
        return make_arm_env(config, render_dir)
    if isinstance(task, CubeTaskConfig):
        from lagrseq.envs.cube_stacking import CubeStackingEnv

        env = _expect(config.env, CubeEnvConfig, "env")
        return CubeStackingEnv(
            stack_size=task.stack_size,
            horizon=env.horizon,
            bonus=env.bonus,
            bonus_on=env.bonus_on,
            revert_wrong_cube=env.revert_wrong_cube,
            wrong_cube_reward=env.wrong_cube_reward,
            terminate_on_complete=env.terminate_on_complete,
        )
    if isinstance(task, ImageTaskConfig):
        from lagrseq.envs.image_completion import ImageCompletionEnv

        image = _expect(config.env, ImageEnvConfig, "env")
        return ImageCompletionEnv(
            target=task.target,
            scans=image.scans,
            bonus=image.bonus,
            goal_threshold=task.goal_threshold,
            goal_ends=image.goal_ends,
            block_wrong_flips=image.block_wrong_flips,
            guided_goal_threshold=image.guided_goal_threshold,
        )
    from lagrseq.envs.object_arrangement import ObjectArrangementEnv

    table = _expect(config.env, ArrangementEnvConfig, "env")
    arrangement = _expect(task, ArrangementTaskConfig, "task")
    return ObjectArrangementEnv(
        target=arrangement.target,
        horizon=table.horizon,
        bonus=table.bonus,
        goal_threshold=arrangement.goal_threshold,
    )


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
    section = _expect(config.primary, TabularConfig, "primary")
    return TabularPrimary(section, _expect(task, cube.CubeStacking, "task"))


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
            return NeuralSeq(section, _expect(task, grid.GridTask, "task").cells, seed, trial)
        return TabularSeq(section.learning_rate)

    return make_policy(section, seq_agent)


def make_arm_env(config: ExperimentConfig, render_dir: Path | None = None) -> Any:
    """The arm-arrangement env with its robot (``env.robot``: sim or remote:HOST:PORT)."""
    import gymnasium as gym

    from lagrseq.envs.arm_arrangement import ArmArrangementEnv

    section = _expect(config.env, ArmEnvConfig, "env")
    task = _expect(config.task, ArmTaskConfig, "task")
    try:
        env = ArmArrangementEnv(
            target=task.target,
            horizon=section.horizon,
            bonus=section.bonus,
            goal_threshold=task.goal_threshold,
            robot=section.robot,
            robot_timeout_s=section.robot_timeout_s,
            robot_token_file=section.robot_token_file,
            robot_tls_ca=section.robot_tls_ca,
            render_size=(section.view_width, section.view_width * 3 // 4),
        )
    except (ImportError, gym.error.DependencyNotInstalled) as exc:
        raise UsageError(f"arm-arrangement: {exc}") from None
    if render_dir is not None:
        from lagrseq.robot.render import EpisodeRenderer

        EpisodeRenderer(env, Path(render_dir)).attach()
    return env


def missing_dependency(config: ExperimentConfig) -> str:
    """Why ``config`` cannot run with the installed extras ("" when it can): the DQN agents of
    the grid tasks need torch (the ``dqn`` extra), the simulated arm pybullet and airo-models
    (the ``arm`` extra), a remote arm grpcio (also the ``arm`` extra)."""
    import importlib.util

    if isinstance(config.env, ArmEnvConfig):
        wanted = ("pybullet", "airo_models") if config.env.robot == "sim" else ("grpc", "google.protobuf")
        absent = [name for name in wanted if importlib.util.find_spec(name.split(".")[0]) is None]
        if absent:
            return f"needs the arm extra ({', '.join(absent)} not installed): pip install 'lagrseq[arm]' (Python <= 3.11)"

    needs_torch = config.primary.kind == "dqn" or (
        config.method == "lagr-seq" and config.secondary.kind == "neural" and config.secondary.policy == "seq"
    )
    if needs_torch and importlib.util.find_spec("torch") is None:
        return "needs torch, which is not installed (pip install 'lagrseq[dqn]')"
    return ""


# Picture views of the state per task: (topic, message builder, view_topics flag).
VIEWS: dict[str, tuple[str, Callable[[Any, int], dict[str, Any]], str]] = {
    "image-completion": (foxglove.IMAGE_TOPIC, foxglove.raw_image, "image"),
    "object-arrangement": (foxglove.GRID_TOPIC, foxglove.grid, "grid"),
}


VIEWS["arm-arrangement"] = (foxglove.GRID_TOPIC, foxglove.grid, "grid")


def view_topics(config: ExperimentConfig) -> dict[str, tuple[str, str, bytes]] | None:
    """The picture topics of ``config``'s task for the sink (None: the task has none)."""
    view = VIEWS.get(config.task.name)
    topics = foxglove.view_topics(**{view[2]: True}) if view else None
    if topics is not None and isinstance(config.env, ArmEnvConfig):
        topics.update(foxglove.arm_topics())
    return topics


def robot_views(config: ExperimentConfig, env: Any) -> Callable[[dict[str, Any], int], list[View]] | None:
    """Arm tasks: after every step the arm's joint state, and every ``env.view_every`` steps a
    camera frame (PNG), both read from the env's robot."""
    section = config.env
    if not isinstance(section, ArmEnvConfig):
        return None
    robot = env.unwrapped.robot
    every = section.view_every

    def views(info: dict[str, Any], global_step: int) -> list[View]:
        state = robot.joint_state()
        out = [View(foxglove.JOINTS_TOPIC, foxglove.joint_state(state.names, state.positions, global_step), global_step)]
        if every and global_step % every == 0:
            picture = env.unwrapped.render_png()
            if picture is not None:
                out.append(View(foxglove.ARM_TOPIC, foxglove.compressed_image(picture, global_step), global_step))
        return out

    return views


def _view(config: ExperimentConfig) -> Callable[[Any, int], View] | None:
    view = VIEWS.get(config.task.name)
    if view is None:
        return None
    topic, picture, _ = view
    return lambda pattern, global_step: View(topic, picture(pattern, global_step), global_step)


def trial_parts(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    open_sink: Callable[[], Sink],
    provider_options: ProviderOptions | None = None,
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
        view=_view(config),
        robot_views=robot_views(config, env),
        placements=isinstance(config.env, ArmEnvConfig),
    )
