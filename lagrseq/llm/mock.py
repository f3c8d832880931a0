"""The deterministic mock provider: a rule-based extrapolator in place of an LLM.

The mock knows no task. It is handed a function (the task's extrapolator) that reads the same
prompt text a real model would get and returns answer text, which then goes through the same
parser as a real answer. Sampling at temperature > 0 uses the generator the mock was given.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lagrseq.llm.base import Answer, Query, Usage

Handler = Callable[[str, float, np.random.Generator], str]


def estimate_tokens(text: str) -> int:
    """A rough token count (about 4 characters a token), for the mock's usage figures."""
    return max(1, (len(text) + 3) // 4)


class MockProvider:
    """Answer every query with ``handler(prompt, temperature, rng)``; costs nothing."""

    def __init__(self, handler: Handler, rng: np.random.Generator, name: str = "mock") -> None:
        self.handler = handler
        self.rng = rng
        self.name = name

    def complete(self, query: Query) -> Answer:
        text = self.handler(query.prompt, query.temperature, self.rng)
        return Answer(
            text=text,
            source="mock",
            model=self.name,
            usage=Usage(estimate_tokens(query.prompt), estimate_tokens(text)),
        )

    def close(self) -> None:
        return None

    def __enter__(self) -> MockProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
