"""Raw-socket HTTP servers on 127.0.0.1 that can misbehave as an HTTP library would not let them
(a body that never ends, a huge one, headers and then silence), and a live provider with short
deadlines to point at them."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from lagrseq.llm.base import Query, user_query
from lagrseq.llm.live import LiveProvider
from lagrseq.tasks import cube
from tests.llm.conftest import fast_settings

TASK = cube.CubeStacking(8)


def query() -> Query:
    return user_query(TASK.name, TASK.prompt((4,)), "gpt-4o-mini", 0.0, 64)


class RawServer:
    """Accepts connections on 127.0.0.1, reads each request, then lets ``behave(sock, stop)``
    answer (or not). Counts requests; ``sent`` adds up the body bytes the behaviours sent."""

    def __init__(self, behave: Callable[[socket.socket, threading.Event, RawServer], None]) -> None:
        self.behave = behave
        self.stop = threading.Event()
        self.requests = 0
        self.sent = 0
        self._lock = threading.Lock()
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.05)
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}/v1"
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except (TimeoutError, OSError):
                continue
            threading.Thread(target=self._handle, args=(conn,), daemon=True).start()

    def _handle(self, conn: socket.socket) -> None:
        with conn:
            conn.settimeout(5.0)
            data = b""
            try:
                while b"\r\n\r\n" not in data:
                    data += conn.recv(65536)
                head, _, rest = data.partition(b"\r\n\r\n")
                length = next(
                    (int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:")), 0
                )
                while len(rest) < length:
                    rest += conn.recv(65536)
                with self._lock:
                    self.requests += 1
                self.behave(conn, self.stop, self)
            except OSError:  # the client hung up: what the tests want
                pass

    def add(self, count: int) -> None:
        with self._lock:
            self.sent += count

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2.0)
        self.listener.close()


@contextlib.contextmanager
def serve(behave: Callable[[socket.socket, threading.Event, RawServer], None]) -> Iterator[RawServer]:
    raw = RawServer(behave)
    try:
        yield raw
    finally:
        raw.close()


def headers(extra: str = "", length: int | None = None, chunked: bool = False) -> bytes:
    lines = ["HTTP/1.1 200 OK", "Content-Type: application/json"]
    if length is not None:
        lines.append(f"Content-Length: {length}")
    if chunked:
        lines.append("Transfer-Encoding: chunked")
    if extra:
        lines.append(extra)
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def live(url: str, **changes: Any) -> LiveProvider:
    values: dict[str, Any] = {"max_retries": 0, "request_deadline_s": 1.0, "read_timeout_s": 10.0}
    values.update(changes)
    return LiveProvider(fast_settings(url, **values), rng=np.random.default_rng(0))
