"""A local llama.cpp server that dies (SIGKILL), stops (SIGSTOP) or stops answering mid-run: the
request in flight fails within its deadline, the server is restarted once (said on stderr), and a
second death ends the trial with one line naming the exit status and the kept log; nothing hangs
and no process is left. The stand-in server of ``tests/llm/fake_llama`` is killed for real; the
failures of a server that cannot start are one line each, naming the log that holds its output."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lagrseq import config as cfg
from lagrseq.errors import ProviderError
from lagrseq.llm import local
from lagrseq.loop.lagr import query_for
from lagrseq.running import wiring
from tests.support.local_server import FAKE, GGUF, gone, start_line

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def model(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """The stand-in server on the path of lagrseq and its children; returns a model file."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(FAKE), str(ROOT)]))
    monkeypatch.syspath_prepend(str(FAKE))
    path = tmp_path / "tiny-model.gguf"
    path.write_bytes(GGUF)
    return path


def provider_and_query(model: Path) -> tuple[object, object, list[str]]:
    said: list[str] = []
    config = wiring.with_provider_model(cfg.load("cube-stacking", "lagr", "upstream"), f"local:{model}")
    task = wiring.make_task(config)
    original = wiring._say
    wiring._say = said.append  # type: ignore[assignment]
    try:
        provider = wiring.make_provider(f"local:{model}", config, np.random.default_rng(0))
    finally:
        wiring._say = original  # type: ignore[assignment]
    provider.supervisor.say = said.append  # type: ignore[attr-defined]
    query = query_for(task, config.llm, task.prefixes()[2])
    return provider, query, said


@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGSTOP])
def test_a_server_killed_mid_run_is_restarted_once_then_the_request_fails_in_one_line(model: Path, how: signal.Signals) -> None:
    provider, query, said = provider_and_query(model)
    try:
        server = provider.server  # type: ignore[attr-defined]
        assert provider.complete(query).text  # type: ignore[attr-defined]
        first = server.process.pid
        os.kill(first, how)
        started = time.monotonic()
        assert provider.complete(query).text  # type: ignore[attr-defined]  # answered by the restarted server
        assert time.monotonic() - started < 30
        assert server.process.pid != first and gone(first)
        restart = next(line for line in said if "restarting it (1/1)" in line)
        assert "exited with status -9 (SIGKILL)" in restart, said  # SIGSTOP: the watchdog killed it
        if how == signal.SIGSTOP:
            assert any("is stopped (SIGSTOP); killing it" in line for line in said), said
        kept = Path(re.search(r"output in (\S+)\)", restart).group(1))  # type: ignore[union-attr]
        assert kept.exists()  # the dead server's log stays for the user
        second = server.process.pid
        os.kill(second, signal.SIGKILL)
        started = time.monotonic()
        with pytest.raises(ProviderError) as failed:
            provider.complete(query)  # type: ignore[attr-defined]
        assert time.monotonic() - started < 30
        message = str(failed.value)
        assert "\n" not in message and "exited with status -9 (SIGKILL)" in message and "restarted 1 time already" in message
        assert gone(second) and not server.running
    finally:
        provider.close()  # type: ignore[attr-defined]
    assert kept.exists()
    kept.unlink()


def test_a_server_killed_by_an_illegal_instruction_says_what_it_means_and_is_not_restarted(model: Path) -> None:
    # a llama.cpp built with -march=native on another CPU (or a wheel pip cached there)
    # dies of SIGILL at its first request; restarting it only dies again
    provider, query, said = provider_and_query(model)
    try:
        server = provider.server  # type: ignore[attr-defined]
        assert provider.complete(query).text  # type: ignore[attr-defined]
        pid = server.process.pid
        os.kill(pid, signal.SIGILL)
        started = time.monotonic()
        with pytest.raises(ProviderError) as failed:
            provider.complete(query)  # type: ignore[attr-defined]
        assert time.monotonic() - started < 30
        message = str(failed.value)
        assert "\n" not in message and "exited with status -4 (SIGILL)" in message
        assert "CPU instructions this machine lacks" in message and local.REBUILD_COMMAND in message
        assert "CMAKE_ARGS=-DGGML_NATIVE=OFF" in message and "restarted 0 times already" in message
        assert not any("restarting it" in line for line in said), said
        assert gone(pid)
        kept = Path(message.rsplit("the server's output is in ", 1)[1].rstrip(")"))
        assert kept.exists()
        kept.unlink()
    finally:
        provider.close()  # type: ignore[attr-defined]


@pytest.mark.slow
def test_a_run_whose_server_dies_twice_ends_in_bounded_time_with_one_line(model: Path, tmp_path: Path) -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr", "--provider", f"local:{model}", "--trials", "1",
         "--set", "run.episodes=100000", "--out", str(tmp_path / "runs"), "--quiet"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "MPLBACKEND": "Agg"},
    )
    assert process.stderr is not None
    killed: list[int] = []
    seen = ""
    deadline = time.monotonic() + 120
    while len(killed) < 2 and time.monotonic() < deadline:
        line = process.stderr.readline()
        seen += line
        if "starting:" in line:
            pid, _ = start_line(line)
        if "ready on" in line:
            time.sleep(1.0)  # queries under way
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
    started = time.monotonic()
    _, rest = process.communicate(timeout=90)
    assert time.monotonic() - started < 90
    err = seen + rest
    assert process.returncode == 2, err
    last = [line for line in err.splitlines() if line.startswith("lagrseq run: error:")]
    assert len(last) == 1 and "exited with status -9 (SIGKILL)" in last[0] and "server's output is in" in last[0]
    assert "Traceback" not in err and all(gone(pid) for pid in killed)


def test_known_start_failures_are_one_line_naming_the_kept_log(model: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken.gguf"
    broken.write_bytes(b"GGUF" + bytes(4))  # the magic, then nothing a loader accepts
    server = local.LocalServer(local.ServerSettings(broken))
    with pytest.raises(ProviderError) as failed:
        server.start()
    message = str(failed.value)
    assert "\n" not in message and "is not a GGUF model this llama.cpp can read" in message
    log = Path(message.rsplit("the server's output is in ", 1)[1].rstrip(")"))
    assert log.exists() and "invalid or unsupported GGUF" in log.read_text()
    log.unlink()
    with socket.socket() as taken:  # the port taken between lagrseq's check and the server's bind
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        server = local.LocalServer(local.ServerSettings(model, port=port))
        original = local.port_taken
        local.port_taken = lambda host, port: False  # type: ignore[assignment]
        try:
            with pytest.raises(ProviderError) as failed:
                server.start()
        finally:
            local.port_taken = original  # type: ignore[assignment]
    message = str(failed.value)
    assert "\n" not in message and f"port {port} is taken; choose another with --port" in message and "output is in" in message
    Path(message.rsplit("the server's output is in ", 1)[1]).unlink()
