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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import msgspec
import numpy as np

from lagrseq.agents.schedules import EpsilonSchedule
from lagrseq.config import ExperimentConfig
from lagrseq.llm.base import Provider
from lagrseq.logs.events import QueryEvent, Sink, Transition, View, jsonable, query_outcome
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
    steps: int = 0
    queries: int = 0
    accepted: int = 0
    guided_steps: int = 0
    total: float = 0.0
    sources: dict[str, int] | None = None
    """Queries per answer source (set at the first query)."""
    epsilon: float = 0.0
    last_reward: float = 0.0


def run_trial(parts: TrialParts, path: Path, on_episode: Callable[[int], None] | None = None) -> TrialResult:
    """Run one trial (Algorithm 1). ``on_episode(length)`` is called after every episode. The
    trial ends after ``run.episodes`` episodes or ``run.max_steps`` steps, or, with
    ``run.stop_at = "first_solve"``, after its first solved episode, or with ``"first_accepted"``,
    with the step of its first accepted answer."""
    started = time.perf_counter()
    config, task, env, sink = parts.config, parts.task, parts.env, parts.sink
    asks = config.method != "baseline"
    trigger = QueryTrigger(config.lagr.trigger)
    solution: Any = None  # the accepted LLM solution (pi_LLM); None while there is none
    global_step = episodes = queries = 0
    total_return = 0.0
    sources: dict[str, int] = {}
    # What a step calls, looked up once per trial (a trial is about 5,000 steps of a few us each).
    schedule, progress, armed, is_complete = parts.primary_epsilon, task.progress, trigger.armed, task.is_complete
    act, learn, step_env, write, views = parts.primary.act, parts.primary.learn, env.step, sink.write, parts.views
    # Without pictures between them, an episode's transitions go to the sink in one call at its
    # end (or where it stops early): a sink call a step was most of what logging cost a cube trial.
    # A task's own fields (declared by it) make its records subclasses of lagrseq's, checked.
    own = parts.task_fields
    record, step_record = (Transition, builtin_step) if own is None else (own.transition, own.step)
    episode_record = builtin_episode if own is None else own.episode_event
    held: list[Transition] = []
    hold: Callable[[Transition], None] = held.append if views is None else write
    guide = parts.guide or task_guide(task)
    lagr, guidance_rng, primary_rng, trial = config.lagr, parts.guidance_rng, parts.primary_rng, parts.trial
    learn_guided = lagr.update_primary_while_guided
    max_steps = config.run.max_steps
    stop_at_solve = config.run.stop_at == "first_solve"  # the trial ends with its first solved episode
    stop_at_first = config.run.stop_at == "first_accepted"  # the trial ends with the step of its first acceptance
    accepted_any = False
    with sink, parts.provider:
        for number in itertools.count():
            if _out_of_budget(config, number, global_step):
                break
            observation, info = env.reset(seed=parts.env_seed if number == 0 else None)
            if lagr.solution_scope == "episode":
                solution = None  # the released cube code forgets the solution every episode
            trigger.reset_episode()
            episode = _Episode(number, solved=task.is_complete(info["pattern"]))
            # Exploration per episode (cube: asked once here) or per step (grid DQNs, a warm-up);
            # /episode logs the last.
            steady = schedule.steady_from(global_step)
            epsilon = episode.epsilon = schedule.at(number, global_step)
            try:
                while True:
                    pattern = info["pattern"]
                    following = solution  # a solution accepted at this step guides from the next one
                    if not steady:
                        epsilon = episode.epsilon = schedule.at(number, global_step)
                    if asks and solution is None:
                        progressed = progress(pattern)
                        if armed(progressed, episode.last_reward):
                            solution = _ask(parts, trigger, episode, pattern, progressed, global_step, queries + episode.queries)
                    # pi_LLM's action once a solution is held (with probability P), else the primary agent's
                    guided = None
                    if following is not None and follows(lagr, guidance_rng):
                        guided = guide(following, observation, info)
                    if guided is None:
                        env_action = action = act(observation, info, epsilon, primary_rng)
                    else:
                        env_action, action, observation, info = guided.env_action, guided.action, guided.observation, guided.info
                    next_observation, reward, terminated, truncated, next_info = step_env(env_action)
                    is_guided = guided is not None
                    # The released cube code does not update the primary agent on guided steps.
                    if not is_guided or learn_guided:
                        learn(Step(observation, info, action, reward, next_observation, next_info, terminated))
                    # The step's transition (and pictures); jsonable keeps a tuple state as it is.
                    state = pattern if type(pattern) is tuple else jsonable(pattern)
                    extra = next_info.get(STEP_LOG)  # what the env adds to the record (an arm's placement)
                    fields = (trial, number, episode.steps, global_step, state, int(action), float(reward), bool(terminated), bool(truncated), is_guided)
                    hold(record(*fields) if extra is None else step_record(fields, extra))
                    if views is not None:
                        for view in views(next_info, global_step):
                            write(view)
                    episode.total += reward
                    episode.guided_steps += is_guided
                    episode.last_reward = reward  # the paper's trigger: query only after a positive reward
                    if not episode.solved:
                        episode.solved = is_complete(next_info["pattern"])
                    episode.steps += 1
                    observation, info = next_observation, next_info
                    global_step += 1
                    if terminated or truncated or (max_steps and global_step >= max_steps):
                        break
                    if stop_at_first and episode.accepted:
                        break
            finally:
                if held:  # the episode's transitions (also those of an episode stopped by an error)
                    steps = held[:]
                    held.clear()
                    sink.write_steps(steps)
            sink.write(
                episode_record(
                    info.get(EPISODE_LOG),  # what the env counted (an arm's placements, a task's own fields)
                    trial=parts.trial, episode=number, return_=float(episode.total), length=episode.steps,
                    queries=episode.queries, accepted=episode.accepted, epsilon=float(episode.epsilon),
                    solved=bool(episode.solved), guided_steps=episode.guided_steps, global_step=global_step,
                    cut_by_step_budget=_out_of_steps(config, global_step) and not (terminated or truncated),
                )
            )
            sink.flush()  # an episode ends: a Ctrl-C keeps every finished episode
            episodes += 1
            queries += episode.queries
            total_return += episode.total
            if episode.sources:
                for source, count in episode.sources.items():
                    sources[source] = sources.get(source, 0) + count
            if on_episode is not None:
                on_episode(episode.steps)
            accepted_any = accepted_any or episode.accepted > 0
            if (stop_at_solve and episode.solved) or (stop_at_first and accepted_any):
                break
    env.close()
    return TrialResult(
        path, parts.trial, episodes, global_step, queries, total_return, time.perf_counter() - started,
        sources=tuple(sorted(sources.items())),
    )


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
        parts.sink.write_not_asked(parts.trial, episode.number, episode.steps, global_step, state)
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


def _out_of_budget(config: ExperimentConfig, episode: int, global_step: int) -> bool:
    """A trial is ``run.episodes`` episodes or ``run.max_steps`` steps long (0: no limit)."""
    return bool(config.run.episodes and episode >= config.run.episodes) or _out_of_steps(config, global_step)


def _out_of_steps(config: ExperimentConfig, global_step: int) -> bool:
    return bool(config.run.max_steps and global_step >= config.run.max_steps)
