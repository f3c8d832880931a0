"""LaGR: when to ask the language model, how to judge its answer, and pi_LLM.

Knows tasks (prompt, parser, evaluation, guidance) and the provider interface, never a concrete
provider or the logs.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from lagrseq.config import LagrConfig, LLMConfig
from lagrseq.llm.base import Answer, Provider, Query, user_query
from lagrseq.tasks.base import Parsed, Pattern, Task


@dataclass(frozen=True)
class Consultation:
    """One query and what became of it."""

    prompt_sha256: str
    answer: Answer
    parsed: Parsed
    evaluation: float
    accepted: bool
    prompt: str = ""
    """The text of the user message (its UTF-8 bytes hash to ``prompt_sha256``)."""


def query_for(task: Task, llm: LLMConfig, pattern: Pattern) -> Query:
    """The query LaGR sends for ``pattern`` (``lagrseq record`` builds the same, so recorded keys
    match the queries of a run)."""
    return user_query(task.name, task.prompt(pattern), llm.model, llm.temperature, llm.max_tokens)


def consult(
    task: Task,
    provider: Provider,
    llm: LLMConfig,
    threshold: float,
    pattern: Pattern,
) -> Consultation:
    """Ask the provider to extrapolate ``pattern``; parse and evaluate the answer.

    An answer that cannot be parsed is a wrong answer (evaluation 0) whose reason is kept in
    ``parsed.error``; it never stops the run.
    """
    query = query_for(task, llm, pattern)
    prompt = query.prompt
    answer = provider.complete(query)
    if answer.source == "miss":  # --on-miss refuse: a refusal is a wrong answer, whatever its text
        parsed, evaluation = Parsed(None, "refused: the recorded store holds no answer to this query"), 0.0
    else:
        parsed = task.parse(answer.text)
        evaluation = task.evaluate(parsed.solution) if parsed.ok else 0.0
    return Consultation(
        prompt_sha256=hashlib.sha256(prompt.encode()).hexdigest(),
        answer=answer,
        parsed=parsed,
        evaluation=float(evaluation),
        accepted=parsed.ok and evaluation >= threshold,
        prompt=prompt,
    )


class QueryTrigger:
    """Whether the current step may lead to a query (before SEQ's decision).

    - ``positive-reward`` (paper): the transition into the current state was rewarded > 0.
    - ``new-max-prefix`` (released cube code): the pattern has progressed further than at this
      episode's last query; the released code checks this one step after the progress was made,
      which is the same state our check sees at the start of the next step.
    - ``every-step`` (released grid code): always.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.queried_progress = 0

    def reset_episode(self) -> None:
        self.queried_progress = 0

    def armed(self, progress: int, last_reward: float) -> bool:
        if self.kind == "every-step":
            return True
        if self.kind == "positive-reward":
            return last_reward > 0
        return progress > self.queried_progress

    def queried(self, progress: int) -> None:
        self.queried_progress = progress


def follows(config: LagrConfig, rng: np.random.Generator) -> bool:
    """Whether this step follows pi_LLM: with probability P (``follow_probability``); P = 1 draws
    nothing from ``rng``."""
    return config.follow_probability >= 1.0 or rng.random() < config.follow_probability
