"""A fake server's replies that echo the API key in every field, and scans of text and of
written files for any fragment of the key."""

from __future__ import annotations

import sqlite3
import string
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.keys import MIN_FRAGMENT, invisible
from lagrseq.llm.base import Query, user_query
from lagrseq.tasks import cube
from tests.llm.conftest import Reply, error_body

TASK = cube.CubeStacking(8)
ECHO_KEY = "sk-proj-" + "".join(np.random.default_rng(8).choice(list(string.ascii_letters + string.digits), 48))
"""The key of the echo tests: random, like a real one (the fixture's key has words in it, such as
LAGRSEQ-, that a store holds in its own right)."""


HARMLESS = "ANSWER-KEPT"
"""A word every echoed answer also carries: the file scan must find it (so it reads what was written)."""


def query(model: str = "gpt-4o-mini") -> Query:
    return user_query(TASK.name, TASK.prompt((4, 5, 6)), model, 0.0, 64)


def windows(key: str, width: int = MIN_FRAGMENT) -> set[str]:
    """Every ``width``-character substring of ``key``, lower-cased (a longer fragment holds one)."""
    low = key.lower()
    return {low[i : i + width] for i in range(len(low) - width + 1)} if len(low) >= width else {low}


def leaks(text: str, key: str = ECHO_KEY) -> list[str]:
    """Fragments of ``key`` (MIN_FRAGMENT characters or more, any case) found in ``text``."""
    low = text.lower()
    return sorted(w for w in windows(key) if w in low)


def visible(text: str) -> str:
    """``text`` without the characters the redactor skips (whitespace, format and control characters)."""
    return "".join(c for c in text if not invisible(c))


def echo_completion(key: str) -> dict[str, Any]:
    """A chat completion with the key in every field a response has, whole and in part."""
    return {
        "id": key[:20],  # the key split over two fields ...
        "object": key,
        "created": 1700000000,
        "model": key[20:] + "-" + key.upper(),  # ... and upper-cased
        "system_fingerprint": "fp_" + key[-20:],  # the part without sk-
        "choices": [
            {
                "index": 0,
                "message": {"role": "assistant", "content": f"{HARMLESS} {key} and {key[3:]} and {key[-20:]}", "refusal": key},
                "finish_reason": key,
                "logprobs": {"content": [{"token": key}]},
            }
        ],
        "usage": {"prompt_tokens": 10, "completion_tokens": 5, "total_tokens": key, "prompt_tokens_details": {"cached_tokens": 0}},
    }


def echo_headers(key: str) -> dict[str, str]:
    return {
        "x-request-id": key,
        "openai-organization": key[-20:],
        "retry-after": key,
        "set-cookie": f"session={key}",
        "x-should-retry": "true",
    }


def echoing(body: Callable[[str], Any], status: int = 200, retry: bool = False) -> Reply:
    def headers(key: str) -> dict[str, str]:
        found = echo_headers(key)
        if not retry:
            del found["x-should-retry"]
        return found

    return Reply(status, body, headers)


FAILURES: dict[str, list[Reply]] = {
    "a choice without a message": [echoing(lambda k: {"id": k, "choices": [{"index": 0, "text": k, "message": k}]})],
    "no choices": [echoing(lambda k: {"id": k, "model": k, "choices": [], "error": k})],
    "a body that is not JSON": [echoing(lambda k: f"<html>{k} {k[-20:]}</html>")],
    "content that is not text": [echoing(lambda k: {"choices": [{"index": 0, "message": {"content": {"k": k}}}]})],
    "HTTP 400": [echoing(lambda k: error_body(k, f"bad request from {k}", k), 400)],
    "HTTP 401": [echoing(lambda k: error_body("invalid_request_error", f"Incorrect API key provided: {k[3:]}", "invalid_api_key"), 401)],
    "HTTP 403 with a list": [echoing(lambda k: [k, {"key": k}], 403)],
    "HTTP 404 with detail": [echoing(lambda k: {"detail": f"no model; your key {k[-20:]}"}, 404)],
    "HTTP 429 quota": [echoing(lambda k: error_body("insufficient_quota", f"quota gone for {k}"), 429)],
    "HTTP 429 then 500 then 503": [
        echoing(lambda k: error_body("requests", f"slow down {k}", k), 429),
        echoing(lambda k: f"upstream {k} overloaded", 500),
        echoing(lambda k: {"error": {"message": {"nested": [k, k.upper()]}, "type": k}}, 503),
    ],
    "a redirect": [echoing(lambda k: k, 302)],
}


def written(root: Path) -> Iterator[tuple[Path, str]]:
    """Every file under ``root`` as text (latin-1 of its bytes, and decompressed where it is zlib
    data), and every value of every table of every SQLite file (stores, the budget ledger)."""
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        data = path.read_bytes()
        yield path, data.decode("latin-1")
        try:
            unpacked: str | None = zlib.decompress(data).decode("latin-1")
        except zlib.error:
            unpacked = None
        if unpacked is not None:
            yield path, unpacked
        if data.startswith(b"SQLite format 3"):
            with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
                tables = [row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
                for table in tables:
                    for row in db.execute(f'SELECT * FROM "{table}"'):
                        for value in row:
                            if isinstance(value, bytes):
                                try:
                                    yield path, zlib.decompress(value).decode("latin-1")
                                except zlib.error:
                                    yield path, value.decode("latin-1")
                            else:
                                yield path, str(value)
