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

Limits, so that no server can hang a run or fill its memory (:class:`LiveSettings`):

- ``request_deadline_s`` (300 s): the most one request may take, from sending it to the last byte
  of the response. From the moment its connection opens, a watchdog shuts that connection down
  at the deadline, so even a server that sends its headers or body a byte a second for ever is cut
  off on time; connecting is limited to the smaller of its timeout and the deadline. An overrun
  counts as a timeout: retried, within ``max_retries``.
- ``read_timeout_s`` (120 s): the longest wait for the next bytes of a response (a timeout,
  retried).
- ``max_response_bytes`` (4 MiB, some thousand times a chat completion): the largest body read,
  counted after decompression (lagrseq asks for gzip or deflate only and decompresses in bounded
  steps, so a compressed bomb is stopped at the cap too). A larger body, or a larger declared
  ``Content-Length``, fails the request at once and is not retried: the same server would send it
  again.

Token counts are not taken on trust either: the usage a server reports is believed up to what the
request can have used (:func:`believed_usage`): completion tokens up to ``n * max_tokens``, prompt
tokens up to :func:`~lagrseq.llm.pricing.prompt_token_bound` (the bound the budget guard uses), and
a missing, negative or fractional count is unknown and counted as that bound. ``on_warning`` is told
once per kind of distrust.

Every failure is one :class:`~lagrseq.errors.ProviderError` line saying what happened and what to
do. The API key is read from the environment (``OPENAI_API_KEY`` or the variable named by
``--api-key-env``), must be printable ASCII (HTTP headers carry nothing else), is kept in a
:class:`Secret` that never prints, sent only in the ``Authorization`` header, and redacted, whole
or in recognisable part (:mod:`lagrseq.keys`), from every string the server sends back
before it reaches an answer, a store, an exception or a callback.
"""

from __future__ import annotations

import contextlib
import email.utils
import json
import math
import os
import re
import socket
import threading
import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np

from lagrseq import __version__, keys
from lagrseq.errors import ConfigError, ProviderError
from lagrseq.keys import Redactor, clip, redact_key_like
from lagrseq.llm.base import Answer, Query, Usage, samplers_of, with_samplers
from lagrseq.llm.pricing import PriceTable, prompt_token_bound
from lagrseq.llm.records import MAX_ANSWER_CHARS
from lagrseq.llm.servers import DEFAULT_BASE_URL, SERVER_KINDS, base_url_problem
from lagrseq.llm.store import endpoint_of
from lagrseq.text import printable

CLIPPED = "lagrseq-clipped"
"""``finish_reason`` of an answer cut to MAX_ANSWER_CHARS (the same limit as the task parsers')."""


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
    """Seconds to wait for the next bytes of a response (at most ``request_deadline_s``)."""
    request_deadline_s: float = 300.0
    """Seconds one request may take, from sending it to the last byte of the response; an overrun
    is a failed attempt, retried like a timeout."""
    max_response_bytes: int = 4 * 1024 * 1024
    """Largest response body read (after decompression); a larger one fails the request, not
    retried."""
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
            raise ConfigError(
                f"unknown server kind {self.server!r}; expected one of {', '.join(SERVER_KINDS)}"
            )
        _check_key_env(self.api_key_env)
        problem = base_url_problem(self.base_url, self.api_key_env)
        if problem is not None:
            raise ConfigError(problem)
        for name in ("connect_timeout_s", "read_timeout_s", "request_deadline_s"):
            _check_setting(name, getattr(self, name), "a finite number of seconds > 0", low=0.0, low_ok=False)
        for name in ("backoff_initial_s", "backoff_max_s", "max_retry_after_s"):
            _check_setting(name, getattr(self, name), "a finite number of seconds >= 0", low=0.0)
        _check_setting("jitter", self.jitter, "a number from 0 to 1", low=0.0, high=1.0)
        _check_setting("max_retries", self.max_retries, "a whole number >= 0", low=0, integer=True)
        _check_setting("max_response_bytes", self.max_response_bytes, "a whole number of bytes >= 1", low=1, integer=True)


_ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,127}")


def _check_key_env(name: Any) -> None:
    """Raise ConfigError unless ``name`` can be the name of an environment variable and does not
    look like an API key (someone passing the key itself to --api-key-env): the message never
    repeats it, since the name appears in other messages."""
    ok = isinstance(name, str) and _ENV_NAME.fullmatch(name) is not None
    looks_like_key = ok and len(name) >= 20 and "_" not in name and not name.isupper() and any(c.isdigit() for c in name)
    if not ok or looks_like_key:
        what = "looks like an API key itself" if looks_like_key or (isinstance(name, str) and redact_key_like(name) != name) else (
            "is not the name of an environment variable (letters, digits and _, not starting with a digit)")
        raise ConfigError(
            f"the value given to --api-key-env (api_key_env, {len(name) if isinstance(name, str) else 0} characters; not "
            f"shown) {what}: export the key in a variable, e.g. OPENAI_API_KEY, and pass that variable's name"
        )


def _check_setting(
    name: str, value: Any, expected: str, low: float, low_ok: bool = True, high: float | None = None, integer: bool = False
) -> None:
    """Raise ConfigError unless ``value`` is a finite number (an int if ``integer``) in range."""
    if isinstance(value, bool) or not isinstance(value, int if integer else (int, float)):
        ok = False
    else:
        ok = (isinstance(value, int) or math.isfinite(value)) and (value >= low if low_ok else value > low)
        ok = ok and (high is None or value <= high)
    if not ok:
        raise ConfigError(f"live setting {name} = {value!r} is out of range: expected {expected}")


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


def redact(text: str, secret: Secret | None) -> str:
    """``text`` with the key, its recognisable fragments and anything that looks like an API key
    blanked out (for messages; answers go through :class:`~lagrseq.keys.Redactor` only)."""
    if secret and secret.reveal():
        text = Redactor(secret.reveal()).text(text)
    return redact_key_like(text)


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

    def __init__(self, reason: str, retry_after: float | None = None, status: int | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.retry_after = retry_after
        self.status = status


class SharedBackoff:
    """One backoff for every request in flight (``lagrseq record --concurrency N``): when the
    server answers 429, no request is sent by any thread until the wait is over, so N threads do
    not each hammer a server that asked them all to slow down. ``sleep`` and ``clock`` are for
    tests."""

    def __init__(self, sleep: Callable[[float], None] = time.sleep, clock: Callable[[], float] = time.monotonic) -> None:
        self._sleep = sleep
        self._clock = clock
        self._lock = threading.Lock()
        self._until = 0.0
        self.holds = 0
        """How many times a 429 paused everyone."""

    def hold(self, delay: float) -> None:
        """Pause every request (this one included) for ``delay`` seconds from now."""
        with self._lock:
            self._until = max(self._until, self._clock() + max(delay, 0.0))
            self.holds += 1

    def wait(self) -> None:
        """Return once no pause is in force."""
        while True:
            with self._lock:
                left = self._until - self._clock()
            if left <= 0:
                return
            self._sleep(left)


class _Watchdog:
    """Shuts a request's connection down at ``deadline`` (a perf_counter time), so that nothing
    the server does (stalling, or sending its status line, headers or body a byte at a time, each
    within the read timeout) outlasts the deadline.

    The socket is learnt through httpx's public ``trace`` request extension the moment the
    connection opens (and again after TLS wraps it), before a byte is sent; the client keeps no
    idle connections, so every request opens one and is watched from its first byte. Without a
    socket to shut (a mock transport), the reader's own deadline checks remain."""

    def __init__(self, deadline: float) -> None:
        self.deadline = deadline
        self.fired = False
        self._lock = threading.Lock()
        self._done = False
        self._sock: socket.socket | None = None
        self._timer: threading.Timer | None = None

    def trace(self, event: str, info: Mapping[str, Any]) -> None:
        """The ``trace`` extension's callback: watch each connection the request opens."""
        if event.endswith((".connect_tcp.complete", ".connect_unix_socket.complete", ".start_tls.complete")):
            self.watch(info.get("return_value"))

    def watch(self, stream: Any) -> None:
        """Shut ``stream``'s socket at the deadline (a stream without one is left alone)."""
        try:
            sock = stream.get_extra_info("socket") if stream is not None else None
        except Exception:  # an unusual transport: no socket to shut
            sock = None
        if not isinstance(sock, socket.socket):
            return
        with self._lock:
            if self._done:
                return
            self._sock = sock  # after TLS, the wrapping socket (the plain one is detached)
            if self._timer is None:
                self._timer = threading.Timer(max(self.deadline - time.perf_counter(), 0.0), self._fire)
                self._timer.daemon = True
                self._timer.start()

    def _fire(self) -> None:
        with self._lock:
            if self._done or self._sock is None:
                return
            self.fired = True
            # the plain socket's shutdown (an SSL socket's own would unwrap it under the reader)
            with contextlib.suppress(OSError):
                socket.socket.shutdown(self._sock, socket.SHUT_RDWR)

    def cancel(self) -> None:
        with self._lock:
            self._done = True
        if self._timer is not None:
            self._timer.cancel()


_LIMITS = httpx.Limits(max_keepalive_connections=0)
"""No idle connections: every request opens its own, so its watchdog sees it open (a reused
connection would give the trace nothing to report). A new connection per chat completion costs a
handshake, small beside the completion itself."""


def status_of(url: str, seconds: float) -> int | None:
    """The HTTP status of ``GET url``, whatever the server does, within ``seconds`` in all
    (connecting, sending, and every byte of the status line and headers); the body is not read.
    None when no status came in time or the connection failed. For readiness probes (the local
    llama.cpp server's ``/v1/models``), where a foreign server on the port might drip for ever."""
    watchdog = _Watchdog(time.perf_counter() + seconds)
    with httpx.Client(timeout=seconds, follow_redirects=False, limits=_LIMITS) as client:
        try:
            with client.stream("GET", url, extensions={"trace": watchdog.trace}) as response:
                return response.status_code
        except httpx.HTTPError:
            return None
        finally:
            watchdog.cancel()


class _Decoder:
    """Undoes the response's Content-Encoding (none, gzip or deflate) in steps that never produce
    more than the room left under the size cap, so a compressed bomb costs no more memory than the
    cap. Any other encoding is refused (lagrseq asks for gzip or deflate only)."""

    def __init__(self, encoding: str, url: str, redactor: Redactor | None = None) -> None:
        self.url = url
        name = encoding.strip().lower()
        self._raw_fallback = False
        if name in ("", "identity"):
            self._z: Any = None
        elif name in ("gzip", "x-gzip"):
            self._z = zlib.decompressobj(zlib.MAX_WBITS | 16)
        elif name == "deflate":
            self._z = zlib.decompressobj()
            self._raw_fallback = True  # "deflate" is zlib-wrapped by the standard, raw by some servers
        else:
            raise ProviderError(
                f"{url}: the response is encoded as {_shown_header(name, redactor)!r}, which lagrseq did not ask for "
                "(it accepts gzip and deflate); check --base-url and any proxy in between"
            )

    def decode(self, data: bytes, room: int) -> bytes:
        """At most ``room + 1`` decoded bytes of ``data`` (more than ``room``: over the cap)."""
        if self._z is None:
            return data[: room + 1]
        try:
            return bytes(self._z.decompress(data, room + 1))
        except zlib.error:
            if not self._raw_fallback:
                raise self._bad() from None
            self._raw_fallback = False
            self._z = zlib.decompressobj(-zlib.MAX_WBITS)
            return self.decode(data, room)
        finally:
            self._raw_fallback = False

    def flush(self, room: int) -> bytes:
        if self._z is None:
            return b""
        try:
            return bytes(self._z.flush())[: room + 1]
        except zlib.error:
            raise self._bad() from None

    def _bad(self) -> ProviderError:
        return ProviderError(f"{self.url}: the compressed response is damaged; check the server")


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
        on_warning: Callable[[str], None] | None = None,
        backoff: SharedBackoff | None = None,
    ) -> None:
        self.settings = settings or LiveSettings()
        self.backoff = backoff
        """Shared by the threads of a concurrent recording: a 429 pauses them all."""
        self._rng_lock = threading.Lock()
        self.kind = SERVER_KINDS[self.settings.server]
        self.endpoint = endpoint_of(self.settings.base_url)
        if self.settings.base_url.split("://", 1)[0].lower() not in ("http", "https") or any(ord(ch) <= 32 for ch in self.settings.base_url):
            raise ConfigError("--base-url (not shown): expected an http:// or https:// URL without spaces or control characters, e.g. https://api.openai.com/v1")
        self.url = self.settings.base_url.rstrip("/") + "/chat/completions"
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.prices = prices if prices is not None else PriceTable()
        self.on_retry = on_retry
        self.on_warning = on_warning if on_warning is not None else on_retry
        """Told once per kind of distrusted usage (defaults to ``on_retry``)."""
        self._warned: set[str] = set()
        self._sleep = sleep
        value = (os.environ if environ is None else environ).get(self.settings.api_key_env, "")
        self._key = Secret(_checked_key(value.strip(), self.settings.api_key_env))
        self._redactor = Redactor(self._key.reveal())
        if not self._key and (self.endpoint == "api.openai.com" or self.settings.api_key_env != "OPENAI_API_KEY"):
            raise ProviderError(
                f"environment variable {self.settings.api_key_env} is not set; export your API key "
                "there, or name another variable with --api-key-env"
            )
        s = self.settings
        # Every phase is limited by the request deadline too (see the module docstring).
        self._timeout = httpx.Timeout(
            min(s.read_timeout_s, s.request_deadline_s),
            connect=min(s.connect_timeout_s, s.request_deadline_s),
            write=min(s.connect_timeout_s, s.request_deadline_s),
            pool=min(s.connect_timeout_s, s.request_deadline_s),
        )
        self._client = httpx.Client(timeout=self._timeout, transport=transport, follow_redirects=False, limits=_LIMITS)
        self.deadline_bound = transport is None
        """Every request's connection is watched from its first byte (httpx's own transports
        report their connections to the ``trace`` extension; one passed in may not)."""
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
        query = self.pin(query)
        answers: list[Answer] = []
        while len(answers) < n:
            ask = min(n - len(answers), self.kind.max_samples_per_request)
            answers.extend(self._request(query, ask))
        return answers[:n]

    def pin(self, query: Query) -> Query:
        """``query`` with the samplers this server kind pins (llama.cpp: ``top_k`` 0, ``min_p`` 0,
        ``repeat_penalty`` 1, so that ``temperature`` means OpenAI's; others: unchanged)."""
        return with_samplers(query, self.kind.samplers)

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
        body.update(samplers_of(query))  # llama.cpp's, when pinned (never sent to OpenAI)
        return body

    def _headers(self) -> dict[str, str]:
        headers = {
            "Content-Type": "application/json",
            "Accept": "application/json",
            "Accept-Encoding": "gzip, deflate",  # what _Decoder undoes in bounded steps
            "User-Agent": f"lagrseq/{__version__}",
        }
        if self._key:
            headers["Authorization"] = f"Bearer {self._key.reveal()}"
        return headers

    def _request(self, query: Query, n: int) -> list[Answer]:
        if self._closed:
            raise ProviderError("the live provider is closed")
        if self._redactor.holds(query.model) or keys.holds_key(query.model):  # before anything is paid for
            raise ConfigError(
                "the model name (not shown) holds the API key or 8 or more characters of it: it would be written "
                "into every store key and log; give the model's name (--model, live:MODEL)"
            )
        body = self.body(query, n)
        attempts = self.settings.max_retries + 1
        last = ""
        for attempt in range(attempts):
            if self.backoff is not None:
                self.backoff.wait()
            try:
                return self._attempt(query, body, n)
            except _Retry as retry:
                last = retry.reason
                if attempt + 1 >= attempts:
                    break
                delay = self._delay(attempt, retry.retry_after, retry.reason)
                shared = self.backoff is not None and retry.status == 429
                if self.on_retry is not None:
                    everyone = " (every request in flight waits)" if shared else ""
                    self.on_retry(f"{retry.reason}; retrying in {delay:.2f} s{everyone} ({attempt + 1}/{self.settings.max_retries})")
                if shared:
                    assert self.backoff is not None
                    self.backoff.hold(delay)
                else:
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
        with self._rng_lock:  # one generator, several recording threads
            draw = float(self.rng.random())
        return delay * (1.0 - s.jitter * draw)

    def _attempt(self, query: Query, body: dict[str, Any], n: int) -> list[Answer]:
        s = self.settings
        started = time.perf_counter()
        deadline = started + s.request_deadline_s
        watchdog = _Watchdog(deadline)
        extensions = {"trace": watchdog.trace}
        try:
            with self._client.stream("POST", self.url, json=body, headers=self._headers(), extensions=extensions) as response:
                watchdog.watch(response.extensions.get("network_stream"))  # a transport that traced nothing
                try:
                    data = self._read(response, deadline, watchdog)
                except _Retry:
                    raise
                except (httpx.HTTPError, ProviderError):
                    if watchdog.fired:
                        raise self._overrun() from None
                    raise
                except Exception:  # a read interrupted by the watchdog (e.g. an unwrapped TLS socket)
                    if watchdog.fired:
                        raise self._overrun() from None
                    raise
                finally:
                    watchdog.cancel()
        except httpx.TimeoutException as exc:
            watchdog.cancel()
            if watchdog.fired or time.perf_counter() - started >= s.request_deadline_s * 0.999:
                raise self._overrun() from None
            phase = {"ConnectTimeout": "connect", "ReadTimeout": "read", "WriteTimeout": "write", "PoolTimeout": "pool"}
            which = phase.get(type(exc).__name__, "")
            limit = self._timeout.read if which == "read" else self._timeout.connect
            raise _Retry(f"no response within the {limit:g} s {which} timeout".replace("  ", " ")) from None
        except (httpx.NetworkError, httpx.RemoteProtocolError) as exc:
            if watchdog.fired:  # the deadline shut the connection before the response began
                raise self._overrun() from None
            raise _Retry(f"connection failed ({type(exc).__name__}: {self._redactor.diagnostic(str(exc))})") from None
        except httpx.HTTPError as exc:  # bad URL, unsupported scheme, proxy trouble: not transient
            raise ProviderError(
                f"{self.url}: cannot send the request ({type(exc).__name__}: {self._redactor.diagnostic(str(exc))}); "
                "check --base-url"
            ) from None
        finally:
            watchdog.cancel()
        latency = time.perf_counter() - started
        if response.status_code != 200:
            self._refuse(response.status_code, response.headers, data, query)
        return self._answers(data, query, n, latency)

    def _overrun(self) -> _Retry:
        return _Retry(
            f"the response did not end within the {self.settings.request_deadline_s:g} s request deadline"
        )

    def _read(self, response: httpx.Response, deadline: float, watchdog: _Watchdog) -> bytes:
        """The body of ``response``, decoded, at most ``max_response_bytes``; _Retry past the
        deadline, ProviderError (not retried) when it is larger."""
        limit = self.settings.max_response_bytes
        declared = response.headers.get("content-length", "").strip()
        if declared.isdigit() and len(declared) < 30 and int(declared) > limit:
            raise self._too_large(f"it declares {int(declared)} bytes")
        decoder = _Decoder(response.headers.get("content-encoding", ""), self.url, self._redactor)
        chunks: list[bytes] = []
        size = 0
        for raw in response.iter_raw():
            piece = decoder.decode(raw, limit - size)
            size += len(piece)
            if size > limit:
                raise self._too_large("it went on past that")
            chunks.append(piece)
            if time.perf_counter() > deadline:
                raise self._overrun()
        tail = decoder.flush(limit - size)
        if size + len(tail) > limit:
            raise self._too_large("it went on past that")
        if watchdog.fired:  # the body "ended" because the watchdog closed the connection
            raise self._overrun()
        chunks.append(tail)
        return b"".join(chunks)

    def _too_large(self, what: str) -> ProviderError:
        return ProviderError(
            f"{self.url}: the response is larger than max_response_bytes = {self.settings.max_response_bytes} "
            f"({what}); not retried: a chat completion is far smaller, so check --base-url, or raise "
            "--max-response-bytes for a server you trust"
        )

    def _refuse(self, status: int, headers: httpx.Headers, data: bytes, query: Query) -> None:
        """Raise for a non-200 response: ``_Retry`` if it is worth retrying, else ProviderError."""
        kind, message = self._error_of(data)
        said = f"HTTP {status}" + (f" {kind}" if kind else "") + (f": {message}" if message else "")
        should = headers.get("x-should-retry", "").strip().lower()
        if kind == "insufficient_quota":
            raise ProviderError(
                f"{self.url}: {said}; the account behind {self.settings.api_key_env} has no quota left "
                "(not retried): add credit or use another key"
            )
        retryable = status in (408, 409, 429) or status >= 500
        if should == "true" or (retryable and should != "false"):
            raise _Retry(said, parse_retry_after(headers), status)
        hint = {
            400: "the server rejected the request",
            401: f"the key in {self.settings.api_key_env} was refused; check it",
            403: f"the key may not use model {query.model!r} here",
            404: f"no model {query.model!r} or no /chat/completions at {self.settings.base_url}; check --base-url and the model name",
            422: "the server could not process the request",
        }.get(status, "not retried")
        raise ProviderError(f"{self.url}: {said}; {hint}")

    def _error_of(self, data: bytes) -> tuple[str, str]:
        """(error type or code, message) from an error body in OpenAI's or vLLM's shape, redacted."""
        show = self._redactor
        try:
            parsed = json.loads(data)
        except (ValueError, RecursionError):  # not JSON, not UTF-8, or nested past Python's limit
            return "", show.diagnostic(data[:4096].decode("utf-8", "replace"))
        error = parsed.get("error", parsed) if isinstance(parsed, dict) else parsed
        if isinstance(error, dict):
            code = error.get("code")
            kind = error.get("type")
            if "insufficient_quota" in (code, kind):
                name = "insufficient_quota"
            else:
                name = show.diagnostic(str(kind or code or ""), 60) if isinstance(kind or code or "", (str, int)) else ""
            message = error.get("message") or error.get("detail") or ""
            return name, show.diagnostic(message) if isinstance(message, str) else show.shown(message, 200)
        return "", show.shown(error, 200)

    def _answers(self, data: bytes, query: Query, n: int, latency: float) -> list[Answer]:
        where = f"{self.url}: HTTP 200 but"
        show = self._redactor
        if not data.strip():
            raise ProviderError(f"{where} the body is empty; the server may be misconfigured")
        try:
            parsed = json.loads(data)
        except (ValueError, RecursionError):
            raise ProviderError(
                f"{where} the body is not JSON ({show.diagnostic(data[:4096].decode('utf-8', 'replace'), 80)!r}); "
                "is --base-url an OpenAI-compatible API root (ending in /v1)?"
            ) from None
        choices = parsed.get("choices") if isinstance(parsed, dict) else None
        if not isinstance(choices, list) or not choices:
            raise ProviderError(f"{where} the body has no choices ({show.shown(parsed)})")
        texts: list[tuple[str, str | None]] = []
        for choice in sorted(choices, key=_choice_index):
            message = choice.get("message") if isinstance(choice, dict) else None
            if not isinstance(message, dict):
                raise ProviderError(f"{where} a choice has no message ({show.shown(choice)})")
            content = message.get("content")
            if content is not None and not isinstance(content, str):
                raise ProviderError(f"{where} a message's content is not text ({type(content).__name__})")
            texts.append((_unicode(show.text(content or "")) or "", _unicode(show.optional(choice.get("finish_reason")))))
        texts = texts[:n]
        usage, notes = believed_usage(parsed.get("usage"), query, n)
        for kind, note in notes:
            self._warn(kind, note)
        # The server reports usage for the whole request; with several choices it is shared out
        # evenly (integer parts that sum to the totals), so summed costs equal the request's.
        parts = len(texts)
        model = _unicode(show.optional(parsed.get("model"))) or query.model
        fingerprint = _unicode(show.optional(parsed.get("system_fingerprint")))
        response_id = _unicode(show.optional(parsed.get("id")))
        answers = []
        for index, (text, _finish) in enumerate(texts):
            if len(text) > MAX_ANSWER_CHARS:
                # Nothing longer is stored or parsed: keep the start, and say so in finish_reason.
                self._warn("clipped", f"an answer of {len(text)} characters was cut to {MAX_ANSWER_CHARS} (MAX_ANSWER_CHARS)")
                texts[index] = (text[:MAX_ANSWER_CHARS], CLIPPED)
        for (text, finish), p, c, k in zip(
            texts,
            _split(usage.prompt_tokens, parts),
            _split(usage.completion_tokens, parts),
            _split(usage.cached_tokens, parts),
            strict=True,
        ):
            share = Usage(p, c, k)
            answers.append(
                Answer(
                    text=text,
                    source="live",
                    model=model,
                    usage=share,
                    finish_reason=finish,
                    latency_s=latency,
                    cost_usd=self.prices.cost(share, model, query.model),
                    system_fingerprint=fingerprint,
                    response_id=response_id,
                )
            )
        return answers

    def _warn(self, kind: str, message: str) -> None:
        """Tell ``on_warning`` about one kind of distrusted usage, the first time it happens."""
        if kind in self._warned or self.on_warning is None:
            return
        self._warned.add(kind)
        self.on_warning(f"{self.url}: {message} (said once per run)")


def _shown_header(value: str, redactor: Redactor | None) -> str:
    """A header value a server sent, for a message: the key and its fragments blanked (this
    provider's and every guarded one) before it is cut to 40 characters, escaped."""
    if redactor is not None:
        value = redactor.text(value)
    return printable(clip(keys.scrub(value), 40))


_SURROGATE = re.compile("[\ud800-\udfff]")


def _unicode(text: str | None) -> str | None:
    """``text`` as valid Unicode: JSON's ``\\ud800`` escapes can smuggle lone surrogates into a
    string, which no store, log or terminal can write; each becomes U+FFFD."""
    if text is None or text.isascii():
        return text
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return _SURROGATE.sub("\ufffd", text)
    return text


def _choice_index(choice: Any) -> int:
    index = choice.get("index") if isinstance(choice, dict) else None
    return index if isinstance(index, int) and not isinstance(index, bool) else 0


def _checked_key(key: str, env: str) -> str:
    """``key`` if it can go in an HTTP header (printable ASCII, no spaces); else a ConfigError that
    names the variable and never shows the key."""
    for position, char in enumerate(key, 1):
        if not 0x21 <= ord(char) <= 0x7E:
            what = "a space or control character" if char.isascii() else "a character that is not ASCII"
            raise ConfigError(
                f"environment variable {env} holds an API key with {what} (character {position} of "
                f"{len(key)}); HTTP headers carry printable ASCII only: set the key again, copied "
                "without stray characters"
            )
    return key


# ---------------------------------------------------------------------------------------------
# Usage a server reports, believed only as far as the request allows
# ---------------------------------------------------------------------------------------------
def _count(value: Any) -> int | None:
    """A token count: a whole number >= 0 (an integral float too); None when it is not one."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        return None
    return int(value) if value >= 0 else None


def believed_usage(raw: Any, query: Query, n: int) -> tuple[Usage, list[tuple[str, str]]]:
    """The usage of one request for ``n`` samples of ``query``, as far as it can be believed, and
    ``(kind, note)`` for every count that was not taken as reported.

    A request cannot have used more than ``n * max_tokens`` completion tokens, nor more prompt
    tokens than :func:`~lagrseq.llm.pricing.prompt_token_bound` (one token per byte of every
    message plus the per-message and per-request overhead; a BPE token is never shorter than a
    byte), and cached tokens are part of the prompt. A count above its bound is capped to it; a
    count that is missing, negative, fractional or not a number is unknown and taken as the bound
    (the worst case, the one the budget guard assumed before sending). The prompt is paid once per
    request, whatever ``n``.
    """
    usage = raw if isinstance(raw, dict) else {}
    bounds = {"prompt_tokens": prompt_token_bound(query), "completion_tokens": max(int(n), 1) * max(int(query.max_tokens), 0)}
    notes: list[tuple[str, str]] = []
    believed: dict[str, int] = {}
    for name, bound in bounds.items():
        reported = _count(usage.get(name))
        if not isinstance(raw, dict):
            believed[name] = bound
            continue
        if reported is None:
            notes.append((f"invalid-{name}", f"the server reported {name} = {_shown_count(usage.get(name))}, not a "
                          f"whole number >= 0; counted as the worst case, {bound} for this request"))
            believed[name] = bound
        elif reported > bound:
            notes.append((f"capped-{name}", f"the server reported {name} = {reported}, more than the request can "
                          f"have used; counted {bound}"))
            believed[name] = bound
        else:
            believed[name] = reported
    if not isinstance(raw, dict):
        notes.append(("no-usage", "the server reported no usage; counted as the worst case "
                      f"({believed['prompt_tokens']} prompt and {believed['completion_tokens']} completion tokens a request)"))
    details = usage.get("prompt_tokens_details")
    cached_raw = details.get("cached_tokens") if isinstance(details, dict) else None
    cached = 0 if cached_raw is None else _count(cached_raw)
    if cached is None:
        notes.append(("invalid-cached_tokens", f"the server reported cached_tokens = {_shown_count(cached_raw)}, "
                      "not a whole number >= 0; counted 0 (billed at the full input rate)"))
        cached = 0
    elif cached > believed["prompt_tokens"]:
        notes.append(("capped-cached_tokens", f"the server reported cached_tokens = {cached}, more than the prompt "
                      f"tokens; counted {believed['prompt_tokens']}"))
        cached = believed["prompt_tokens"]
    return Usage(believed["prompt_tokens"], believed["completion_tokens"], cached), notes


def _shown_count(value: Any) -> str:
    """A reported count for a message: numbers as they are, anything else by its type only (a
    string from a server is never repeated)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return repr(value)
    return "missing" if value is None else f"a {type(value).__name__}"
