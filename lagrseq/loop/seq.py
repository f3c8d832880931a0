"""SEQ: the secondary agent that decides whether to query the LLM, and its query reward.

The secondary agent is a two-armed bandit over states (the paper's MAB setting): action 0 = do not
query (reward 0), action 1 = query (reward from the evaluation of the answer). Ties go to "do not
query", as ``np.argmax`` does in the released code, so an untried state is queried only when
exploring.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable

import numpy as np

from lagrseq.config import SecondaryConfig


def query_reward(evaluation: float, accepted: bool, config: SecondaryConfig) -> float:
    """The secondary agent's reward for a query.

    binary: ``reward_correct`` if the answer was accepted, else ``reward_wrong``.
    logistic (paper appendix): 1 / (1 + exp(-steepness * (E/N - midpoint))) on the normalised
    evaluation E/N of the answer.
    """
    if config.query_reward == "logistic":
        z = -config.logistic_steepness * (evaluation - config.logistic_midpoint)
        return 1.0 / (1.0 + math.exp(z))
    return config.reward_correct if accepted else config.reward_wrong


class TabularSecondary:
    """The paper's tabular SEQ agent: bandit values Q2[s] = [value of not querying, value of
    querying], one row per exact pattern (its tuple: a cube stack's letters in order). It is the
    :class:`lagrseq.loop.policies.SecondaryAgent` the ``seq`` policy consults."""

    def __init__(self, learning_rate: float) -> None:
        self.learning_rate = learning_rate
        self.table: dict[Hashable, np.ndarray] = {}

    def values(self, key: Hashable) -> np.ndarray:
        row = self.table.get(key)
        if row is None:
            row = self.table[key] = np.zeros(2)
        return row

    def decide(self, pattern: Iterable[Hashable], epsilon: float, rng: np.random.Generator) -> int:
        """epsilon-greedy over {0: skip, 1: query}; ties choose 0."""
        if rng.random() < epsilon:
            return int(rng.integers(2))
        row = self.values(tuple(pattern))
        return 1 if row[1] > row[0] else 0

    def update(self, pattern: Iterable[Hashable], decision: int, reward: float) -> None:
        """Bandit update Q2[s,a] += lr * (r - Q2[s,a]) (no bootstrapping: every decision ends)."""
        row = self.values(tuple(pattern))
        row[decision] += self.learning_rate * (reward - row[decision])
