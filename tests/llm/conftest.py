"""Fixtures of the provider tests: a clean environment, a scripted OpenAI-compatible server on
127.0.0.1, and the authors' caches (read from ``../shared`` beside the repository, never copied)."""

from __future__ import annotations

import json
import threading
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lagrseq.llm.live import LiveSettings
from lagrseq.tasks import cube

AUTHORS_CACHES = Path(__file__).resolve().parents[3] / "shared" / "data" / "authors_caches"
SECRET = "sk-test-LAGRSEQ-0123456789abcdefSECRET"
KEY_ENV = "LAGRSEQ_TEST_API_KEY"


@pytest.fixture(autouse=True)
def clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """No real key and no proxy can leak into a test; the test key is set under its own name."""
    for name in ("OPENAI_API_KEY", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "http_proxy", "https_proxy", "all_proxy"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv(KEY_ENV, SECRET)


def authors_cache(name: str) -> Path:
    path = AUTHORS_CACHES / name
    if not path.is_file():
        pytest.skip(f"authors' cache {name} not found at {AUTHORS_CACHES} (the shared/ folder beside the repository)")
    return path


@dataclass
class Reply:
    """One scripted response."""

    status: int = 200
    body: Any = None
    """dict/list: sent as JSON; bytes/str: sent as is; None: a chat completion of the default answer;
    a callable: called with the key the request carried (its Authorization value without
    ``Bearer``) and its result sent as above (a server that echoes the key)."""
    headers: Any = field(default_factory=dict)
    """Header names and values, or a callable of the key returning them."""
    delay_s: float = 0.0
    """Wait this long before answering (longer than the client's read timeout: a timeout)."""
    extra_length: int = 0
    """Declare this many more bytes than are sent, then close: a body cut short."""


def error_body(kind: str, message: str, code: str | None = None) -> dict[str, Any]:
    return {"error": {"message": message, "type": kind, "param": None, "code": code or kind}}


def cube_answer(prompt: str, temperature: float) -> str:
    """What the default server answers: the task's rule-based extrapolator, like the mock."""
    return cube.extrapolate(prompt, temperature, np.random.default_rng(0))


class FakeOpenAI:
    """A scripted Chat Completions server. Requests take replies from ``script`` in order; with the
    script empty, they get a completion of ``responder(prompt, temperature)`` with ``n`` choices
    (or one, with ``honour_n=False``), usage and a server-side model name."""

    def __init__(self) -> None:
        self.script: deque[Reply] = deque()
        self.requests: list[dict[str, Any]] = []
        self.headers: list[dict[str, str]] = []
        self.responder: Callable[[str, float], str] = cube_answer
        self.honour_n = True
        self.release = threading.Event()
        self._lock = threading.Lock()
        self._count = 0
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:
                return None

            def do_POST(self) -> None:
                length = int(self.headers.get("Content-Length", "0"))
                body = json.loads(self.rfile.read(length) or b"null")
                with server._lock:
                    server.requests.append(body)
                    server.headers.append({k.lower(): v for k, v in self.headers.items()})
                    reply = server.script.popleft() if server.script else Reply()
                    server._count += 1
                    number = server._count
                if reply.delay_s:
                    server.release.wait(reply.delay_s)
                key = self.headers.get("Authorization", "").removeprefix("Bearer ")
                payload = reply.body(key) if callable(reply.body) else reply.body
                payload = payload if payload is not None else server.completion(body, number)
                headers = reply.headers(key) if callable(reply.headers) else reply.headers
                data = payload if isinstance(payload, bytes) else (
                    payload.encode() if isinstance(payload, str) else json.dumps(payload).encode()
                )
                try:
                    self.send_response(reply.status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data) + reply.extra_length))
                    for name, value in headers.items():
                        self.send_header(name, value)
                    self.end_headers()
                    self.wfile.write(data)
                    self.wfile.flush()
                except OSError:  # the client gave up (a timeout test)
                    pass
                self.close_connection = True

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.httpd.block_on_close = False  # type: ignore[attr-defined]
        self.httpd.handle_error = lambda *args: None  # type: ignore[method-assign]
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, args=(0.01,), daemon=True)
        self.thread.start()

    def completion(self, body: dict[str, Any], number: int) -> dict[str, Any]:
        prompt = body["messages"][-1]["content"]
        n = int(body.get("n", 1)) if self.honour_n else 1
        texts = [self.responder(prompt, float(body.get("temperature", 1.0))) for _ in range(n)]
        return {
            "id": f"chatcmpl-{number}",
            "object": "chat.completion",
            "created": 1700000000,
            "model": body["model"] + "-2024-07-18",
            "system_fingerprint": "fp_test",
            "choices": [
                {"index": i, "message": {"role": "assistant", "content": t}, "finish_reason": "stop"}
                for i, t in enumerate(texts)
            ],
            "usage": {
                "prompt_tokens": len(prompt) // 4,
                "completion_tokens": sum(len(t) // 4 for t in texts),
                "total_tokens": len(prompt) // 4 + sum(len(t) // 4 for t in texts),
                "prompt_tokens_details": {"cached_tokens": 0},
            },
        }

    def close(self) -> None:
        self.release.set()
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def server() -> Iterator[FakeOpenAI]:
    fake = FakeOpenAI()
    try:
        yield fake
    finally:
        fake.close()


def fast_settings(url: str, **changes: Any) -> LiveSettings:
    """Settings for tests: tiny backoffs, short timeouts, the test key variable."""
    values: dict[str, Any] = {
        "base_url": url,
        "api_key_env": KEY_ENV,
        "connect_timeout_s": 2.0,
        "read_timeout_s": 2.0,
        "max_retries": 3,
        "backoff_initial_s": 0.001,
        "backoff_max_s": 0.005,
    }
    values.update(changes)
    return LiveSettings(**values)
