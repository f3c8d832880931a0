"""Provider records and the one-method provider interface.

A provider turns a :class:`Query` (the exact prompt and sampling settings) into an
:class:`Answer` (text, usage, where it came from). Providers know nothing of RL or of tasks: the
caller parses and evaluates the text.

Providers that can return several samples of one query in one go (a live server honouring the
API's ``n``, or a wrapper around one) also implement :class:`MultiSampleProvider`;
:func:`sample` asks any provider for ``n`` answers, looping over ``complete`` when it has to.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any, Literal, Protocol, runtime_checkable

Source = Literal["live", "recorded", "mock", "miss", "calibrated"]
"""Where an answer came from; ``miss``: a recorded store lacked the query and ``--on-miss refuse``
answered it with a refusal (empty text, never accepted); ``calibrated``: ``--on-miss calibrated``
answered it with a draw at the store's own acceptance rate (``lagrseq.llm.calibrated``)."""
RecordedAs = Literal["text", "array", "list"]


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
    stop: tuple[str, ...] | None = None
    """Stop sequences sent to the server (None: the API default, no stop sequence)."""
    seed: int | None = None
    """The API's best-effort ``seed`` (None: not sent). Not the run seed."""
    top_k: int | None = None
    """llama.cpp's top-k cut (0: off). None: not sent and not in the key (OpenAI has no top-k);
    a query served by llama.cpp is pinned to 0 (:func:`with_samplers`)."""
    min_p: float | None = None
    """llama.cpp's min-p cut (0: off). None: not sent and not in the key; pinned to 0 for llama.cpp."""
    repeat_penalty: float | None = None
    """llama.cpp's repetition penalty (1: off). None: not sent and not in the key; pinned to 1 for
    llama.cpp."""

    @property
    def prompt(self) -> str:
        """The text of the last user message (the task prompt)."""
        return self.messages[-1].content


@dataclass(frozen=True)
class Usage:
    """Token counts reported by the server (or estimated, for the mock)."""

    prompt_tokens: int = 0
    completion_tokens: int = 0
    cached_tokens: int = 0
    """Prompt tokens the server served from its prompt cache (billed at the cached rate)."""

    @property
    def total_tokens(self) -> int:
        return self.prompt_tokens + self.completion_tokens


@dataclass(frozen=True)
class Answer:
    """What came back.

    ``cost_usd`` is what this answer cost now: the priced usage of a live answer, 0 for a recorded
    or mock one (and for an answer decided without a request), None when the model has no price
    in the price table. ``model`` is the model the
    server says it used (e.g. ``gpt-3.5-turbo-0125`` for ``gpt-3.5-turbo``).
    """

    text: str
    source: Source
    model: str
    usage: Usage | None = None
    """Token counts; None when unknown (the authors' caches recorded none) or when nothing was
    sent (a refused miss, a calibrated draw): logged as null, never as 0."""
    finish_reason: str | None = "stop"
    latency_s: float = 0.0
    cost_usd: float | None = 0.0
    system_fingerprint: str | None = None
    response_id: str | None = None
    """The server's id of the response the answer came in (live answers)."""
    record_key: str | None = None
    """The recorded store's key of the query (recorded answers, and live ones that were stored)."""
    sample_index: int | None = None
    """Which of the key's recorded samples this answer is (recorded answers)."""
    recorded_as: RecordedAs | None = None
    """How a recorded sample was stored: the raw answer ``text``, or an ``array`` or ``list`` that
    an old cache held already parsed and that the importer wrote out as text."""


class Provider(Protocol):
    """Anything that answers queries. A context manager whose ``close`` is idempotent."""

    name: str

    def complete(self, query: Query) -> Answer: ...

    def close(self) -> None: ...

    def __enter__(self) -> Any: ...

    def __exit__(self, *exc: object) -> None: ...


@runtime_checkable
class MultiSampleProvider(Protocol):
    """A provider that can return ``n`` samples of one query at once."""

    name: str

    @property
    def max_samples_per_request(self) -> int:
        """How many samples one underlying request yields (1: one request per sample)."""
        ...

    def complete(self, query: Query) -> Answer: ...

    def complete_n(self, query: Query, n: int) -> list[Answer]: ...

    def close(self) -> None: ...


def samples_per_request(provider: Provider) -> int:
    """How many samples ``provider`` gets from one underlying request."""
    if isinstance(provider, MultiSampleProvider):
        return max(1, int(provider.max_samples_per_request))
    return 1


def sample(provider: Provider, query: Query, n: int) -> list[Answer]:
    """``n`` answers to ``query``: in one go where the provider can, else one call per answer."""
    if n <= 0:
        return []
    if isinstance(provider, MultiSampleProvider):
        return provider.complete_n(query, n)
    return [provider.complete(query) for _ in range(n)]


SAMPLER_FIELDS = ("top_k", "min_p", "repeat_penalty")
"""The sampler settings beyond OpenAI's that a query may carry (sent and keyed only when set)."""


def with_samplers(query: Query, samplers: Iterable[tuple[str, float]]) -> Query:
    """``query`` with every sampler of ``samplers`` (name, value) it does not set already: how a
    server kind pins its own defaults (llama.cpp: ``top_k`` 40, ``min_p`` 0.05, ``repeat_penalty``
    1.1) to OpenAI's meaning of temperature (:data:`lagrseq.llm.servers.LLAMA_CPP_SAMPLERS`)."""
    missing = {name: value for name, value in samplers if getattr(query, name) is None}
    if not missing:
        return query
    changes: dict[str, Any] = {name: (int(value) if name == "top_k" else float(value)) for name, value in missing.items()}
    return replace(query, **changes)


def samplers_of(query: Query) -> dict[str, float]:
    """The sampler settings ``query`` carries beyond OpenAI's (name -> value; empty: none)."""
    return {name: getattr(query, name) for name in SAMPLER_FIELDS if getattr(query, name) is not None}


def pinned(provider: Any, query: Query) -> Query:
    """``query`` as ``provider`` sends it: with the sampler settings its server kind pins (a
    provider without ``pin``, such as the mock or a recorded store, sends it as it is). Whoever
    keys a query for a provider keys this one, so the key says what the server was asked."""
    pin = getattr(provider, "pin", None)
    return query if pin is None else pin(query)  # type: ignore[no-any-return]


def user_query(task: str, prompt: str, model: str, temperature: float, max_tokens: int) -> Query:
    """A single-user-message query, as the released code sends."""
    return Query(
        task=task,
        model=model,
        messages=(Message("user", prompt),),
        temperature=temperature,
        max_tokens=max_tokens,
    )
