"""The options of the built-in provider kinds, one frozen dataclass per kind, each field set by
the command-line flag declared on it (``lagrseq.registry.flag``).

Where answers come from, not what the experiment is, so these are command-line options rather
than config fields; they are written into each trial's metadata (``registry.logged_options``).
The API key is never here, only the name of its variable. ``mock`` has no options; ``live`` is
:class:`LiveOptions`, ``recorded`` :class:`RecordedOptions` (its misses and what a live fallback
needs), ``local`` :class:`LocalOptions`. The settings several kinds share are small dataclasses
composed into them: :class:`HttpLimits` (timeouts, response cap) and :class:`Limits` (budget).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lagrseq.config import number_type
from lagrseq.errors import UsageError
from lagrseq.llm.servers import DEFAULT_BASE_URL, SERVER_KINDS, base_url_problem
from lagrseq.registry import NOT_LOGGED, flag
from lagrseq.registry import ON_MISS as ON_MISS  # defined below the suite file, which checks it too


@dataclass(frozen=True)
class HttpLimits:
    """How long and how much one HTTP request may take (the live server, the local one)."""

    read_timeout_s: float = field(default=120.0, metadata=flag(
        "--read-timeout", "seconds to wait for the next bytes of a response (default {default:g})",
        metavar="S", type=number_type("seconds", gt=0, le=86_400)))
    """Seconds to wait for the next bytes of a response."""
    request_deadline_s: float = field(default=300.0, metadata=flag(
        "--request-deadline", "seconds one whole request may take, then retried (default {default:g})",
        metavar="S", type=number_type("seconds", gt=0, le=86_400)))
    """Most seconds one request may take, from sending to the last byte (retried like a timeout)."""
    max_response_bytes: int = field(default=4 * 1024 * 1024, metadata=flag(
        "--max-response-bytes", "largest response body in bytes; a larger one fails (default {default})",
        metavar="N", type=number_type("bytes", integer=True, ge=1024, le=2**31)))
    """Largest response body read, decompressed (a larger one fails at once, not retried)."""


@dataclass(frozen=True)
class Limits:
    """A budget of answers that may cost (per run with a ``budget_ledger``: every trial and
    worker together; else per provider)."""

    max_cost_usd: float | None = field(default=None, metadata=flag(
        "--max-cost-usd", "per {per}: stop before a live request could pass X US dollars",
        metavar="X", type=number_type("US dollars", ge=0, le=1e6)))
    """Stop before a request that could pass this many US dollars."""
    max_queries: int | None = field(default=None, metadata=flag(
        "--max-queries", "per {per}: stop before a live request would pass N live answers",
        metavar="N", type=number_type("queries", integer=True, ge=0, le=10**9)))
    """Stop before a request that would pass this many answers."""
    budget_ledger: str | None = field(default=None, metadata=NOT_LOGGED)
    """SQLite file holding one budget for every trial and worker of a run (set by the runner when
    a limit is given; not logged: it says where, not what)."""

    @property
    def limited(self) -> bool:
        return self.max_cost_usd is not None or self.max_queries is not None


@dataclass(frozen=True)
class LiveOptions:
    """``live[:MODEL]``: an OpenAI-compatible server asked now."""

    base_url: str = field(default=DEFAULT_BASE_URL, metadata=flag(
        "--base-url", "OpenAI-compatible API root (default: {default})", metavar="URL"))
    """API root of the live server; its host is also part of every recorded key."""
    api_key_env: str = field(default="OPENAI_API_KEY", metadata=flag(
        "--api-key-env", "variable holding the key, never written (default: {default})", metavar="NAME"))
    """Environment variable holding the API key."""
    server: str = field(default="openai", metadata=flag(
        "--server", f"kind of server: {'|'.join(SERVER_KINDS)} (default: {{default}})",
        metavar="KIND", choices=tuple(SERVER_KINDS)))
    """Kind of OpenAI-compatible server (whether it honours ``n``)."""
    price_table: str | None = field(default=None, metadata=flag(
        "--price-table", "prices (USD per million tokens) over the built-in dated table", metavar="FILE.toml"))
    """TOML file of prices over the built-in table."""
    http: HttpLimits = field(default_factory=HttpLimits)
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        problem = base_url_problem(self.base_url, self.api_key_env if isinstance(self.api_key_env, str) else None)
        if problem is not None:
            raise UsageError(problem)


@dataclass(frozen=True)
class RecordedOptions:
    """``recorded:STORE``: answers from a store, keyed under ``live.base_url``'s host; a miss is
    answered as ``on_miss`` says (``live``: asked with ``live`` and recorded)."""

    on_miss: str = field(default="error", metadata=flag(
        "--on-miss", f"recorded misses: {'|'.join(ON_MISS)} (default {{default}})",
        metavar="MODE", choices=ON_MISS))
    """What answers a query the store lacks (error | mock | live | refuse | calibrated)."""
    live: LiveOptions = field(default_factory=LiveOptions)
    """The store's endpoint (``base_url``) and, with ``on_miss = live``, the server asked."""

    def __post_init__(self) -> None:
        if self.on_miss not in ON_MISS:
            raise UsageError(f"--on-miss {self.on_miss!r}; expected one of {', '.join(ON_MISS)}")

    @property
    def pays(self) -> bool:
        """Its misses are asked live (and may cost money)."""
        return self.on_miss == "live"


@dataclass(frozen=True)
class LocalOptions:
    """``local[:MODEL.gguf]``: a llama.cpp server started on this machine for the run."""

    n_ctx: int = field(default=2048, metadata=flag(
        "--n-ctx", "local server's context size in tokens (default {default})",
        metavar="N", type=number_type("tokens", integer=True, ge=64, le=2**20), logged_as="local_n_ctx"))
    """The llama.cpp server's context size in tokens."""
    threads: int = field(default=0, metadata=flag(
        "--threads", "local server's CPU threads (default 0: half the cores, at least 1)",
        metavar="N", type=number_type("threads", integer=True, ge=0, le=1024), logged_as="local_threads"))
    """The llama.cpp server's threads (0: half the cores, at least 1)."""
    http: HttpLimits = field(default_factory=HttpLimits)
    limits: Limits = field(default_factory=Limits)
