"""More servers that misbehave on 127.0.0.1, beyond ``test_limits.py``: status
line and headers dripped a byte at a time, lying lengths, endless or huge headers, a chunked body
that never ends, redirect loops, bodies that are not chat completions (HTML, server-sent events,
JSON of the wrong types, nesting past the recursion limit, lone surrogates), and the local
server's readiness probe against a server that drips. Every case ends in an answer or one line,
within the request deadline, and nothing a store cannot hold gets through.

Where a server would go on for ever, it counts what it sent and whether the client hung up: the
client must hang up long before the server is through (no wall-clock assertions).
"""

from __future__ import annotations

import json
import socket
import stat
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lagrseq.errors import ProviderError
from lagrseq.llm import local
from lagrseq.llm.live import LiveProvider
from lagrseq.llm.store import RecordStore, query_key, sample_from_answer
from tests.llm.conftest import fast_settings
from tests.support.servers import RawServer, headers, live, query, serve

DRIP_BYTES = 400
"""A dripping server sends this many bytes, one every DRIP_S: 40 s, against a 1 s deadline."""
DRIP_S = 0.1


class Drip:
    """Sends ``data`` one byte every DRIP_S; records whether the client hung up before the end."""

    def __init__(self, data: bytes) -> None:
        self.data = data[:DRIP_BYTES]
        self.hung_up = threading.Event()
        self.finished = threading.Event()

    def __call__(self, conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        try:
            for byte in self.data:
                if stop.wait(DRIP_S):
                    return
                conn.sendall(bytes([byte]))
                raw.add(1)
        except OSError:
            self.hung_up.set()
            return
        self.finished.set()


def test_a_status_line_and_headers_dripped_byte_by_byte_end_at_the_deadline() -> None:
    """Each byte comes well within the read timeout and before there is a response to watch:
    only a deadline on every read stops it (old: the request lasted as long as the drip)."""
    drip = Drip(b"HTTP/1.1 200 OK\r\nX-Slow: " + b"a" * DRIP_BYTES)
    with serve(drip) as raw:
        with live(raw.url, request_deadline_s=1.0, read_timeout_s=5.0) as provider:
            assert provider.deadline_bound
            with pytest.raises(ProviderError, match="did not end within the 1 s request deadline") as caught:
                provider.complete(query())
        assert "\n" not in str(caught.value)
        assert drip.hung_up.wait(5.0) and not drip.finished.is_set()
        assert raw.sent < DRIP_BYTES // 2


def test_every_request_opens_a_watched_connection_of_its_own() -> None:
    """No connection is kept idle, so a second request connects anew and is watched from its
    first byte like the first (a reused connection would open nothing to watch)."""
    good = json.dumps({"choices": [{"message": {"content": "['e']"}}]}).encode()
    drip = Drip(b"HTTP/1.1 200 OK\r\nX-Slow: " + b"a" * DRIP_BYTES)
    connections = []

    def behave(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        connections.append(conn)
        if len(connections) == 1:
            conn.sendall(headers(length=len(good)) + good)
        else:
            drip(conn, stop, raw)

    with serve(behave) as raw, live(raw.url, request_deadline_s=1.0, read_timeout_s=5.0) as provider:
        assert provider.complete(query()).text == "['e']"
        with pytest.raises(ProviderError, match="1 s request deadline"):
            provider.complete(query())
        assert len(connections) == 2 and drip.hung_up.wait(5.0) and not drip.finished.is_set()


def endless(piece: bytes, head: bytes) -> Any:
    def behave(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(head)
        while not stop.is_set():
            conn.sendall(piece)
            raw.add(len(piece))

    return behave


@pytest.mark.parametrize(
    ("behave", "expected"),
    [
        (endless(b"X-A: " + b"a" * 8000 + b"\r\n", b"HTTP/1.1 200 OK\r\n"), "connection failed"),
        (endless(b"a" * 8000, b"HTTP/1.1 200 OK\r\nX-A: "), "connection failed"),
        (endless(b"400\r\n" + b" " * 1024 + b"\r\n", headers(chunked=True)), "larger than max_response_bytes"),
        (endless(b"data: {}\n\n" * 100, headers(chunked=False).replace(b"application/json", b"text/event-stream")), "larger than max_response_bytes"),
    ],
    ids=["endless headers", "one endless header", "endless chunks", "endless events"],
)
def test_endless_headers_or_bodies_stop_at_a_limit(behave: Any, expected: str) -> None:
    with serve(behave) as raw:
        with live(raw.url, request_deadline_s=30.0, max_response_bytes=256 * 1024) as provider, pytest.raises(ProviderError) as caught:
            provider.complete(query())
        assert expected in str(caught.value) and "\n" not in str(caught.value)
        assert raw.sent < 64 * 1024 * 1024


def test_a_length_that_lies_is_one_line() -> None:
    short = b'{"choices": []}'
    completion = json.dumps({"choices": [{"message": {"content": "['e','f']"}}]}).encode()

    def under(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers(length=1000) + short)  # then closes

    def over(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers(length=10) + completion)

    with serve(under) as raw, live(raw.url, max_retries=1) as provider, pytest.raises(ProviderError, match="gave up after 2 attempts: connection failed"):
        provider.complete(query())
    with serve(over) as raw, live(raw.url) as provider, pytest.raises(ProviderError, match="the body is not JSON") as caught:
        provider.complete(query())
    assert "\n" not in str(caught.value)


def test_a_redirect_loop_is_not_followed() -> None:
    def loop(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(f"HTTP/1.1 307 Temporary Redirect\r\nLocation: {raw.url}/chat/completions\r\nContent-Length: 0\r\n\r\n".encode())

    with serve(loop) as raw:
        with live(raw.url, max_retries=3) as provider, pytest.raises(ProviderError, match="HTTP 307; not retried"):
            provider.complete(query())
        assert raw.requests == 1


def reply(body: bytes, content_type: str = "application/json") -> Any:
    def behave(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers(length=len(body)).replace(b"application/json", content_type.encode()) + body)

    return behave


def choice(content: Any) -> bytes:
    return json.dumps({"choices": [{"index": 0, "message": {"role": "assistant", "content": content}}]}).encode()


@pytest.mark.parametrize(
    ("body", "content_type", "expected"),
    [
        (b"<html><body>Bad gateway</body></html>", "text/html", "the body is not JSON"),
        (b'data: {"choices":[{"delta":{"content":"[\'e\']"}}]}\n\ndata: [DONE]\n\n', "text/event-stream", "the body is not JSON"),
        (b"[" * 100_000, "application/json", "the body is not JSON"),
        (b'{"choices": [{"message": {"content": "x"}}], "usage": {"prompt_tokens": ' + b"9" * 5000 + b"}}", "application/json", "the body is not JSON"),
        (b"[1, 2]", "application/json", "the body has no choices"),
        (b'{"choices": {"0": {"message": {"content": "x"}}}}', "application/json", "the body has no choices"),
        (b'{"choices": "x"}', "application/json", "the body has no choices"),
        (b'{"choices": ["x"]}', "application/json", "a choice has no message"),
        (b'{"choices": [{"message": [1]}]}', "application/json", "a choice has no message"),
        (choice(5), "application/json", "content is not text (int)"),
        (choice([{"type": "text", "text": "x"}]), "application/json", "content is not text (list)"),
        (choice({"a": 1}), "application/json", "content is not text (dict)"),
        (b"", "application/json", "the body is empty"),
    ],
    ids=["html", "sse", "nested", "huge int", "list", "choices dict", "choices str", "choice str", "message list",
         "content int", "content parts", "content dict", "empty"],
)
def test_a_200_that_is_not_a_chat_completion_is_one_line_and_not_retried(body: bytes, content_type: str, expected: str) -> None:
    with serve(reply(body, content_type)) as raw:
        with live(raw.url, max_retries=3) as provider, pytest.raises(ProviderError) as caught:
            provider.complete(query())
        message = str(caught.value)
        assert expected in message and "\n" not in message and len(message) < 400, message
        assert raw.requests == 1


@pytest.mark.parametrize(
    "usage",
    [
        b'{"prompt_tokens": -5, "completion_tokens": -1}',
        b'{"prompt_tokens": NaN, "completion_tokens": Infinity}',
        b'{"prompt_tokens": 1e300, "completion_tokens": 1000000000000}',
        b'{"prompt_tokens": "10", "completion_tokens": null, "prompt_tokens_details": {"cached_tokens": -3}}',
        b'"lots"',
    ],
    ids=["negative", "nan", "huge", "strings", "not an object"],
)
def test_usage_of_the_wrong_kind_counts_as_the_worst_case(usage: bytes) -> None:
    body = b'{"choices": [{"message": {"content": "[\'e\']"}, "finish_reason": {"x": 1}}], "model": 7, "id": [1], "usage": ' + usage + b"}"
    said: list[str] = []
    with serve(reply(body)) as raw:
        provider = LiveProvider(fast_settings(raw.url, max_retries=0), rng=np.random.default_rng(0), on_warning=said.append)
        with provider:
            answer = provider.complete(query())
    q = query()
    assert answer.text == "['e']" and answer.model == q.model and answer.finish_reason is None and answer.response_id is None
    assert answer.usage.completion_tokens == q.max_tokens and answer.usage.prompt_tokens > 0
    assert answer.usage.cached_tokens == 0 and said and all("\n" not in line for line in said)


def test_lone_surrogates_become_replacement_characters_and_the_answer_can_be_stored(tmp_path: Path) -> None:
    """JSON escapes can carry lone surrogates, which no store, log or terminal can write (old: the
    answer was paid for, then refused by the store)."""
    body = (b'{"choices": [{"message": {"content": "[\'e\',\\ud800\'f\']\\udfff"}, "finish_reason": "st\\ud83dop"}],'
            b' "model": "m\\udc00", "system_fingerprint": "fp\\ud800", "id": "c\\ud800"}')
    with serve(reply(body)) as raw, live(raw.url) as provider:
        answer = provider.complete(query())
    for text in (answer.text, answer.finish_reason, answer.model, answer.system_fingerprint, answer.response_id):
        assert text is not None and "\ufffd" in text
        text.encode("utf-8")  # valid Unicode
    assert answer.text == "['e',\ufffd'f']\ufffd"
    key, request = query_key(query(), "127.0.0.1")
    with RecordStore(tmp_path / "store") as store:
        assert store.add(key, request, "cube-stacking", [sample_from_answer(answer, key)]) == 1
        assert store.entry(key).samples[0].text == answer.text  # type: ignore[union-attr]


# ---------------------------------------------------------------- the local server's readiness probe
def test_the_local_servers_readiness_probe_ends_against_a_dripping_server(tmp_path: Path) -> None:
    """A server on the port that drips its headers (a foreign one, or a hung start) cannot hold
    the start past its timeout: every probe ends within its 2 s (old: one probe lasted as long as
    the drip, whatever the startup timeout)."""
    sent = tmp_path / "sent"
    script = tmp_path / "drip-server"
    script.write_text(
        f"#!{sys.executable}\n"
        "import os, socket, sys, time, pathlib\n"
        "port = int(sys.argv[sys.argv.index('--port') + 1])\n"
        "listener = socket.create_server(('127.0.0.1', port))\n"
        "conn, _ = listener.accept()\n"
        f"for count, byte in enumerate(b'HTTP/1.1 200 OK' + b'a' * {DRIP_BYTES}, 1):\n"
        f"    time.sleep({DRIP_S})\n"
        "    conn.sendall(bytes([byte]))\n"
        # written whole or not at all: the server is killed at any moment, and a plain
        # write_text killed between truncating and writing left an empty file
        f"    pathlib.Path({str(sent) + '.tmp'!r}).write_text(str(count))\n"
        f"    os.replace({str(sent) + '.tmp'!r}, {str(sent)!r})\n",
        encoding="utf-8",
    )
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    model = tmp_path / "m.gguf"
    model.write_bytes(b"GGUF" + bytes(60))
    server = local.LocalServer(local.ServerSettings(model=model, startup_timeout_s=1.0), python=str(script))
    with pytest.raises(ProviderError, match="did not answer .*/models within 1 s") as caught:
        server.start()
    assert "\n" not in str(caught.value) and not server.running
    assert int(sent.read_text()) < DRIP_BYTES // 2  # stopped long before the drip was over


def test_no_proxy_from_the_environment_escapes_the_deadline(monkeypatch: pytest.MonkeyPatch) -> None:
    """A proxy taken from the environment that drips its answer is cut off at the deadline too
    (the proxy runs on 127.0.0.1; the URL behind it is never contacted)."""
    drip = Drip(b"HTTP/1.1 200 OK\r\nX-Slow: " + b"a" * DRIP_BYTES)
    with serve(drip) as proxy:
        monkeypatch.setenv("HTTP_PROXY", proxy.url.removesuffix("/v1"))
        monkeypatch.setenv("NO_PROXY", "")
        with live("http://127.0.0.1:9/v1", request_deadline_s=1.0, read_timeout_s=5.0) as provider:
            assert provider.deadline_bound
            with pytest.raises(ProviderError, match="1 s request deadline"):
                provider.complete(query())
        assert drip.hung_up.wait(5.0) and not drip.finished.is_set()
        assert proxy.sent < DRIP_BYTES // 2


