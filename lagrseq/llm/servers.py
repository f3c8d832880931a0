"""What lagrseq knows about kinds of OpenAI-compatible servers (stdlib only, so the command line
can list them without importing httpx)."""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_BASE_URL = "https://api.openai.com/v1"


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
