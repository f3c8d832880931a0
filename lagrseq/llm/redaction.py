"""Keeping the API key out of everything a server sends back: :mod:`lagrseq.keys` (moved there so
the logs, the stores and the command line, below and beside ``llm``, use the same guard)."""

from __future__ import annotations

from lagrseq.keys import MARK, MIN_FRAGMENT, Redactor, clip, redact_key_like

__all__ = ["MARK", "MIN_FRAGMENT", "Redactor", "clip", "redact_key_like"]
