"""The live provider: OpenAI-compatible Chat Completions over httpx.

Any server that speaks ``POST {base_url}/chat/completions`` works: OpenAI's API (the default),
vLLM, Ollama's ``/v1``, llama.cpp's server. What differs between them and matters here is whether
the API's ``n`` (several samples in one request) is honoured; :data:`SERVER_KINDS` says so per
server kind, and a server that returns fewer choices than asked is topped up with more requests.

Failures, as the OpenAI client libraries treat them:

- retried, with exponential backoff and jitter (drawn from the generator the provider was given):
  connection errors, timeouts, a response cut short, HTTP 408, 409, 429 and 5xx. The server's
  ``retry-after-ms`` / ``retry-after`` (seconds or an HTTP date) is honoured up to
  ``max_retry_after_s``; a longer wait is reported instead of slept. ``x-should-retry: true|false``
  overrides the status code.
- not retried: 400, 401, 403, 404, 422 and other 4xx, and a 429 whose error type or code is
  ``insufficient_quota`` (no amount of waiting helps); a 200 whose body is empty, not JSON, or not a
  chat completion.

Every failure is one :class:`~lagrseq.errors.ProviderError` line saying what happened and what to
do. The API key is read from the environment (``OPENAI_API_KEY`` or the variable named by
``--api-key-env``), kept in a :class:`Secret` that never prints, sent only in the ``Authorization``
header, and redacted from anything the server echoes back.
"""

from __future__ import annotations

import email.utils
import json
import math
import os
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np

from lagrseq import __version__
from lagrseq.errors import ProviderError
from lagrseq.llm.base import Answer, Query, Usage
from lagrseq.llm.pricing import PriceTable
from lagrseq.llm.servers import DEFAULT_BASE_URL, SERVER_KINDS
from lagrseq.llm.store import endpoint_of


@dataclass(frozen=True)
class LiveSettings:
    """How to reach the server and how patiently."""

    base_url: str = DEFAULT_BASE_URL
    """The API root; ``/chat/completions`` is appended."""
    api_key_env: str = "OPENAI_API_KEY"
    """Environment variable holding the API key."""
    server: str = "openai"
    """A key of :data:`SERVER_KINDS`."""
    connect_timeout_s: float = 10.0
    """Seconds to open a connection (also the write and pool timeouts)."""
    read_timeout_s: float = 120.0
    """Seconds to wait for the next bytes of a response."""
    max_retries: int = 5
    """Retries after the first attempt (0: fail on the first retryable error)."""
    backoff_initial_s: float = 0.5
    """Delay before the first retry; doubles with every retry."""
    backoff_max_s: float = 8.0
    """Longest backoff delay."""
    jitter: float = 0.25
    """Each backoff delay is multiplied by (1 - jitter * u), u uniform in [0, 1)."""
    max_retry_after_s: float = 60.0
    """Longest server-requested wait (retry-after) that is slept; longer ones fail the call."""

    def __post_init__(self) -> None:
        if self.server not in SERVER_KINDS:
            raise ProviderError(
                f"unknown server kind {self.server!r}; expected one of {', '.join(SERVER_KINDS)}"
            )
        if self.max_retries < 0 or self.backoff_initial_s < 0 or not 0 <= self.jitter <= 1:
            raise ProviderError(
                "retry settings out of range: max_retries >= 0, backoff_initial_s >= 0, 0 <= jitter <= 1"
            )


class Secret:
    """A string that never shows itself: not in repr, str, f-strings, logs or pickles."""

    __slots__ = ("_value",)

    def __init__(self, value: str) -> None:
        self._value = value

    def reveal(self) -> str:
        return self._value

    def __repr__(self) -> str:
        return "Secret('****')"

    __str__ = __repr__

    def __format__(self, spec: str) -> str:
        return repr(self)

    def __reduce__(self) -> Any:
        raise TypeError("refusing to pickle an API key")

    def __bool__(self) -> bool:
        return bool(self._value)


_KEY_LIKE = re.compile(r"\b(sk|key|api[_-]?key)[-_][A-Za-z0-9_\-*.]{6,}", re.IGNORECASE)


def redact(text: str, secret: Secret | None) -> str:
    """``text`` with the key, and anything that looks like an API key, blanked out."""
    if secret and secret.reveal():
        text = text.replace(secret.reveal(), "****")
    return _KEY_LIKE.sub(lambda m: m.group(1) + "-****", text)


def _clip(text: str, width: int = 200) -> str:
    one = " ".join(text.split())
    return one if len(one) <= width else one[: width - 3] + "..."


def parse_retry_after(headers: Mapping[str, str], now: float | None = None) -> float | None:
    """Seconds the server asks us to wait: ``retry-after-ms``, else ``retry-after`` as seconds
    (floats allowed) or an HTTP date; None when absent or unreadable."""
    for name, divisor in (("retry-after-ms", 1000.0), ("retry-after", 1.0)):
        value = headers.get(name)
        if value is None:
            continue
        try:
            delay = float(value)
        except ValueError:
            continue
        if math.isfinite(delay):
            return max(delay / divisor, 0.0)
    value = headers.get("retry-after")
    if value:
        try:
            moment = email.utils.parsedate_to_datetime(value)
        except (TypeError, ValueError, IndexError):
            return None
        return max(moment.timestamp() - (time.time() if now is None else now), 0.0)
    return None


def _split(total: int, parts: int) -> list[int]:
    """``total`` split into ``parts`` integers that differ by at most one and sum to it."""
    base, extra = divmod(max(total, 0), parts)
    return [base + (1 if i < extra else 0) for i in range(parts)]


class _Retry(Exception):
    """Internal: this attempt failed in a way worth retrying."""

    def __init__(self, reason: str, retry_after: float | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.retry_after = retry_after


class LiveProvider:
    """Ask an OpenAI-compatible server. A context manager; ``close`` is idempotent.

    ``rng`` draws the backoff jitter (pass one spawned from the run seed); ``prices`` turns usage
    into ``cost_usd`` (None when the model is not in the table); ``transport`` is for embedding
    lagrseq (an ``httpx.MockTransport``, a proxy); ``environ`` is where the key is looked up.
    """

    name = "live"

    def __init__(
        self,
        settings: LiveSettings | None = None,
        rng: np.random.Generator | None = None,
        prices: PriceTable | None = None,
        transport: httpx.BaseTransport | None = None,
        environ: Mapping[str, str] | None = None,
        on_retry: Callable[[str], None] | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.settings = settings or LiveSettings()
        self.kind = SERVER_KINDS[self.settings.server]
        self.endpoint = endpoint_of(self.settings.base_url)
        self.url = self.settings.base_url.rstrip("/") + "/chat/completions"
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.prices = prices if prices is not None else PriceTable()
        self.on_retry = on_retry
        self._sleep = sleep
        value = (os.environ if environ is None else environ).get(self.settings.api_key_env, "")
        self._key = Secret(value.strip())
        if not self._key and (self.endpoint == "api.openai.com" or self.settings.api_key_env != "OPENAI_API_KEY"):
            raise ProviderError(
                f"environment variable {self.settings.api_key_env} is not set; export your API key "
                "there, or name another variable with --api-key-env"
            )
        timeout = httpx.Timeout(
            self.settings.read_timeout_s,
            connect=self.settings.connect_timeout_s,
            write=self.settings.connect_timeout_s,
            pool=self.settings.connect_timeout_s,
        )
        self._client = httpx.Client(timeout=timeout, transport=transport, follow_redirects=False)
        self._closed = False

    @property
    def max_samples_per_request(self) -> int:
        return self.kind.max_samples_per_request

    def __repr__(self) -> str:
        return (
            f"LiveProvider(base_url={self.settings.base_url!r}, server={self.kind.name!r}, "
            f"api_key_env={self.settings.api_key_env!r})"
        )

    # ------------------------------------------------------------------ the interface
    def complete(self, query: Query) -> Answer:
        return self.complete_n(query, 1)[0]

    def complete_n(self, query: Query, n: int) -> list[Answer]:
        """``n`` samples of ``query``: ``n`` per request where the server honours it, more
        requests where it returns fewer."""
        answers: list[Answer] = []
        while len(answers) < n:
            ask = min(n - len(answers), self.kind.max_samples_per_request)
            answers.extend(self._request(query, ask))
        return answers[:n]

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._client.close()

    def __enter__(self) -> LiveProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ one request, with retries
    def body(self, query: Query, n: int) -> dict[str, Any]:
        """The JSON body sent for ``n`` samples of ``query``."""
        body: dict[str, Any] = {
            "model": query.model,
            "messages": [{"role": m.role, "content": m.content} for m in query.messages],
            "temperature": query.temperature,
            "top_p": query.top_p,
            "max_tokens": query.max_tokens,
        }
        if n != 1:
            body["n"] = n
        if query.stop:
            body["stop"] = list(query.stop)
        if query.seed is not None:
            body["seed"] = query.seed
        return body

    def _headers(self) -> dict[str, str]:
        headers = {
            "Content-Type": "application/json",
            "Accept": "application/json",
            "User-Agent": f"lagrseq/{__version__}",
        }
        if self._key:
            headers["Authorization"] = f"Bearer {self._key.reveal()}"
        return headers

    def _request(self, query: Query, n: int) -> list[Answer]:
        if self._closed:
            raise ProviderError("the live provider is closed")
        body = self.body(query, n)
        attempts = self.settings.max_retries + 1
        last = ""
        for attempt in range(attempts):
            try:
                return self._attempt(query, body, n)
            except _Retry as retry:
                last = retry.reason
                if attempt + 1 >= attempts:
                    break
                delay = self._delay(attempt, retry.retry_after, retry.reason)
                if self.on_retry is not None:
                    self.on_retry(f"{retry.reason}; retrying in {delay:.2f} s ({attempt + 1}/{self.settings.max_retries})")
                self._sleep(delay)
        raise ProviderError(
            f"{self.url}: gave up after {attempts} attempt{'s' if attempts != 1 else ''}: {last}; "
            "check --base-url and the server, or try again later"
        )

    def _delay(self, attempt: int, retry_after: float | None, reason: str) -> float:
        if retry_after is not None and retry_after > 0:  # 0 or a past date: back off as usual
            if retry_after > self.settings.max_retry_after_s:
                raise ProviderError(
                    f"{self.url}: {reason}; the server asks to wait {retry_after:.0f} s, longer than "
                    f"the {self.settings.max_retry_after_s:.0f} s lagrseq waits; try again later"
                )
            return retry_after
        s = self.settings
        delay = min(s.backoff_initial_s * 2.0**attempt, s.backoff_max_s)
        return delay * (1.0 - s.jitter * float(self.rng.random()))

    def _attempt(self, query: Query, body: dict[str, Any], n: int) -> list[Answer]:
        started = time.perf_counter()
        try:
            response = self._client.post(self.url, json=body, headers=self._headers())
        except httpx.TimeoutException as exc:
            phase = {"ConnectTimeout": "connect", "ReadTimeout": "read", "WriteTimeout": "write", "PoolTimeout": "pool"}
            which = phase.get(type(exc).__name__, "")
            limit = self.settings.read_timeout_s if which == "read" else self.settings.connect_timeout_s
            raise _Retry(f"no response within the {limit:g} s {which} timeout".replace("  ", " ")) from None
        except (httpx.NetworkError, httpx.RemoteProtocolError) as exc:
            raise _Retry(f"connection failed ({type(exc).__name__}: {redact(str(exc), self._key)})") from None
        except httpx.HTTPError as exc:  # bad URL, unsupported scheme, proxy trouble: not transient
            raise ProviderError(
                f"{self.url}: cannot send the request ({type(exc).__name__}: {redact(str(exc), self._key)}); "
                "check --base-url"
            ) from None
        latency = time.perf_counter() - started
        if response.status_code != 200:
            self._refuse(response, query)
        return self._answers(response, query, n, latency)

    def _refuse(self, response: httpx.Response, query: Query) -> None:
        """Raise for a non-200 response: ``_Retry`` if it is worth retrying, else ProviderError."""
        status = response.status_code
        kind, message = self._error_of(response)
        said = f"HTTP {status}" + (f" {kind}" if kind else "") + (f": {message}" if message else "")
        should = response.headers.get("x-should-retry", "").lower()
        if kind == "insufficient_quota":
            raise ProviderError(
                f"{self.url}: {said}; the account behind {self.settings.api_key_env} has no quota left "
                "(not retried): add credit or use another key"
            )
        retryable = status in (408, 409, 429) or status >= 500
        if should == "true" or (retryable and should != "false"):
            raise _Retry(said, parse_retry_after(response.headers))
        hint = {
            400: "the server rejected the request",
            401: f"the key in {self.settings.api_key_env} was refused; check it",
            403: f"the key may not use model {query.model!r} here",
            404: f"no model {query.model!r} or no /chat/completions at {self.settings.base_url}; check --base-url and the model name",
            422: "the server could not process the request",
        }.get(status, "not retried")
        raise ProviderError(f"{self.url}: {said}; {hint}")

    def _error_of(self, response: httpx.Response) -> tuple[str, str]:
        """(error type or code, message) from an error body in OpenAI's or vLLM's shape."""
        try:
            data = response.json()
        except (json.JSONDecodeError, UnicodeDecodeError, ValueError):
            return "", redact(_clip(response.text), self._key)
        error = data.get("error", data) if isinstance(data, dict) else data
        if isinstance(error, dict):
            code = error.get("code")
            kind = error.get("type")
            name = "insufficient_quota" if "insufficient_quota" in (code, kind) else str(kind or code or "")
            message = error.get("message") or error.get("detail") or ""
            return name, redact(_clip(str(message)), self._key)
        return "", redact(_clip(str(error)), self._key)

    def _answers(self, response: httpx.Response, query: Query, n: int, latency: float) -> list[Answer]:
        where = f"{self.url}: HTTP 200 but"
        if not response.content.strip():
            raise ProviderError(f"{where} the body is empty; the server may be misconfigured")
        try:
            data = response.json()
        except (json.JSONDecodeError, UnicodeDecodeError, ValueError):
            raise ProviderError(
                f"{where} the body is not JSON ({redact(_clip(response.text, 80), self._key)!r}); "
                "is --base-url an OpenAI-compatible API root (ending in /v1)?"
            ) from None
        choices = data.get("choices") if isinstance(data, dict) else None
        if not isinstance(choices, list) or not choices:
            raise ProviderError(f"{where} the body has no choices ({redact(_clip(json.dumps(data), 120), self._key)})")
        texts: list[tuple[str, str | None]] = []
        for choice in sorted(choices, key=lambda c: c.get("index", 0) if isinstance(c, dict) else 0):
            message = choice.get("message") if isinstance(choice, dict) else None
            if not isinstance(message, dict):
                raise ProviderError(f"{where} a choice has no message ({_clip(json.dumps(choice), 120)})")
            content = message.get("content")
            if content is not None and not isinstance(content, str):
                raise ProviderError(f"{where} a message's content is not text ({type(content).__name__})")
            finish = choice.get("finish_reason")
            texts.append((content or "", finish if isinstance(finish, str) else None))
        texts = texts[:n]
        raw_usage = data.get("usage")
        usage_known = isinstance(raw_usage, dict)
        usage = raw_usage if isinstance(raw_usage, dict) else {}
        details = usage.get("prompt_tokens_details") or {}
        prompt = _int(usage.get("prompt_tokens"))
        completion = _int(usage.get("completion_tokens"))
        cached = _int(details.get("cached_tokens")) if isinstance(details, dict) else 0
        # The server reports usage for the whole request; with several choices it is shared out
        # evenly (integer parts that sum to the totals), so summed costs equal the request's.
        parts = len(texts)
        model = data.get("model") if isinstance(data.get("model"), str) else query.model
        fingerprint = data.get("system_fingerprint")
        response_id = data.get("id") if isinstance(data.get("id"), str) else None
        answers = []
        for (text, finish), p, c, k in zip(
            texts, _split(prompt, parts), _split(completion, parts), _split(cached, parts), strict=True
        ):
            share = Usage(p, c, k)
            cost = self.prices.cost(share, model, query.model) if usage_known else None
            answers.append(
                Answer(
                    text=text,
                    source="live",
                    model=model,
                    usage=share,
                    finish_reason=finish,
                    latency_s=latency,
                    cost_usd=cost,
                    system_fingerprint=fingerprint if isinstance(fingerprint, str) else None,
                    response_id=response_id,
                )
            )
        return answers


def _int(value: Any) -> int:
    return int(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0 else 0
