"""The LaGR-SEQ loop: Algorithm 1 of the paper, one trial, top to bottom.

For every step: while no accepted LLM solution is held, the secondary agent may query the LLM
from the current state (SEQ + LaGR); once a solution is accepted, the primary agent follows pi_LLM
(with probability P) from the next step on; otherwise it acts on its own policy. Every transition,
every secondary decision and every episode goes to the sink.

The parts (env, task, agents, provider, sink, generators) are built by ``lagrseq.running.wiring``; this
module knows only their interfaces.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import msgspec
import numpy as np

from lagrseq.agents.schedules import EpsilonSchedule
from lagrseq.config import ExperimentConfig, LagrConfig, RunConfig
from lagrseq.llm.base import Provider
from lagrseq.logs.events import (
    EpisodeEvent,
    NotAsked,
    QueryEvent,
    Sink,
    Transition,
    View,
    jsonable,
    query_outcome,
)
from lagrseq.logs.task_fields import TaskFields, builtin_episode, builtin_step
from lagrseq.loop.adapters import PrimaryAgent, Step
from lagrseq.loop.lagr import Consultation, QueryTrigger, consult, follows
from lagrseq.loop.policies import AskContext, AskingPolicy
from lagrseq.loop.seq import query_reward
from lagrseq.tasks.base import EPISODE_LOG, STEP_LOG, Task


class Guided(NamedTuple):
    """pi_LLM's step: its action, and where it acts."""

    action: int
    """The action as the agents and the log see it (the task's guidance)."""
    env_action: int
    """The same action as ``env.step`` takes it: equal to ``action`` unless the env lets pi_LLM
    name where it acts in its action (the grid envs' cell actions)."""
    observation: Any
    """The observation it acts on (what the primary agent learns from on a guided step)."""
    info: dict[str, Any]


Guide = Callable[[Any, Any, dict[str, Any]], "Guided | None"]
"""pi_LLM: (the accepted solution, observation, info) -> its step, or None when it asks for
nothing (the primary agent acts)."""


def task_guide(task: Task) -> Guide:
    """pi_LLM acting wherever the environment is (``info["cursor"]``, if any): the task's
    ``guidance``. An env whose actions let pi_LLM name its own cell brings its own guide (the
    task's registered ``guide``)."""

    def guide(solution: Any, observation: Any, info: dict[str, Any]) -> Guided | None:
        action = task.guidance(info["pattern"], solution, info.get("cursor"))
        return None if action is None else Guided(action, action, observation, info)

    return guide


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
    sources: tuple[tuple[str, int], ...] = ()
    """Queries per answer source (``recorded``, ``mock``, ``live``), sorted: with
    ``recorded:STORE``, answers from another source are store misses a fallback answered."""


@dataclass(frozen=True)
class TrialParts:
    """Everything one trial runs on, built by ``lagrseq.running.wiring.trial_parts``."""

    config: ExperimentConfig
    trial: int
    task: Task
    env: Any
    primary: PrimaryAgent
    secondary: AskingPolicy | None
    """When to ask (``lagrseq.loop.policies``): the configured policy of ``lagr-seq``, ``Always`` for
    ``lagr``; None for ``baseline``, which never reaches a decision."""
    provider: Provider
    sink: Sink
    primary_epsilon: EpsilonSchedule
    secondary_epsilon: EpsilonSchedule
    env_seed: int
    primary_rng: np.random.Generator
    secondary_rng: np.random.Generator
    guidance_rng: np.random.Generator
    views: Callable[[dict[str, Any], int], list[View]] | None = None
    """The pictures after each step, from its info (the task's registered views: the state, so
    the run opens in Foxglove; an arm's camera and joints)."""
    guide: Guide | None = None
    """pi_LLM (None: :func:`task_guide`, the task's guidance where the env is)."""
    task_fields: TaskFields | None = None
    """The record types of a task that logs fields of its own (``TaskSpec.episode_fields``,
    ``step_fields``); None: lagrseq's records."""


@dataclass
class _Episode:
    """The counters of one episode (its ``/episode`` record)."""

    number: int
    solved: bool
    steady: bool = False
    """Whether epsilon stays what it is at the episode's start (a per-episode schedule)."""
    steps: int = 0
    queries: int = 0
    accepted: int = 0
    guided_steps: int = 0
    total: float = 0.0
    sources: dict[str, int] | None = None
    """Queries per answer source (set at the first query)."""
    epsilon: float = 0.0
    last_reward: float = 0.0
    ended_by_env: bool = False
    """Whether its last step terminated or truncated it (else the trial's step budget, or an
    early stop, ended it)."""


class _Records:
    """The trial's log records: lagrseq's, or those of a task that declares fields of its own,
    with what the env adds to them (``info[STEP_LOG]``: an arm's placement; ``info[EPISODE_LOG]``:
    what the env counted)."""

    def __init__(self, own: TaskFields | None) -> None:
        self._transition, self._step = (Transition, builtin_step) if own is None else (own.transition, own.step)
        self._episode = builtin_episode if own is None else own.episode_event

    def transition(self, fields: tuple[Any, ...], info: dict[str, Any]) -> Transition:
        extra = info.get(STEP_LOG)
        return self._transition(*fields) if extra is None else self._step(fields, extra)

    def episode(self, info: dict[str, Any], **summary: Any) -> EpisodeEvent:
        return self._episode(info.get(EPISODE_LOG), **summary)


class _Ending:
    """When a trial ends: after ``run.episodes`` episodes or ``run.max_steps`` steps (0: no
    limit); with ``run.stop_at = "first_solve"`` after its first solved episode; with
    ``"first_accepted"`` with the step of its first accepted answer."""

    def __init__(self, run: RunConfig) -> None:
        self.episodes, self.max_steps = run.episodes, run.max_steps
        self.at_solve, self.at_accepted = run.stop_at == "first_solve", run.stop_at == "first_accepted"

    def before_episode(self, number: int, global_step: int) -> bool:
        return bool(self.episodes and number >= self.episodes) or self.out_of_steps(global_step)

    def out_of_steps(self, global_step: int) -> bool:
        return bool(self.max_steps and global_step >= self.max_steps)

    def after_step(self, episode: _Episode, global_step: int) -> bool:
        return self.out_of_steps(global_step) or (self.at_accepted and episode.accepted > 0)

    def after_episode(self, episode: _Episode) -> bool:
        return (self.at_solve and episode.solved) or (self.at_accepted and episode.accepted > 0)


@dataclass
class _Trial:
    """What a trial carries from step to step and from episode to episode."""

    parts: TrialParts
    guide: Guide
    records: _Records
    ending: _Ending
    trigger: QueryTrigger
    lagr: LagrConfig
    sink: Sink
    asks: bool
    """Whether the method queries at all (``baseline`` never does)."""
    solution: Any = None
    """The accepted LLM solution (pi_LLM's); None while there is none."""
    global_step: int = 0
    episodes: int = 0
    queries: int = 0
    total_return: float = 0.0
    sources: dict[str, int] = field(default_factory=dict)

    @classmethod
    def of(cls, parts: TrialParts) -> _Trial:
        config = parts.config
        return cls(parts, parts.guide or task_guide(parts.task), _Records(parts.task_fields), _Ending(config.run),
                   QueryTrigger(config.lagr.trigger), config.lagr, parts.sink, config.method != "baseline")


def run_trial(parts: TrialParts, path: Path, on_episode: Callable[[int], None] | None = None) -> TrialResult:
    """Run one trial (Algorithm 1). ``on_episode(length)`` is called after every episode; the
    trial ends as :class:`_Ending` says."""
    started = time.perf_counter()
    trial = _Trial.of(parts)
    with parts.sink, parts.provider:
        for number in itertools.count():
            if trial.ending.before_episode(number, trial.global_step):
                break
            observation, info = parts.env.reset(seed=parts.env_seed if number == 0 else None)
            if trial.lagr.solution_scope == "episode":
                trial.solution = None  # the released cube code forgets the solution every episode
            trial.trigger.reset_episode()
            episode = _Episode(number, solved=parts.task.is_complete(info["pattern"]))
            # exploration per episode (cube: asked once here) or per step (grid DQNs, a warm-up)
            episode.steady = parts.primary_epsilon.steady_from(trial.global_step)
            episode.epsilon = parts.primary_epsilon.at(number, trial.global_step)
            ended = False
            while not ended:
                observation, info, ended = _step(trial, episode, observation, info)
            _end_episode(trial, episode, info)
            if on_episode is not None:
                on_episode(episode.steps)
            if trial.ending.after_episode(episode):
                break
    parts.env.close()
    return TrialResult(
        path, parts.trial, trial.episodes, trial.global_step, trial.queries, trial.total_return,
        time.perf_counter() - started, sources=tuple(sorted(trial.sources.items())),
    )


def _step(trial: _Trial, episode: _Episode, observation: Any, info: dict[str, Any]) -> tuple[Any, dict[str, Any], bool]:
    """One step of Algorithm 1: the secondary agent may query (while no solution is held);
    pi_LLM acts (with probability P) once a solution is held, else the primary agent; the
    primary agent learns; the transition goes to the sink. Returns the next observation and
    info, and whether the episode ended."""
    parts, task, primary = trial.parts, trial.parts.task, trial.parts.primary
    pattern = info["pattern"]
    following = trial.solution  # a solution accepted at this step guides from the next one
    if not episode.steady:
        episode.epsilon = parts.primary_epsilon.at(episode.number, trial.global_step)
    if trial.asks and following is None:
        progress = task.progress(pattern)
        if trial.trigger.armed(progress, episode.last_reward):
            trial.solution = _ask(parts, trial.trigger, episode, pattern, progress, trial.global_step,
                                  trial.queries + episode.queries)
    guided = None
    if following is not None and follows(trial.lagr, parts.guidance_rng):
        guided = trial.guide(following, observation, info)
    if guided is None:
        env_action = action = primary.act(observation, info, episode.epsilon, parts.primary_rng)
    else:
        env_action, action, observation, info = guided.env_action, guided.action, guided.observation, guided.info
    next_observation, reward, terminated, truncated, next_info = parts.env.step(env_action)
    if guided is None or trial.lagr.update_primary_while_guided:  # the released cube code: not on guided steps
        primary.learn(Step(observation, info, action, reward, next_observation, next_info, terminated))
    state = pattern if type(pattern) is tuple else jsonable(pattern)  # jsonable keeps a tuple as it is
    fields = (parts.trial, episode.number, episode.steps, trial.global_step, state, int(action), float(reward),
              bool(terminated), bool(truncated), guided is not None)
    trial.sink.write(trial.records.transition(fields, next_info))
    if parts.views is not None:  # the pictures after the step
        for view in parts.views(next_info, trial.global_step):
            trial.sink.write(view)
    episode.total += reward
    episode.guided_steps += guided is not None
    episode.last_reward = reward  # the paper's trigger: query only after a positive reward
    episode.solved = episode.solved or task.is_complete(next_info["pattern"])
    episode.steps += 1
    trial.global_step += 1
    episode.ended_by_env = bool(terminated or truncated)
    ended = episode.ended_by_env or trial.ending.after_step(episode, trial.global_step)
    return next_observation, next_info, ended


def _end_episode(trial: _Trial, episode: _Episode, info: dict[str, Any]) -> None:
    """The episode's ``/episode`` record (the sink keeps every finished episode from then on,
    through a Ctrl-C), and the trial's totals."""
    parts = trial.parts
    parts.sink.write(
        trial.records.episode(
            info, trial=parts.trial, episode=episode.number, return_=float(episode.total), length=episode.steps,
            queries=episode.queries, accepted=episode.accepted, epsilon=float(episode.epsilon),
            solved=bool(episode.solved), guided_steps=episode.guided_steps, global_step=trial.global_step,
            cut_by_step_budget=trial.ending.out_of_steps(trial.global_step) and not episode.ended_by_env,
        )
    )
    trial.episodes += 1
    trial.queries += episode.queries
    trial.total_return += episode.total
    for source, count in (episode.sources or {}).items():
        trial.sources[source] = trial.sources.get(source, 0) + count


def _ask(
    parts: TrialParts, trigger: QueryTrigger, episode: _Episode, pattern: Any, progress: int, global_step: int,
    queries: int,
) -> Any:
    """SEQ + LaGR from the current state: the asking policy decides; a query's answer is parsed,
    evaluated and, above the threshold, accepted. Returns the accepted solution or None.
    ``progress``: the task's progress of ``pattern``; ``queries``: the trial's queries so far."""
    config, task, provider = parts.config, parts.task, parts.provider
    policy = parts.secondary
    assert policy is not None  # baseline never asks
    context = AskContext(
        pattern=pattern, progress=progress, episode=episode.number, episode_step=episode.steps,
        global_step=global_step, epsilon=parts.secondary_epsilon.at(episode.number, global_step),
        rng=parts.secondary_rng, queries_trial=queries, queries_episode=episode.queries,
        peek=lambda: consult(task, provider, config.llm, config.lagr.threshold, pattern),
    )
    decision = policy.decide(context)
    state = pattern if type(pattern) is tuple else jsonable(pattern)  # jsonable keeps a tuple as it is
    if decision == 0:  # not querying earns the neutral reward
        policy.update(context, decision, 0.0)
        parts.sink.write(NotAsked(parts.trial, episode.number, episode.steps, global_step, state))
        return None
    event = QueryEvent(
        trial=parts.trial, episode=episode.number, step=episode.steps, global_step=global_step,
        state=state, decision=int(decision),
    )
    solution = None
    reward = 0.0
    if decision == 1:
        result = context.query()
        trigger.queried(progress)
        reward = query_reward(result.evaluation, result.accepted, config.secondary) - config.secondary.query_cost
        context.evaluation, context.accepted = result.evaluation, result.accepted
        episode.queries += 1
        if episode.sources is None:
            episode.sources = {}
        source = result.answer.source
        episode.sources[source] = episode.sources.get(source, 0) + 1
        if result.accepted:
            episode.accepted += 1
            solution = result.parsed.solution
        event = query_event(event, result, provider.name, config.llm.temperature, reward)
    policy.update(context, decision, reward)
    parts.sink.write(event)
    return solution


def query_event(event: QueryEvent, result: Consultation, provider: str, temperature: float, reward: float) -> QueryEvent:
    """A decision record completed with what the query sent and got back."""
    answer = result.answer
    return msgspec.structs.replace(
        event,
        queried=True,
        prompt_sha256=result.prompt_sha256,
        answer=answer.text,
        solution=jsonable(result.parsed.solution) if result.parsed.ok else None,
        parse_error=result.parsed.error,
        evaluation=result.evaluation,
        accepted=result.accepted,
        query_reward=float(reward),
        provider=provider,
        model=answer.model,
        temperature=temperature,
        prompt_tokens=None if answer.usage is None else answer.usage.prompt_tokens,
        completion_tokens=None if answer.usage is None else answer.usage.completion_tokens,
        cached_tokens=None if answer.usage is None else answer.usage.cached_tokens,
        cost_usd=answer.cost_usd,
        latency_s=answer.latency_s,
        source=answer.source,
        record_key=answer.record_key,
        sample_index=answer.sample_index,
        finish_reason=answer.finish_reason,
        system_fingerprint=answer.system_fingerprint,
        prompt=result.prompt,
        outcome=query_outcome(provider, answer.source),
    )
