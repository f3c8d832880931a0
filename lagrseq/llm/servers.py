"""What lagrseq knows about kinds of OpenAI-compatible servers (stdlib only, so the command line
can list them without importing httpx)."""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import urlsplit

DEFAULT_BASE_URL = "https://api.openai.com/v1"


def base_url_problem(base_url: str) -> str | None:
    """Why ``base_url`` may not be used (it carries credentials: ``user:password@``, a query
    string or a fragment, which would be printed in messages and written into every trial's
    metadata), or None. The message never repeats the URL."""
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
    return None


@dataclass(frozen=True)
class ServerKind:
    """What differs between OpenAI-compatible servers and matters here."""

    name: str
    max_samples_per_request: int
    """How many samples one request may ask for with ``n`` (1: the server ignores ``n``, so
    lagrseq sends one request per sample)."""
    description: str


SERVER_KINDS: dict[str, ServerKind] = {
    "openai": ServerKind("openai", 128, "OpenAI's API: honours n (up to 128)"),
    "vllm": ServerKind("vllm", 128, "vLLM's OpenAI-compatible server: honours n"),
    "ollama": ServerKind("ollama", 1, "Ollama's /v1 endpoint: no n, one request per sample"),
    "llama.cpp": ServerKind("llama.cpp", 1, "llama.cpp's server: no n, one request per sample"),
}

RECORD_MODES: tuple[str, ...] = ("once", "new", "none", "all")
"""vcrpy's record modes, as :mod:`lagrseq.llm.recorded` implements them."""
