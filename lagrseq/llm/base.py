"""Provider records and the one-method provider interface.

A provider turns a :class:`Query` (the exact prompt and sampling settings) into an
:class:`Answer` (text, usage, where it came from). Providers know nothing of RL or of tasks: the
caller parses and evaluates the text.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

Source = Literal["live", "recorded", "mock"]


@dataclass(frozen=True)
class Message:
    """One chat message."""

    role: Literal["system", "user", "assistant"]
    content: str


@dataclass(frozen=True)
class Query:
    """What is asked: the task it belongs to, the model, the exact messages and settings."""

    task: str
    model: str
    messages: tuple[Message, ...]
    temperature: float = 0.0
    max_tokens: int = 256
    top_p: float = 1.0

    @property
    def prompt(self) -> str:
        """The text of the last user message (the task prompt)."""
        return self.messages[-1].content


@dataclass(frozen=True)
class Usage:
    """Token counts reported by the server (or estimated, for the mock)."""

    prompt_tokens: int = 0
    completion_tokens: int = 0

    @property
    def total_tokens(self) -> int:
        return self.prompt_tokens + self.completion_tokens


@dataclass(frozen=True)
class Answer:
    """What came back."""

    text: str
    source: Source
    model: str
    usage: Usage = field(default_factory=Usage)
    finish_reason: str = "stop"
    latency_s: float = 0.0
    cost_usd: float = 0.0
    system_fingerprint: str | None = None


class Provider(Protocol):
    """Anything that answers queries."""

    name: str

    def complete(self, query: Query) -> Answer: ...

    def close(self) -> None: ...


def user_query(task: str, prompt: str, model: str, temperature: float, max_tokens: int) -> Query:
    """A single-user-message query, as the released code sends."""
    return Query(
        task=task,
        model=model,
        messages=(Message("user", prompt),),
        temperature=temperature,
        max_tokens=max_tokens,
    )
