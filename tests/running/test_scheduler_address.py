"""A Dask scheduler address is checked before anything starts: a malformed ``--scheduler`` and
something other than a scheduler answering there are each one line, and no trial runs."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.errors import UsageError
from lagrseq.running.executors import check_scheduler
from tests.support.cli import cli, refused

SMALL = ["--set", "run.episodes=2", "--quiet"]


@pytest.mark.parametrize(
    "address",
    ["bad", "tcp://host:notaport", "tcp://host:0", "tcp://host:65536", "tcp://:8786", "tcp://host", "http://host:8786", "tcp://ho st:1", "tcp://h:1\n", "tcp://h:1\x00"],
)
def test_a_bad_scheduler_address_is_one_line_before_anything_starts(tmp_path: Path, address: str) -> None:
    error = refused("run", "cube-stacking", "--executor", "dask", "--scheduler", address, "--trials", "1", "--out", str(tmp_path / "r"), *SMALL)
    assert "--scheduler" in error and "tcp://HOST:PORT" in error
    status, _, err = cli("reproduce", "--quick", "--items", "table2", "--executor", "dask", "--scheduler", address, "--out", str(tmp_path / "p"))
    assert status == 2 and len(err.strip().splitlines()) == 1, err  # no progress bar drawn before it
    assert not list(tmp_path.rglob("*.mcap*"))


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=40))
def test_check_scheduler_returns_an_address_or_raises_one_usage_error(text: str) -> None:
    try:
        assert check_scheduler(text) == text
    except UsageError as exc:
        assert "\n" not in str(exc)


@pytest.fixture
def garbage_server() -> Iterator[int]:
    """A TCP server on 127.0.0.1 that answers every connection with bytes Dask cannot read."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    server.settimeout(0.1)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn, suppress(OSError):
                conn.sendall(b"HTTP/1.1 200 OK\r\n\r\n" + b"\xff" * 4096)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield server.getsockname()[1]
    stop.set()
    thread.join(timeout=5)
    server.close()


def test_something_else_answering_at_the_scheduler_address_is_one_line(tmp_path: Path, garbage_server: int) -> None:
    pytest.importorskip("distributed")
    error = refused(
        "run", "cube-stacking", "--executor", "dask", "--scheduler", f"tcp://127.0.0.1:{garbage_server}",
        "--trials", "1", "--out", str(tmp_path), *SMALL,
    )
    assert f"no Dask scheduler answered at tcp://127.0.0.1:{garbage_server}" in error
    assert not list(tmp_path.rglob("*.mcap*"))


