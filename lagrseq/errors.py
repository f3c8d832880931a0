"""One small tree of lagrseq errors; callers catch :class:`LagrseqError`.

Foreign exceptions (tomllib, json, mcap, httpx, pickle) are caught where they enter lagrseq and
re-raised as one of these, so the command line can print a single line and exit with status 2::

    LagrseqError
    ├── ConfigError          bad configuration: unknown field, bad value, unknown preset
    ├── UsageError           bad command-line usage: unknown task, method, provider
    ├── ParseError           an LLM answer that cannot be read as a solution (usually logged, not raised)
    ├── ProviderError        an LLM provider failed (missing key, HTTP error, malformed body, cache miss)
    └── LogError             an MCAP log that cannot be written or read (truncated, corrupt, wrong schema)

Every message says what was expected, what was found and, where there is one, what to do.
"""

from __future__ import annotations


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


class LogError(LagrseqError):
    """An MCAP log that cannot be written or read."""
