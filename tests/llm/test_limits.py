"""No server can hang a request or fill memory: a deadline per request, a cap on the response size
(decompressed too), a configurable read timeout, and settings that must make sense.

The servers here are raw sockets on 127.0.0.1, so they can misbehave in ways an HTTP library would
not let them: a body that never ends, a huge one, headers and then silence.
"""

from __future__ import annotations

import socket
import threading
import time
import tracemalloc
import zlib
from collections.abc import Callable

import numpy as np
import pytest

from lagrseq.errors import ConfigError, ProviderError
from lagrseq.llm.live import LiveProvider, LiveSettings
from tests.llm.conftest import FakeOpenAI, fast_settings
from tests.support.servers import TASK, RawServer, headers, live, query, serve

MIB = 1024 * 1024


def trickle(chunked: bool) -> Callable[[socket.socket, threading.Event, RawServer], None]:
    """Headers, then one byte of body every 20 ms, for ever."""

    def behave(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers(chunked=chunked))
        while not stop.wait(0.02):
            conn.sendall(b"1\r\n \r\n" if chunked else b" ")
            raw.add(1)

    return behave


def flood(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
    """Headers without a length, then 64 KiB blocks as fast as the client takes them, for ever."""
    conn.sendall(headers())
    block = b"[" * 65536
    while not stop.is_set():
        conn.sendall(block)
        raw.add(len(block))


def stall_after_headers(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
    conn.sendall(headers(length=100))
    stop.wait(30)


def stall_before_headers(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
    stop.wait(30)


@pytest.mark.parametrize("chunked", [False, True], ids=["until-close", "chunked"])
def test_a_body_that_never_ends_is_cut_off_at_the_deadline_and_retried(chunked: bool) -> None:
    with serve(trickle(chunked)) as raw:
        retries: list[str] = []
        provider = LiveProvider(
            fast_settings(raw.url, max_retries=1, request_deadline_s=1.0, read_timeout_s=10.0),
            rng=np.random.default_rng(0),
            on_retry=retries.append,
        )
        started = time.perf_counter()
        with provider, pytest.raises(ProviderError, match="did not end within the 1 s request deadline") as caught:
            provider.complete(query())
        elapsed = time.perf_counter() - started
        assert 2.0 <= elapsed < 3.5  # two attempts of one second, though no read ever waited 10 s
        assert raw.requests == 2 and len(retries) == 1 and "request deadline" in retries[0]
        assert "gave up after 2 attempts" in str(caught.value) and "\n" not in str(caught.value)


def test_headers_then_silence_ends_at_the_deadline() -> None:
    with serve(stall_after_headers) as raw:
        started = time.perf_counter()
        with live(raw.url) as provider, pytest.raises(ProviderError, match="1 s request deadline"):
            provider.complete(query())
        assert time.perf_counter() - started < 2.0 and raw.requests == 1


def test_no_headers_at_all_ends_at_the_deadline_too() -> None:
    with serve(stall_before_headers) as raw:
        started = time.perf_counter()
        with live(raw.url) as provider, pytest.raises(ProviderError, match="1 s request deadline"):
            provider.complete(query())
        assert time.perf_counter() - started < 2.0


def test_the_read_timeout_is_a_setting_of_its_own() -> None:
    with serve(stall_after_headers) as raw:
        started = time.perf_counter()
        with live(raw.url, read_timeout_s=0.3, request_deadline_s=20.0) as provider, pytest.raises(
            ProviderError, match="0.3 s read timeout"
        ):
            provider.complete(query())
        assert time.perf_counter() - started < 1.5


def test_a_huge_body_stops_at_the_cap_in_bounded_memory_and_is_not_retried() -> None:
    with serve(flood) as raw:
        tracemalloc.start()
        started = time.perf_counter()
        try:
            with live(raw.url, max_retries=3, max_response_bytes=MIB, request_deadline_s=30.0) as provider, pytest.raises(
                ProviderError, match="larger than max_response_bytes = 1048576"
            ) as caught:
                provider.complete(query())
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert time.perf_counter() - started < 5.0
        assert raw.requests == 1  # not retried: the same server would send it again
        assert peak < 6 * MIB, peak  # the cap and a block or two, not what the server kept sending
        assert "not retried" in str(caught.value) and "--max-response-bytes" in str(caught.value)


def test_a_declared_length_over_the_cap_is_refused_before_reading() -> None:
    def liar(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers(length=10**12))
        stop.wait(30)

    with serve(liar) as raw:
        started = time.perf_counter()
        with live(raw.url, request_deadline_s=30.0) as provider, pytest.raises(ProviderError, match="declares 1000000000000 bytes"):
            provider.complete(query())
        assert time.perf_counter() - started < 1.0


def gzip_bomb(megabytes: int) -> bytes:
    packer = zlib.compressobj(9, zlib.DEFLATED, zlib.MAX_WBITS | 16)
    zeros = b"0" * MIB
    return b"".join(packer.compress(zeros) for _ in range(megabytes)) + packer.flush()


def test_a_compressed_bomb_stops_at_the_cap_in_bounded_memory() -> None:
    bomb = gzip_bomb(24)  # 24 MiB of text in some 24 KiB

    def send(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers("Content-Encoding: gzip", length=len(bomb)) + bomb)

    with serve(send) as raw:
        tracemalloc.start()
        try:
            with live(raw.url, max_response_bytes=MIB, request_deadline_s=30.0) as provider, pytest.raises(
                ProviderError, match="larger than max_response_bytes"
            ):
                provider.complete(query())
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < 6 * MIB, peak


def test_a_gzip_answer_within_the_cap_is_read(server: FakeOpenAI) -> None:
    import gzip
    import json

    from tests.llm.conftest import Reply

    completion = server.completion({"model": "gpt-4o-mini", "messages": [{"content": TASK.prompt((4,))}]}, 1)
    server.script.append(Reply(body=gzip.compress(json.dumps(completion).encode()), headers={"Content-Encoding": "gzip"}))
    with live(server.url) as provider:
        answer = provider.complete(query())
    assert TASK.parse(answer.text).ok and server.headers[0]["accept-encoding"] == "gzip, deflate"


def test_an_encoding_that_was_not_asked_for_is_refused() -> None:
    def brotli(conn: socket.socket, stop: threading.Event, raw: RawServer) -> None:
        conn.sendall(headers("Content-Encoding: br", length=4) + b"\x00\x01\x02\x03")

    with serve(brotli) as raw, live(raw.url) as provider, pytest.raises(ProviderError, match="encoded as 'br'.*gzip and deflate"):
        provider.complete(query())


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("request_deadline_s", 0.0),
        ("request_deadline_s", float("nan")),
        ("request_deadline_s", float("inf")),
        ("read_timeout_s", -1.0),
        ("read_timeout_s", "5"),
        ("connect_timeout_s", True),
        ("max_response_bytes", 0),
        ("max_response_bytes", 1.5),
        ("max_response_bytes", -1),
        ("max_retries", -1),
        ("max_retries", 2.0),
        ("backoff_initial_s", float("nan")),
        ("max_retry_after_s", float("-inf")),
        ("jitter", 1.5),
    ],
)
def test_settings_out_of_range_are_one_line(name: str, value: object) -> None:
    with pytest.raises(ConfigError) as caught:
        LiveSettings(**{name: value})  # type: ignore[arg-type]
    message = str(caught.value)
    assert name in message and "expected" in message and "\n" not in message


def test_the_defaults_are_sane() -> None:
    settings = LiveSettings()
    assert settings.request_deadline_s == 300.0 and settings.read_timeout_s == 120.0
    assert settings.max_response_bytes == 4 * MIB

