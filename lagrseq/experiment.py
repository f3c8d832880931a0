"""The LaGR-SEQ loop (Algorithm 1 of the paper) and the wiring of concrete parts.

``run_trial`` is the algorithm, top to bottom: for every step, while no accepted LLM solution is
held, the secondary agent may query the LLM (LaGR-SEQ) from the current state; once a solution is
accepted, the primary agent follows pi_LLM (with probability P) from the next step on. Every
transition, every secondary decision and every episode goes to the trial's MCAP file.

Everything concrete (which env, agent, provider) is chosen here and nowhere else.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import multiprocessing
import platform
import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Protocol, TypeVar

import numpy as np

from lagrseq import __version__, seeding
from lagrseq.agents.schedules import EpsilonSchedule
from lagrseq.agents.tabular import TabularQ
from lagrseq.config import (
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
from lagrseq.lagr import QueryTrigger, consult, follows, query_for
from lagrseq.llm.base import Provider, Query
from lagrseq.llm.mock import MockProvider
from lagrseq.llm.servers import DEFAULT_BASE_URL
from lagrseq.logs import foxglove
from lagrseq.logs.reader import find_logs, is_complete, read_info, read_topic
from lagrseq.logs.schemas import ACCURACY_METHOD
from lagrseq.logs.sink import McapSink
from lagrseq.seeding import Stream
from lagrseq.seq import TabularSecondary, query_reward
from lagrseq.tasks import cube, grid
from lagrseq.tasks.arrangement import object_arrangement
from lagrseq.tasks.base import Task
from lagrseq.tasks.image import image_completion

PROVIDER_KINDS = ("mock", "recorded", "live")
ON_MISS = ("error", "mock", "live")


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
    """recorded:STORE only: what answers a query the store lacks (error | mock | live)."""
    price_table: str | None = None
    """TOML file of prices over the built-in table."""
    max_cost_usd: float | None = None
    """Per trial (live answers): stop before a request that could pass this many US dollars."""
    max_queries: int | None = None
    """Per trial (live answers): stop before a request that would pass this many answers."""

    def __post_init__(self) -> None:
        if self.on_miss not in ON_MISS:
            raise UsageError(f"--on-miss {self.on_miss!r}; expected one of {', '.join(ON_MISS)}")

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)


# ------------------------------------------------------------------------------------------
# Results
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrialResult:
    """What a finished trial reports back (the MCAP file holds everything else)."""

    path: Path
    trial: int
    episodes: int
    steps: int
    queries: int
    total_return: float
    seconds: float
    skipped: bool = False


# ------------------------------------------------------------------------------------------
# Algorithm 1
# ------------------------------------------------------------------------------------------
def run_trial(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    path: Path,
    log: bool = True,
    on_episode: Callable[[int], None] | None = None,
    provider_options: ProviderOptions | None = None,
) -> TrialResult:
    """Run one trial and log it to ``path`` (``log=False`` runs without writing, for benchmarks).
    ``on_episode(length)`` is called after every episode with its number of steps."""
    started = time.perf_counter()
    config = with_provider_model(config, provider_spec)  # live:MODEL asks MODEL, and the log says so
    task = make_task(config)
    env = make_env(config)
    primary = make_primary(config, task, env, seed, trial)
    secondary = make_secondary(config, task, seed, trial) if config.method == "lagr-seq" else None
    provider = make_provider(
        provider_spec, config, seeding.generator(seed, trial, Stream.LLM), provider_options
    )
    primary_rng = seeding.generator(seed, trial, Stream.PRIMARY)
    secondary_rng = seeding.generator(seed, trial, Stream.SECONDARY)
    guidance_rng = seeding.generator(seed, trial, Stream.GUIDANCE)
    primary_epsilon = _schedule(config.primary, config.run)
    secondary_epsilon = _schedule(config.secondary, config.run)
    trigger = QueryTrigger(config.lagr.trigger)
    lagr = config.lagr
    asks_llm = config.method != "baseline"
    view = VIEWS.get(config.task.name)  # a picture of the state, so the run opens in Foxglove
    sink = (
        McapSink(
            path,
            run_metadata(config, trial, seed, provider_spec, provider_options),
            extra_topics=foxglove.view_topics(**{view[2]: True}) if view else None,
        )
        if log
        else _NullSink()
    )

    global_step = 0
    total_queries = 0
    total_return = 0.0
    episodes_run = 0
    solution: Any = None  # the accepted LLM solution (pi_LLM), None while there is none
    with sink, provider:
        for episode in itertools.count():
            if config.run.episodes and episode >= config.run.episodes:
                break
            if config.run.max_steps and global_step >= config.run.max_steps:
                break
            observation, info = env.reset(
                seed=seeding.integer_seed(seed, trial, Stream.ENV) if episode == 0 else None
            )
            if lagr.solution_scope == "episode":
                solution = None
            trigger.reset_episode()
            last_reward = 0.0
            episode_return = 0.0
            queries = accepted = guided_steps = 0
            solved = task.is_complete(info["pattern"])
            step = 0
            while True:
                pattern = info["pattern"]
                following = solution  # a solution accepted at this step guides from the next one
                # Exploration per episode (cube) or per step (grid DQNs); /episode logs the last.
                epsilon = primary_epsilon.at(episode, global_step)
                epsilon2 = secondary_epsilon.at(episode, global_step)

                # SEQ + LaGR: from the current state, maybe query the LLM.
                if asks_llm and solution is None and trigger.armed(task.progress(pattern), last_reward):
                    if secondary is None:
                        decision = 1  # LaGR without SEQ: query whenever triggered
                    else:
                        decision = secondary.decide(pattern, epsilon2, secondary_rng)
                    record = _decision_record(trial, episode, step, global_step, pattern, decision)
                    if decision == 1:
                        result = consult(task, provider, config.llm, lagr.threshold, pattern)
                        trigger.queried(task.progress(pattern))
                        reward2 = query_reward(result.evaluation, result.accepted, config.secondary)
                        queries += 1
                        if result.accepted:
                            accepted += 1
                            solution = result.parsed.solution
                        record.update(_query_fields(result, provider, config, reward2))
                    else:
                        reward2 = 0.0  # not querying earns the neutral reward
                    if secondary is not None:
                        secondary.update(secondary.key(pattern), decision, reward2)
                    sink.write("/query", record, global_step)

                # Act: follow pi_LLM once a solution is held, else the primary agent's policy.
                action = None
                if following is not None and follows(lagr, guidance_rng):
                    # The released grid code's pi_LLM picks its own cell (the solution's next
                    # missing one) instead of the scanned or drawn cell.
                    cell = task.guided_cell(pattern, following, info.get("cursor"))
                    if cell is not None:
                        observation, info = env.steer(cell)
                    action = task.guidance(pattern, following, info.get("cursor"))
                guided = action is not None
                if action is None:
                    action = primary.act(observation, info, epsilon, primary_rng)

                next_observation, reward, terminated, truncated, next_info = env.step(action)

                # Learn: the primary agent is not updated on guided steps in the released cube code.
                if not guided or lagr.update_primary_while_guided:
                    primary.learn(
                        observation, info, action, reward, next_observation, next_info, terminated
                    )

                sink.write(
                    "/transition",
                    {
                        "trial": trial,
                        "episode": episode,
                        "step": step,
                        "global_step": global_step,
                        "state": _jsonable(pattern),
                        "action": int(action),
                        "reward": float(reward),
                        "terminated": bool(terminated),
                        "truncated": bool(truncated),
                        "guided": guided,
                    },
                    global_step,
                )
                if view is not None:
                    topic, picture, _ = view
                    sink.write(topic, picture(next_info["pattern"], global_step), global_step)
                episode_return += reward
                guided_steps += guided
                last_reward = reward
                solved = solved or task.is_complete(next_info["pattern"])
                observation, info = next_observation, next_info
                step += 1
                global_step += 1
                if terminated or truncated:
                    break
                if config.run.max_steps and global_step >= config.run.max_steps:
                    break

            sink.write(
                "/episode",
                {
                    "trial": trial,
                    "episode": episode,
                    "return": float(episode_return),
                    "length": step,
                    "queries": queries,
                    "accepted": accepted,
                    "epsilon": float(epsilon),
                    "solved": bool(solved),
                    "guided_steps": guided_steps,
                    "global_step": global_step,
                },
                max(global_step - 1, 0),
            )
            sink.flush()
            total_queries += queries
            total_return += episode_return
            episodes_run += 1
            if on_episode is not None:
                on_episode(step)
    env.close()
    return TrialResult(
        path=path,
        trial=trial,
        episodes=episodes_run,
        steps=global_step,
        queries=total_queries,
        total_return=total_return,
        seconds=time.perf_counter() - started,
    )


# Picture views of the state per task: (topic, message builder, view_topics flag).
VIEWS: dict[str, tuple[str, Callable[[Any, int], dict[str, Any]], str]] = {
    "image-completion": (foxglove.IMAGE_TOPIC, foxglove.raw_image, "image"),
    "object-arrangement": (foxglove.GRID_TOPIC, foxglove.grid, "grid"),
}


def _decision_record(
    trial: int, episode: int, step: int, global_step: int, pattern: Any, decision: int
) -> dict[str, Any]:
    return {
        "trial": trial,
        "episode": episode,
        "step": step,
        "global_step": global_step,
        "state": _jsonable(pattern),
        "decision": int(decision),
        "queried": False,
        "prompt_sha256": None,
        "answer": None,
        "solution": None,
        "parse_error": None,
        "evaluation": None,
        "accepted": None,
        "query_reward": 0.0,
        "provider": None,
        "model": None,
        "temperature": None,
        "prompt_tokens": None,
        "completion_tokens": None,
        "cost_usd": None,
        "latency_s": None,
        "source": None,
        "record_key": None,
        "sample_index": None,
        "finish_reason": None,
        "system_fingerprint": None,
    }


def _query_fields(result: Any, provider: Provider, config: ExperimentConfig, reward2: float) -> dict[str, Any]:
    answer = result.answer
    return {
        "queried": True,
        "prompt_sha256": result.prompt_sha256,
        "answer": answer.text,
        "solution": _jsonable(result.parsed.solution) if result.parsed.ok else None,
        "parse_error": result.parsed.error,
        "evaluation": result.evaluation,
        "accepted": result.accepted,
        "query_reward": float(reward2),
        "provider": provider.name,
        "model": answer.model,
        "temperature": config.llm.temperature,
        "prompt_tokens": answer.usage.prompt_tokens,
        "completion_tokens": answer.usage.completion_tokens,
        "cost_usd": answer.cost_usd,
        "latency_s": answer.latency_s,
        "source": answer.source,
        "record_key": answer.record_key,
        "sample_index": answer.sample_index,
        "finish_reason": answer.finish_reason,
        "system_fingerprint": answer.system_fingerprint,
    }


def _jsonable(pattern: Any) -> Any:
    """A pattern as JSON-ready data (a tuple of ints stays as it is: it encodes as a list)."""
    if pattern is None:
        return None
    if isinstance(pattern, np.ndarray):
        return pattern.tolist()
    if isinstance(pattern, tuple):
        return pattern
    return [int(x) for x in pattern]


class _NullSink:
    """Stands in for the MCAP sink when logging is off (benchmarks measure its cost)."""

    def write(self, topic: str, record: dict[str, Any], log_time: int) -> None:
        return None

    def flush(self) -> None:
        return None

    def __enter__(self) -> _NullSink:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


# ------------------------------------------------------------------------------------------
# Fig. 4: the LLM alone (no RL)
# ------------------------------------------------------------------------------------------
def run_accuracy_probe(
    config: ExperimentConfig,
    samples: int,
    seed: int,
    provider_spec: str,
    path: Path,
    log: bool = True,
) -> TrialResult:
    """Fig. 4: query the provider ``samples`` times with every prefix of the target (1/N to N/N
    of the sequence) and log each answer as a ``/query`` record (``fraction`` = prefix length /
    N); replay rebuilds the accuracy curves from these records alone."""
    started = time.perf_counter()
    task = make_task(config)
    if not isinstance(task, cube.CubeStacking):  # pragma: no cover - only cube tasks exist here
        raise UsageError(f"the accuracy probe needs a sequence task, not {config.task.name!r}")
    provider = make_provider(provider_spec, config, seeding.generator(seed, 0, Stream.LLM))
    metadata = {**run_metadata(config, 0, seed, provider_spec), "method": ACCURACY_METHOD}
    metadata["samples"] = str(samples)
    sink = McapSink(path, metadata) if log else _NullSink()
    target = task.target
    index = 0
    with sink, provider:
        for length in range(1, len(target) + 1):
            prefix = tuple(target[:length])
            for sample in range(samples):
                result = consult(task, provider, config.llm, config.lagr.threshold, prefix)
                record = _decision_record(0, 0, sample, index, prefix, 1)
                record.update(_query_fields(result, provider, config, 0.0))
                record["prefix_length"] = length
                record["fraction"] = length / len(target)
                sink.write("/query", record, index)
                index += 1
            sink.flush()  # one chunk per prefix: a crash keeps every finished prefix
    return TrialResult(path, 0, 0, 0, index, 0.0, time.perf_counter() - started)


def probe_path(out: Path, config: ExperimentConfig, provider_spec: str, seed: int, samples: int) -> Path:
    """``OUT/<task>/llm-accuracy/<preset>-<provider>-seed<S>-<digest>/samples-<K>.mcap``."""
    name = f"{config.preset}-{provider_slug(provider_spec)}-seed{seed}-{config.digest()}"
    return out / config.task.name / ACCURACY_METHOD / name / f"samples-{samples:04d}.mcap"


# ------------------------------------------------------------------------------------------
# Wiring: the only place that knows concrete tasks, envs, agents and providers
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
    raise UsageError(f"unknown task {task.name!r}")  # pragma: no cover


def _make_grid_env(config: ExperimentConfig) -> Any:
    from lagrseq.envs.image_completion import ImageCompletionEnv
    from lagrseq.envs.object_arrangement import ObjectArrangementEnv

    task = config.task
    if isinstance(task, ImageTaskConfig):
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
    table = _expect(config.env, ArrangementEnvConfig, "env")
    arrangement = _expect(task, ArrangementTaskConfig, "task")
    return ObjectArrangementEnv(
        target=arrangement.target,
        horizon=table.horizon,
        bonus=table.bonus,
        goal_threshold=arrangement.goal_threshold,
    )


def make_env(config: ExperimentConfig) -> Any:
    if not isinstance(config.task, CubeTaskConfig):
        return _make_grid_env(config)
    from lagrseq.envs.cube_stacking import CubeStackingEnv

    env = _expect(config.env, CubeEnvConfig, "env")
    return CubeStackingEnv(
        stack_size=config.task.stack_size,
        horizon=env.horizon,
        bonus=env.bonus,
        bonus_on=env.bonus_on,
        revert_wrong_cube=env.revert_wrong_cube,
        wrong_cube_reward=env.wrong_cube_reward,
        terminate_on_complete=env.terminate_on_complete,
    )


def _schedule(section: Any, run: RunConfig) -> EpsilonSchedule:
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


class PrimaryAgent(Protocol):
    """What the loop asks of a primary agent."""

    def act(self, observation: Any, info: dict[str, Any], epsilon: float, rng: np.random.Generator) -> int: ...

    def learn(
        self,
        observation: Any,
        info: dict[str, Any],
        action: int,
        reward: float,
        next_observation: Any,
        next_info: dict[str, Any],
        terminated: bool,
    ) -> None: ...


class SecondaryAgent(Protocol):
    """What the loop asks of a secondary (SEQ) agent."""

    def key(self, pattern: Any) -> Any: ...

    def decide(self, pattern: Any, epsilon: float, rng: np.random.Generator) -> int: ...

    def update(self, key: Any, decision: int, reward: float) -> None: ...


class TabularPrimary:
    """Tabular Q-learning on the task's patterns, with the configured state index."""

    def __init__(self, config: ExperimentConfig, task: cube.CubeStacking) -> None:
        section = _expect(config.primary, TabularConfig, "primary")
        self.agent = TabularQ(task.n_actions, section.learning_rate, section.discount)
        self.invalid = section.invalid_actions
        self.pre_revert = section.bootstrap_from == "pre-revert"
        if section.state_index == "upstream-aliased":
            target = task.target
            self.key: Callable[[Any], Hashable] = lambda p: cube.upstream_state_key(p, target)
        else:
            self.key = tuple

    def act(self, observation: Any, info: dict[str, Any], epsilon: float, rng: np.random.Generator) -> int:
        return self.agent.act(self.key(info["pattern"]), epsilon, rng, info["action_mask"], self.invalid)

    def learn(
        self,
        observation: Any,
        info: dict[str, Any],
        action: int,
        reward: float,
        next_observation: Any,
        next_info: dict[str, Any],
        terminated: bool,
    ) -> None:
        following = next_info["pre_revert_pattern"] if self.pre_revert else next_info["pattern"]
        self.agent.update(self.key(info["pattern"]), action, reward, self.key(following), terminated)


class TabularSeq(TabularSecondary):
    """The tabular SEQ agent keyed by the pattern."""

    @staticmethod
    def key(pattern: Any) -> Hashable:
        return tuple(pattern)

    def decide(self, pattern: Any, epsilon: float, rng: np.random.Generator) -> int:  # type: ignore[override]
        return super().decide(self.key(pattern), epsilon, rng)


# The primary and secondary networks each get their own part of the TORCH and REPLAY streams.
PRIMARY_PART, SECONDARY_PART = 0, 1


class DQNPrimary:
    """A DQN on the environment's observation vector (grid tasks; torch is imported here)."""

    def __init__(self, section: DQNConfig, env: Any, seed: int, trial: int) -> None:
        from lagrseq.agents.dqn import DQN

        space = env.observation_space
        normalise = section.normalise_observations
        self.agent = DQN(
            observation_size=int(space.shape[0]),
            n_actions=int(env.action_space.n),
            hidden_sizes=section.hidden_sizes,
            learning_rate=section.learning_rate,
            discount=section.discount,
            batch_size=section.batch_size,
            buffer_size=section.buffer_size,
            target_update_interval=section.target_update_interval,
            seed=seeding.integer_seed(seed, trial, Stream.TORCH, PRIMARY_PART),
            device=section.device,
            observation_low=space.low if normalise else None,
            observation_high=space.high if normalise else None,
            cpu_threads=section.cpu_threads,
        )
        self.replay_rng = seeding.generator(seed, trial, Stream.REPLAY, PRIMARY_PART)

    def act(self, observation: Any, info: dict[str, Any], epsilon: float, rng: np.random.Generator) -> int:
        return self.agent.act(observation, epsilon, rng)

    def learn(
        self,
        observation: Any,
        info: dict[str, Any],
        action: int,
        reward: float,
        next_observation: Any,
        next_info: dict[str, Any],
        terminated: bool,
    ) -> None:
        # Bootstrap from the real next observation (the released code's can be stale, SPEC 7.15),
        # then one optimiser step per environment step.
        self.agent.remember(observation, action, reward, next_observation, terminated)
        self.agent.train_step(self.replay_rng)


class NeuralSeq:
    """The neural SEQ bandit on the flattened grid: Q2(s) = [skip, query], fitted to r2."""

    def __init__(self, section: NeuralSecondaryConfig, cells: int, seed: int, trial: int) -> None:
        from lagrseq.agents.dqn import DQN

        self.agent = DQN(
            observation_size=cells,
            n_actions=2,
            hidden_sizes=section.hidden_sizes,
            learning_rate=section.learning_rate,
            discount=0.0,  # a bandit: every decision ends
            batch_size=section.batch_size,
            buffer_size=section.buffer_size,
            target_update_interval=0,
            seed=seeding.integer_seed(seed, trial, Stream.TORCH, SECONDARY_PART),
            device=section.device,
        )
        self.replay_rng = seeding.generator(seed, trial, Stream.REPLAY, SECONDARY_PART)

    @staticmethod
    def key(pattern: Any) -> np.ndarray:
        return np.asarray(pattern, dtype=np.float32).ravel()

    def decide(self, pattern: Any, epsilon: float, rng: np.random.Generator) -> int:
        """epsilon-greedy over {0: skip, 1: query}; ties choose 0."""
        return self.agent.act(self.key(pattern), epsilon, rng)

    def update(self, key: Any, decision: int, reward: float) -> None:
        self.agent.remember(key, decision, reward, key, True)
        self.agent.train_step(self.replay_rng)


def make_primary(config: ExperimentConfig, task: Task, env: Any, seed: int, trial: int) -> PrimaryAgent:
    if isinstance(config.primary, DQNConfig):
        return DQNPrimary(config.primary, env, seed, trial)
    return TabularPrimary(config, task)  # type: ignore[arg-type]


def make_secondary(config: ExperimentConfig, task: Task, seed: int, trial: int) -> SecondaryAgent:
    section = config.secondary
    if isinstance(section, NeuralSecondaryConfig):
        grid_task = _expect(task, grid.GridTask, "task")
        return NeuralSeq(section, grid_task.cells, seed, trial)
    return TabularSeq(section.learning_rate)


def mock_profiles() -> tuple[str, ...]:
    """Names accepted by ``--provider mock:PROFILE``."""
    return tuple(cube.PROFILES)


def parse_provider(spec: str) -> tuple[str, str]:
    """Split ``kind[:argument]`` and check it: ``mock``, ``mock:PROFILE``, ``recorded:STORE``,
    ``live`` or ``live:MODEL``."""
    kind, _, argument = spec.partition(":")
    if kind not in PROVIDER_KINDS:
        raise UsageError(
            f"unknown provider {spec!r}; expected mock, mock:PROFILE, recorded:STORE, live or live:MODEL"
        )
    if kind == "mock" and argument and argument not in mock_profiles():
        raise UsageError(
            f"unknown mock profile {argument!r}; expected one of: {', '.join(mock_profiles())}"
        )
    if kind == "recorded" and not argument:
        raise UsageError("provider 'recorded' needs a store: recorded:STORE (a directory)")
    return kind, argument


def with_provider_model(config: ExperimentConfig, spec: str) -> ExperimentConfig:
    """``live:MODEL`` asks MODEL: the configuration (and so every log) says so."""
    kind, argument = parse_provider(spec)
    if kind == "live" and argument and argument != config.llm.model:
        return replace(config, llm=replace(config.llm, model=argument))
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

    kind, argument = parse_provider(spec)
    options = options or ProviderOptions()
    if kind == "mock":
        return MockProvider(extrapolator(config, argument or "ideal"), rng, name=spec)
    if kind == "live":
        return make_live(options, rng, budgeted=True)
    store = RecordStore(argument, create=options.on_miss == "live")
    endpoint = endpoint_of(options.base_url)
    run_seed = int(rng.integers(2**63))
    if options.on_miss == "live":
        # A miss is asked live and recorded (one sample), so the next run finds it.
        return RecordingProvider(store, make_live(options, rng, budgeted=True), endpoint, "new", 1, run_seed)
    fallback = MockProvider(extrapolator(config), rng, name="mock") if options.on_miss == "mock" else None
    return RecordedProvider(store, endpoint, run_seed, fallback)


def missing_dependency(config: ExperimentConfig) -> str:
    """Why ``config`` cannot run with the installed extras ("" when it can): the DQN agents of
    the grid tasks need torch (the ``dqn`` extra)."""
    import importlib.util

    needs_torch = config.primary.kind == "dqn" or (
        config.method == "lagr-seq" and config.secondary.kind == "neural"
    )
    if needs_torch and importlib.util.find_spec("torch") is None:
        return "needs torch, which is not installed (pip install 'lagrseq[dqn]')"
    return ""


def check_provider(spec: str, config: ExperimentConfig, options: ProviderOptions | None = None) -> None:
    """Build the provider once and close it, so that a missing API key or store fails before any
    trial starts (nothing is sent)."""
    make_provider(spec, config, np.random.default_rng(0), options).close()


def make_live(
    options: ProviderOptions,
    rng: np.random.Generator,
    budgeted: bool = False,
    on_retry: Callable[[str], None] | None = None,
) -> Any:
    """The live provider of ``options``, behind a budget guard when asked (one budget per call)."""
    from lagrseq.llm.budget import Budget, BudgetedProvider
    from lagrseq.llm.live import LiveProvider, LiveSettings

    prices = load_prices(options.price_table)
    settings = LiveSettings(base_url=options.base_url, api_key_env=options.api_key_env, server=options.server)
    live = LiveProvider(settings, rng=rng, prices=prices, on_retry=on_retry)
    if not budgeted:
        return live
    return BudgetedProvider(live, Budget(options.max_cost_usd, options.max_queries), prices)


def load_prices(price_table: str | Path | None) -> Any:
    """The built-in price table, with ``price_table`` (a TOML file) over it."""
    from lagrseq.llm.pricing import PriceTable, read_price_table

    return read_price_table(price_table) if price_table else PriceTable()


def extrapolator(
    config: ExperimentConfig, profile: str = "ideal"
) -> Callable[[str, float, np.random.Generator], str]:
    """What the mock provider answers with: the task's rule-based extrapolator (``ideal``) or a
    calibrated profile of it (``cube.PROFILES``). The mock itself stays task-free."""
    task = make_task(config)
    if isinstance(task, cube.CubeStacking):
        return cube.profile_extrapolator(task, profile)
    if profile != "ideal":
        raise UsageError(
            f"mock profile {profile!r} is calibrated for cube stacking only; "
            f"{config.task.name} has the ideal mock (--provider mock)"
        )
    return grid.extrapolate


# ------------------------------------------------------------------------------------------
# Recording: which prompts to ask, and how outside data becomes a task's pattern
# ------------------------------------------------------------------------------------------
def pattern_from(task: Task, value: Any) -> Any:
    """A task pattern from outside data (an authors' cache key, an MCAP ``state``); raises
    ValueError when it does not fit the task. Tasks check shapes with ``coerce_pattern``."""
    coerce = getattr(task, "coerce_pattern", None)
    if coerce is not None:
        return coerce(value)
    array = np.asarray(value)
    return array if array.ndim > 1 else tuple(int(x) for x in array)


def prompt_function(config: ExperimentConfig) -> Callable[[Any], str]:
    """``prompt_for(key)``: the prompt a run sends for an outside pattern (authors' cache import)."""
    task = make_task(config)
    return lambda key: query_for(task, config.llm, pattern_from(task, key)).prompt


def record_patterns(
    config: ExperimentConfig, runs: Sequence[str | Path] = (), topic: str = "/query"
) -> list[Any]:
    """The patterns ``lagrseq record`` asks about, without duplicates, in first-met order: the
    states of ``topic`` records in the MCAP logs under ``runs`` (``/query``: where the secondary
    agent decided; ``/transition``: every state met), or, with no runs, every prefix of a cube
    target."""
    task = make_task(config)
    if not runs:
        if isinstance(task, cube.CubeStacking):
            return list(task.prefixes())
        raise UsageError(
            f"{config.task.name} has no default set of prompts; give runs with --from-runs"
        )
    if topic not in ("/query", "/transition"):
        raise UsageError(f"--states-from {topic!r}; expected /query or /transition")
    patterns: list[Any] = []
    seen: set[str] = set()
    for path in find_logs(runs):
        logged = read_info(path).config
        logged_task = logged.get("task", {})
        wanted = json.loads(json.dumps(asdict(config.task)))
        if logged_task != wanted:
            raise UsageError(
                f"{path}: a run of task {logged_task}, not {wanted}; pass matching runs or --set task fields"
            )
        for record in read_topic(path, topic):
            state = record.get("state")
            marker = json.dumps(state)
            if state is None or marker in seen:
                continue
            seen.add(marker)
            try:
                patterns.append(pattern_from(task, state))
            except ValueError as exc:
                raise UsageError(f"{path}: state {marker[:60]} does not fit the task: {exc}") from None
    if not patterns:
        raise UsageError(f"no {topic} states in {', '.join(map(str, runs))}")
    return patterns


def record_queries(config: ExperimentConfig, patterns: Sequence[Any]) -> list[Query]:
    """The queries a run of ``config`` would send from ``patterns`` (same key, same prompt)."""
    task = make_task(config)
    return [query_for(task, config.llm, pattern) for pattern in patterns]


# ------------------------------------------------------------------------------------------
# Runs: several trials, resumable, optionally in parallel
# ------------------------------------------------------------------------------------------
def run_metadata(
    config: ExperimentConfig,
    trial: int,
    seed: int,
    provider_spec: str,
    provider_options: ProviderOptions | None = None,
) -> dict[str, str]:
    """The ``lagrseq.run`` metadata record: everything replay needs to know about the trial."""
    return {
        "provider_options": (provider_options or ProviderOptions()).to_json(),
        "config": config.to_json(),
        "task": config.task.name,
        "method": config.method,
        "preset": config.preset,
        "provider": provider_spec,
        "seed": str(seed),
        "trial": str(trial),
        "lagrseq_version": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def provider_slug(spec: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in spec)


def run_directory(out: Path, config: ExperimentConfig, provider_spec: str, seed: int, name: str | None = None) -> Path:
    """``OUT/<task>/<method>/<name>``; the default name tells preset, provider, seed and a digest
    of the whole configuration, so runs that differ in any field never share a directory."""
    if name is None:
        name = f"{config.preset}-{provider_slug(provider_spec)}-seed{seed}-{config.digest()}"
    return out / config.task.name / config.method / name


def trial_path(directory: Path, trial: int) -> Path:
    return directory / f"trial-{trial:03d}.mcap"


def _run_trial_job(args: tuple[Any, ...]) -> TrialResult:
    config_dict, trial, seed, provider_spec, path, options = args
    from lagrseq.config import from_dict

    return run_trial(
        from_dict(config_dict), trial, seed, provider_spec, Path(path), provider_options=options
    )


def process_pool(jobs: int) -> ProcessPoolExecutor:
    """A pool of ``jobs`` worker processes, spawned rather than forked: forking a process that
    runs threads (the progress bar's, torch's) can deadlock."""
    return ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"))


def progress_unit(config: ExperimentConfig) -> tuple[str, int]:
    """What a progress bar counts for ``config`` and how many per trial: environment steps when the
    trial has a step budget (grid tasks), else episodes."""
    if config.run.max_steps:
        return "step", config.run.max_steps
    return "ep", config.run.episodes


def run_trials(
    config: ExperimentConfig,
    trials: int,
    seed: int,
    provider_spec: str,
    directory: Path,
    jobs: int = 1,
    progress: Any = None,
    provider_options: ProviderOptions | None = None,
    pool: Executor | None = None,
) -> list[TrialResult]:
    """Run trials 0..trials-1 into ``directory``; trials whose log is complete are skipped.
    ``pool``: an executor to reuse (``lagrseq reproduce`` keeps one warm for the whole suite)."""
    parse_provider(provider_spec)
    unit, per_trial = progress_unit(config)
    results: list[TrialResult] = []
    todo: list[int] = []
    for trial in range(trials):
        path = trial_path(directory, trial)
        if is_complete(path):
            results.append(TrialResult(path, trial, 0, 0, 0, 0.0, 0.0, skipped=True))
            if progress is not None:
                progress.update(per_trial)
        else:
            todo.append(trial)
    if pool is None and (jobs <= 1 or len(todo) <= 1):
        for trial in todo:
            results.append(
                run_trial(
                    config,
                    trial,
                    seed,
                    provider_spec,
                    trial_path(directory, trial),
                    on_episode=(
                        (lambda steps: progress.update(steps if unit == "step" else 1))
                        if progress is not None
                        else None
                    ),
                    provider_options=provider_options,
                )
            )
    else:
        with contextlib.ExitStack() as stack:
            if pool is None:
                pool = stack.enter_context(process_pool(jobs))
            futures = [
                pool.submit(
                    _run_trial_job,
                    (
                        config.to_dict(),
                        trial,
                        seed,
                        provider_spec,
                        str(trial_path(directory, trial)),
                        provider_options,
                    ),
                )
                for trial in todo
            ]
            for future in as_completed(futures):
                result = future.result()
                results.append(result)
                if progress is not None:
                    progress.update(per_trial)
    return sorted(results, key=lambda r: r.trial)


def with_episodes(config: ExperimentConfig, episodes: int) -> ExperimentConfig:
    """A copy of ``config`` with another episode count."""
    return replace(config, run=replace(config.run, episodes=episodes))
