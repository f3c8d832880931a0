"""One small tree of lagrseq errors; callers catch :class:`LagrseqError`.

Foreign exceptions (tomllib, json, mcap, httpx, pickle) are caught where they enter lagrseq and
re-raised as one of these, so the command line can print a single line and exit with status 2::

    LagrseqError
    ├── ConfigError          bad configuration: unknown field, bad value, unknown preset
    ├── UsageError           bad command-line usage: unknown task, method, provider
    ├── ParseError           an LLM answer that cannot be read as a solution (usually logged, not raised)
    ├── ProviderError        an LLM provider failed (missing key, HTTP error, malformed body, cache miss)
    │   ├── StoreError       a recorded store, JSONL file or authors' pickle that cannot be used
    │   │   └── RecordMiss   a query with no recorded answer (strict mode)
    │   └── BudgetExceeded   the next call would pass --max-cost-usd or --max-queries (not sent)
    ├── LogError             an MCAP log that cannot be written or read (truncated, corrupt, wrong schema)
    └── TrialsFailed         some trials of a sweep failed (the others finished); says which and what to do

Every message says what was expected, what was found and, where there is one, what to do.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


class LagrseqError(Exception):
    """Base class of every error lagrseq raises on purpose."""


class ConfigError(LagrseqError):
    """Invalid configuration (field, value or file)."""


class UsageError(LagrseqError):
    """Invalid command-line usage."""


class ParseError(LagrseqError):
    """An LLM answer that cannot be parsed into a solution."""


class ProviderError(LagrseqError):
    """An LLM provider could not produce an answer."""


class StoreError(ProviderError):
    """A recorded-answer store, JSONL export or authors' cache that cannot be read or written."""


class RecordMiss(StoreError):
    """A query whose key has no recorded answer, in a mode that may not ask anyone else."""


class BudgetExceeded(ProviderError):
    """A call was not sent because it could take the spending past a configured limit."""


class LogError(LagrseqError):
    """An MCAP log that cannot be written or read."""


class RecordError(LogError):
    """A record a task's env made that its task does not declare (an undeclared field, a value
    of another type, a non-finite number, text that is not valid UTF-8): deterministic, the same
    trial makes it again."""


class TrialsFailed(LagrseqError):
    """Some trials of a sweep raised; the others ran to their end. ``runs``: what failed, one
    entry per run (:class:`lagrseq.running.runner.RunFailures`), for a caller that reports each
    run apart (``lagrseq reproduce``)."""

    def __init__(self, message: str, runs: Sequence[Any] = ()) -> None:
        super().__init__(message)
        self.runs = tuple(runs)
