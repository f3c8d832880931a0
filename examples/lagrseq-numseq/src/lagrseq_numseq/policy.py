"""The ``backoff`` asking policy: ask with probability p, multiplied by a factor after every
rejected answer of the episode (reset at its start). Knobs: ``ask_probability`` (p at an
episode's start) and its own ``backoff_factor`` (default 0.5: halved)."""

from __future__ import annotations

from typing import Any


class Backoff:
    def __init__(self, probability: float, factor: float = 0.5) -> None:
        self.start = probability
        self.factor = factor
        self.probability = probability
        self.episode = -1

    def decide(self, context: Any) -> int:
        if context.episode != self.episode:
            self.episode, self.probability = context.episode, self.start
        return int(context.rng.random() < self.probability)

    def update(self, context: Any, asked: int, query_reward: float) -> None:
        if asked and not context.accepted:
            self.probability *= self.factor
