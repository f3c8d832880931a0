"""What lagrseq knows about kinds of OpenAI-compatible servers (stdlib only, so the command line
can list them without importing httpx)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from urllib.parse import unquote, urlsplit

DEFAULT_BASE_URL = "https://api.openai.com/v1"

_KEY_PREFIX = re.compile(r"(^|[^A-Za-z0-9])(sk|pk|rk|key|token|secret|api[_-]?key|bearer)[-_=:][A-Za-z0-9_\-*.~+/=]{6,}", re.IGNORECASE)
"""A segment that starts like an API key: ``sk-...``, ``key_...``, ``api-key=...``, ``token:...``."""
_RANDOM_RUN = re.compile(r"[A-Za-z0-9_\-+=]{32,}")
"""A long run of token characters (an unprefixed key, a JWT part, a base64 secret)."""


def key_like(text: str) -> bool:
    """``text`` (a host label or a path segment, percent-decoded) looks like a secret: an API key's
    prefix followed by at least 6 token characters, or a long run of token characters mixing
    digits and letters: at least 32 with both cases, or at least 40 (model names such as
    ``gpt-4o-mini-2024-07-18`` are shorter; a Cloudflare account id, 32 lower-case hex digits, is
    not taken for a key)."""
    decoded = unquote(text)
    if _KEY_PREFIX.search(decoded):
        return True
    for run in (m.group(0) for m in _RANDOM_RUN.finditer(decoded)):
        letters, digits = any(c.isalpha() for c in run), any(c.isdigit() for c in run)
        both_cases = any(c.isupper() for c in run) and any(c.islower() for c in run)
        if letters and digits and (both_cases or len(run) >= 40):
            return True
    return False


def base_url_problem(base_url: str, key_env: str | None = None) -> str | None:
    """Why ``base_url`` may not be used (it holds a guarded API key or a fragment of it of 8
    characters or more, :func:`lagrseq.keys.holds_key`, ``key_env`` being guarded too; it carries
    credentials: ``user:password@``, a query string, a fragment, or a key-like segment in its host
    or path (:func:`key_like`), which would be printed in messages and written into every trial's
    metadata), or None. The message never repeats the URL."""
    from lagrseq import keys

    if key_env is not None:
        keys.watch(key_env)
    if keys.holds_key(base_url):
        return (
            "--base-url holds the API key, or 8 or more characters of it (the URL is not shown; were "
            "--base-url and the key swapped?): give the API root, e.g. https://api.openai.com/v1, and "
            "keep the key in its environment variable (--api-key-env)"
        )
    try:
        parts = urlsplit(base_url if "://" in base_url else f"https://{base_url}")
        userinfo = parts.username is not None or parts.password is not None
    except ValueError:
        return "--base-url is not a URL; expected e.g. https://api.openai.com/v1"
    if userinfo or parts.query or parts.fragment or "?" in base_url or "#" in base_url:
        return (
            "--base-url carries credentials or parameters (user:password@, ?... or #...; the URL is not "
            "shown): they would be written into every log, so give the API root alone, e.g. "
            "https://api.openai.com/v1, and the key in an environment variable (--api-key-env)"
        )
    pieces = [*(parts.hostname or "").split("."), *(p for segment in parts.path.split("/") for p in segment.split(";"))]
    if any(key_like(piece) for piece in pieces if piece):
        return (
            "--base-url carries what looks like an API key in its host or path (the URL is not shown): it "
            "would be printed and written into every log, so give the API root without it, e.g. "
            "https://api.openai.com/v1, and the key in an environment variable (--api-key-env); a gateway "
            "that needs the key in its path cannot be used"
        )
    return None


@dataclass(frozen=True)
class ServerKind:
    """What differs between OpenAI-compatible servers and matters here."""

    name: str
    max_samples_per_request: int
    """How many samples one request may ask for with ``n`` (1: the server ignores ``n``, so
    lagrseq sends one request per sample)."""
    description: str
    samplers: tuple[tuple[str, float], ...] = ()
    """Sampler settings sent with every request and kept in its record key, so that the server's
    own defaults cannot change what ``temperature`` means (:func:`lagrseq.llm.base.with_samplers`)."""


LLAMA_CPP_SAMPLERS: tuple[tuple[str, float], ...] = (("top_k", 0), ("min_p", 0.0), ("repeat_penalty", 1.0))
"""OpenAI's meaning of temperature on llama.cpp's server: its defaults (llama-cpp-python's server:
``top_k`` 40, ``min_p`` 0.05, ``repeat_penalty`` 1.1) cut and reweight the distribution that
``temperature`` scales; pinned off, with ``top_p`` 1, tau samples the model's own softmax(logits / tau)."""


SERVER_KINDS: dict[str, ServerKind] = {
    "openai": ServerKind("openai", 128, "OpenAI's API: honours n (up to 128)"),
    "vllm": ServerKind("vllm", 128, "vLLM's OpenAI-compatible server: honours n"),
    "ollama": ServerKind("ollama", 1, "Ollama's /v1 endpoint: no n, one request per sample"),
    "llama.cpp": ServerKind("llama.cpp", 1, "llama.cpp's server: no n, one request per sample; top_k 0, min_p 0, repeat_penalty 1 sent (OpenAI's sampling)", LLAMA_CPP_SAMPLERS),
}

RECORD_MODES: tuple[str, ...] = ("once", "new", "none", "all")
"""vcrpy's record modes, as :mod:`lagrseq.llm.recorded` implements them."""
