"""When to ask: asking policies, the secondary agent generalised.

The loop (``lagrseq.loop.experiment``) calls ``policy.decide(context)`` wherever the trigger allows a
query and no accepted solution is held, then ``policy.update(context, asked, query_reward)`` with
the query reward (0 when it did not ask). An :class:`AskContext` holds only what the agent may
know: the pattern, its progress, the step and episode counters, the query counts so far, and,
after a query, the evaluation and acceptance of the answer. It never holds the target; the oracle
alone may look at the provider's answer first (:meth:`AskContext.peek`), which is not a query.

Policies (config field ``secondary.policy`` with ``--method lagr-seq``):

- ``never`` / ``always``: what ``baseline`` and ``lagr`` do;
- ``random``: ask with probability ``ask_probability``;
- ``seq``: the paper's tabular or neural bandit (:class:`SeqPolicy` wraps it unchanged);
- ``thompson``: a posterior per context (:class:`ThompsonPolicy`);
- ``oracle``: ask only when the answer would be accepted (a lower bound on queries);
- ``advance``: ask where the primary agent's progress reaches a new best of the episode, or
  has stalled for ``stall_steps`` decisions, on a rejected pattern only again with the decaying
  chance ``reask_decay`` gives (default: never) (:class:`AdvancePolicy`);
- any of them behind :class:`Budget` (``secondary.budget`` > 0): at most N queries per trial or
  per episode;
- any of them behind :class:`ProgressGate` (``secondary.min_progress`` > 0): never ask before the
  pattern has come this far (stack height, cells on), where answers are rarely accepted.

A per-query cost lambda (``secondary.query_cost``) is subtracted from the query reward by the
loop, so it reaches every learning policy (and the ``/query`` log) the same way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable
from typing import Any, Protocol

import numpy as np


class AskContext:
    """What an asking policy may know at one decision (never the target)."""

    __slots__ = (
        "pattern", "progress", "episode", "episode_step", "global_step", "epsilon", "rng",
        "queries_trial", "queries_episode", "evaluation", "accepted", "peeked", "_peek",
    )

    def __init__(
        self,
        pattern: Any,
        progress: int,
        episode: int,
        episode_step: int,
        global_step: int,
        epsilon: float,
        rng: np.random.Generator,
        queries_trial: int,
        queries_episode: int,
        peek: Callable[[], Any] | None = None,
    ) -> None:
        self.pattern = pattern
        self.progress = progress
        """How far the pattern has come (stack height, cells on): ``Task.progress``."""
        self.episode = episode
        self.episode_step = episode_step
        self.global_step = global_step
        self.epsilon = epsilon
        """The secondary agent's exploration rate at this step (its schedule)."""
        self.rng = rng
        """The secondary agent's random stream (SECONDARY)."""
        self.queries_trial = queries_trial
        self.queries_episode = queries_episode
        self.evaluation: float | None = None
        """After a query: the normalised evaluation E of the answer."""
        self.accepted: bool | None = None
        """After a query: whether the answer was accepted."""
        self.peeked: Any = None
        """The consultation the oracle looked at (the loop reuses it if the oracle asks)."""
        self._peek = peek

    def query(self) -> Any:
        """The consultation of the query this decision makes: the answer the policy peeked at,
        if it did (a look becomes the query it decided to make), else the provider asked now."""
        return self.peek()

    def peek(self) -> Any:
        """The provider's answer to this pattern, parsed and evaluated, without it counting as a
        query (the oracle only). Asked once per decision."""
        if self._peek is None:
            raise RuntimeError("this loop offers no peek at answers (the oracle needs one)")
        if self.peeked is None:
            self.peeked = self._peek()
        return self.peeked


class AskingPolicy(Protocol):
    """Whether to query the LLM now, and what to learn from the outcome."""

    def decide(self, context: AskContext) -> int: ...

    def update(self, context: AskContext, asked: int, query_reward: float) -> None: ...


class SecondaryAgent(Protocol):
    """The paper's SEQ agent (tabular or neural bandit over patterns): whether to query the LLM
    from a pattern, and its bandit update (the adapters in :mod:`lagrseq.loop.adapters`)."""

    def decide(self, pattern: Any, epsilon: float, rng: np.random.Generator) -> int: ...

    def update(self, pattern: Any, decision: int, reward: float) -> None: ...


def pattern_key(pattern: Any) -> Hashable:
    """A hashable key of one exact pattern (a cube stack or a grid)."""
    if isinstance(pattern, np.ndarray):
        return (pattern.shape, pattern.tobytes())
    return tuple(pattern)


class Never:
    """Never ask (``baseline``'s choice, logged as decisions 0)."""

    def decide(self, context: AskContext) -> int:
        return 0

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        return None


class Always:
    """Ask whenever triggered (``lagr``)."""

    def decide(self, context: AskContext) -> int:
        return 1

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        return None


class RandomAsk:
    """Ask with probability p (one draw from the secondary stream per decision)."""

    def __init__(self, probability: float) -> None:
        self.probability = probability

    def decide(self, context: AskContext) -> int:
        return int(context.rng.random() < self.probability)

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        return None


class SeqPolicy:
    """The paper's SEQ bandit, exactly as before: epsilon-greedy on its values, bandit update."""

    def __init__(self, agent: SecondaryAgent) -> None:
        self.agent = agent

    def decide(self, context: AskContext) -> int:
        return self.agent.decide(context.pattern, context.epsilon, context.rng)

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        self.agent.update(context.pattern, asked, query_reward)


class Oracle:
    """Ask only when the answer would be accepted: it looks at the answer first (uncounted), so
    its query count is the lower bound for the return that guidance gives."""

    def decide(self, context: AskContext) -> int:
        return int(bool(context.peek().accepted))

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        return None


class ThompsonPolicy:
    """Thompson sampling over contexts that generalise across states.

    The context of a decision is (progress, how often this exact pattern was already answered
    and rejected, capped at 2): a taller stack or fuller grid shares what was learnt at that
    progress, and a pattern whose answer was already rejected is its own context (at temperature
    0 a repeated question gets the same answer). Binary query reward: a Beta(a, b) posterior per
    context on acceptance; the sampled acceptance rate theta gives the expected reward
    theta * reward_correct + (1 - theta) * reward_wrong - cost. Logistic reward: a Gaussian
    posterior on the reward itself (prior mean a / (a + b), precision a + b, noise precision 4:
    rewards lie in [0, 1]). Ask when the sampled net reward is above 0, the reward of not asking.
    """

    NOISE_PRECISION = 4.0
    REJECTED_CAP = 2

    def __init__(
        self,
        prior: tuple[float, float],
        reward: str = "binary",
        reward_correct: float = 1.0,
        reward_wrong: float = 0.0,
        cost: float = 0.0,
    ) -> None:
        self.prior_a, self.prior_b = float(prior[0]), float(prior[1])
        self.logistic = reward == "logistic"
        self.reward_correct, self.reward_wrong, self.cost = reward_correct, reward_wrong, cost
        self.posterior: dict[Hashable, list[float]] = {}
        """Binary: [a, b]; logistic: [mean, precision]."""
        self.rejected: dict[Hashable, int] = {}

    def context_key(self, context: AskContext) -> Hashable:
        rejected = self.rejected.get(pattern_key(context.pattern), 0)
        return (int(context.progress), min(rejected, self.REJECTED_CAP))

    def _row(self, key: Hashable) -> list[float]:
        row = self.posterior.get(key)
        if row is None:
            a, b = self.prior_a, self.prior_b
            row = self.posterior[key] = [a / (a + b), a + b] if self.logistic else [a, b]
        return row

    def decide(self, context: AskContext) -> int:
        row = self._row(self.context_key(context))
        if self.logistic:
            value = row[0] + context.rng.standard_normal() / math.sqrt(row[1])
        else:
            theta = context.rng.beta(row[0], row[1])
            value = theta * self.reward_correct + (1.0 - theta) * self.reward_wrong
        return int(value - self.cost > 0.0)

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        if not asked:
            return
        key = self.context_key(context)
        row = self._row(key)
        if self.logistic:
            reward = query_reward + self.cost  # the loop subtracted the cost; learn the reward
            precision = row[1] + self.NOISE_PRECISION
            row[0] = (row[0] * row[1] + reward * self.NOISE_PRECISION) / precision
            row[1] = precision
        elif context.accepted:
            row[0] += 1.0
        else:
            row[1] += 1.0
        if not context.accepted:
            exact = pattern_key(context.pattern)
            self.rejected[exact] = self.rejected.get(exact, 0) + 1


class AdvancePolicy:
    """Ask where the primary agent advances, and where it has stalled.

    Built from the failure mode of ``thompson`` with a query cost: it reaches its first solve as
    early as always in most trials, but in 1-2 trials in 10 it skips the very decisions at which
    always's answer was accepted (its posterior at that progress had fallen after rejections),
    and the first solve comes hundreds or thousands of steps later. In always's logs, accepted
    answers come at decisions where the pattern's progress rises above its best of the episode
    so far, on a pattern not already answered and rejected, a small share of all decisions. So
    this policy asks:

    - at every decision where the progress (stack height, cells on) rises above its best of
      this episode (the episode's first decision included): the primary agent advanced;
    - once ``stall_steps`` decisions have passed without a new best and without a query: it
      stalled (a new best, a query or a new episode restarts the count);
    - on a pattern already answered and rejected k times, only with probability
      ``reask_decay ** k`` (one draw from the secondary stream, made only there and only when
      ``reask_decay`` > 0); the default 0 never asks it again (at temperature 0 the same question
      gets the same answer; a refused store miss is a rejection too). With sampled answers
      (temperature > 0) a second sample may be accepted where the first was not.

    Nothing here knows the task or the target: progress is what the agent sees of its own
    pattern, the count is in decisions. At ``reask_decay`` = 0 it draws nothing from the
    secondary stream."""

    def __init__(self, stall_steps: int, reask_decay: float = 0.0) -> None:
        if stall_steps < 1:
            raise ValueError(f"stall_steps must be >= 1, got {stall_steps}")
        if not 0.0 <= reask_decay <= 1.0:
            raise ValueError(f"reask_decay must lie in [0, 1], got {reask_decay}")
        self.stall_steps = stall_steps
        self.reask_decay = reask_decay
        self.episode: int | None = None
        self.best = -1
        """The highest progress seen at a decision in this episode (-1: none yet)."""
        self.waited = 0
        """Decisions since the last new best, the last query or the episode's start."""
        self.rejected: dict[Hashable, int] = {}
        """How often each pattern's answer was rejected (absent: never)."""
        self.stalled = 0
        """Queries asked because the agent stalled (not at a new best)."""
        self.reasked = 0
        """Queries asked again on a pattern whose answer was already rejected."""

    def decide(self, context: AskContext) -> int:
        progress = int(context.progress)
        if context.episode != self.episode:
            self.episode, self.best, self.waited = context.episode, -1, 0
        advanced = progress > self.best
        if advanced:
            self.best, self.waited = progress, 0
        else:
            self.waited += 1
        stalled = not advanced and self.waited >= self.stall_steps
        if not (advanced or stalled) or not self._may_ask(context):
            return 0
        if stalled:
            self.waited = 0
            self.stalled += 1
        return 1

    def _may_ask(self, context: AskContext) -> bool:
        """Whether this pattern may be asked: never rejected, or drawn again with probability
        ``reask_decay ** k`` after k rejections (no draw at ``reask_decay`` = 0)."""
        times = self.rejected.get(pattern_key(context.pattern), 0)
        if times == 0:
            return True
        if self.reask_decay <= 0.0 or context.rng.random() >= self.reask_decay**times:
            return False
        self.reasked += 1
        return True

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        if asked and not context.accepted:
            key = pattern_key(context.pattern)
            self.rejected[key] = self.rejected.get(key, 0) + 1


class Budget:
    """At most ``limit`` queries per trial or per episode, whatever ``inner`` decides. Once spent,
    the inner policy is not consulted (nor updated) and the decision is 0."""

    def __init__(self, inner: AskingPolicy, limit: int, scope: str = "trial") -> None:
        self.inner = inner
        self.limit = limit
        self.per_episode = scope == "episode"

    def spent(self, context: AskContext) -> bool:
        used = context.queries_episode if self.per_episode else context.queries_trial
        return used >= self.limit

    def decide(self, context: AskContext) -> int:
        if self.spent(context):
            return 0
        return self.inner.decide(context)

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        if asked or not self.spent(context):
            self.inner.update(context, asked, query_reward)


class ProgressGate:
    """Ask only once the pattern's progress (stack height, cells on) is at least ``min_progress``
    (KnowNo / When2Ask-style: a query is worth its price where the answer is likely to be
    accepted). Below it the inner policy is neither consulted (so it draws nothing from the
    secondary stream) nor updated, and the decision is 0. Progress is what the agent sees of its
    own pattern; the gate never looks at the target."""

    def __init__(self, inner: AskingPolicy, min_progress: int) -> None:
        self.inner = inner
        self.min_progress = min_progress

    def open(self, context: AskContext) -> bool:
        return context.progress >= self.min_progress

    def decide(self, context: AskContext) -> int:
        if not self.open(context):
            return 0
        return self.inner.decide(context)

    def update(self, context: AskContext, asked: int, query_reward: float) -> None:
        if asked or self.open(context):
            self.inner.update(context, asked, query_reward)


def make_seq(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return SeqPolicy(seq_agent())


def make_never(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return Never()


def make_always(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return Always()


def make_random(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return RandomAsk(section.ask_probability)


def make_thompson(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return ThompsonPolicy(
        (section.thompson_prior[0], section.thompson_prior[1]),
        section.query_reward,
        section.reward_correct,
        section.reward_wrong,
        section.query_cost,
    )


def make_oracle(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return Oracle()


def make_advance(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    return AdvancePolicy(int(section.knob("stall_steps")), float(section.knob("reask_decay")))


def make_policy(section: Any, seq_agent: Callable[[], SecondaryAgent]) -> AskingPolicy:
    """The asking policy of a ``[secondary]`` section (its registered factory, in
    ``lagrseq.registry.POLICIES``); ``seq_agent`` builds the paper's bandit (only called by
    ``seq``, so other policies never need torch). Every policy may sit behind a progress gate
    and a budget."""
    from lagrseq.registry import POLICIES

    policy: AskingPolicy = POLICIES.get(section.policy).make(section, seq_agent)
    if section.min_progress > 0:
        policy = ProgressGate(policy, section.min_progress)
    if section.budget > 0:
        policy = Budget(policy, section.budget, section.budget_scope)
    return policy
