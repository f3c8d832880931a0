"""The local server's life, in the default test run: lagrseq starts ``python -m llama_cpp.server``
as a child process, waits for it, talks to it, and stops it (and what it started) on every way
out: a normal end, a start that fails, Ctrl-C, SIGTERM, and lagrseq killed outright.

The server here is the stand-in of ``tests/llm/fake_llama`` (same command line, same HTTP
endpoints, same failures; the real one needs the local-llm extra and is tested in
``test_local_llm.py``). Everything is real processes and real HTTP on 127.0.0.1."""

from __future__ import annotations

import contextlib
import json
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

from lagrseq import cli
from lagrseq import config as cfg
from lagrseq.errors import ProviderError, UsageError
from lagrseq.llm import local
from lagrseq.logs.reader import find_logs, read_topic
from lagrseq.loop.lagr import query_for
from lagrseq.progress import Reporter
from lagrseq.running import wiring
from tests.support.local_server import FAKE, GGUF, gone, start_line

ROOT = Path(__file__).resolve().parents[2]

def DEFAULT_SIGINT() -> None:  # noqa: N802 (used like a constant)
    """In the child: Ctrl-C's default action, so Python raises KeyboardInterrupt there even when
    this test run itself was started as a background job (whose SIGINT is ignored and inherited)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """The stand-in server on the path of lagrseq and its children; returns a model file."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(FAKE), str(ROOT)]))
    monkeypatch.syspath_prepend(str(FAKE))
    model = tmp_path / "tiny-model.gguf"
    model.write_bytes(GGUF)
    return model


def helper_pid(log: Path) -> int:
    """The pid of the process the stand-in server started in its group (from its log)."""
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        match = re.search(r"helper pid (\d+)", log.read_text() if log.exists() else "")
        if match:
            return int(match.group(1))
        time.sleep(0.05)
    raise AssertionError(f"no helper pid in {log}")


def group_members(pgid: int) -> list[int]:
    """The processes of process group ``pgid`` (from /proc: no log file needed)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:
            members.append(int(stat.parent.name))
    return members


def test_the_provider_starts_asks_and_stops_the_server_and_its_group(fake: Path) -> None:
    config = wiring.with_provider_model(cfg.load("cube-stacking", "lagr", "upstream"), f"local:{fake}")
    assert config.llm.model == "tiny-model"
    task = wiring.make_task(config)
    provider = wiring.make_provider(f"local:{fake}", config, np.random.default_rng(0))
    server = provider.server  # type: ignore[attr-defined]
    pid, log = server.process.pid, server.log
    helper = helper_pid(log)
    try:
        answer = provider.complete(query_for(task, config.llm, task.prefixes()[2]))
    finally:
        provider.close()
    assert answer.source == "live" and answer.model == "tiny-model" and answer.cost_usd == 0.0
    assert answer.usage is not None and answer.usage.prompt_tokens > 0 and answer.latency_s is not None
    assert gone(pid) and gone(helper)  # the whole process group
    assert not log.exists()  # its temporary log is removed
    provider.close()  # idempotent


def test_no_api_key_is_sent_to_the_local_server(fake: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", "sk-should-never-leave-LAGRSEQ-0123456789")
    provider = wiring.make_local(str(fake), wiring.LocalOptions(), np.random.default_rng(0))
    try:
        assert "Authorization" not in provider.inner.inner._headers()  # type: ignore[attr-defined]
    finally:
        provider.close()


def test_start_failures_are_one_line_and_leave_no_process(fake: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken.gguf"
    broken.write_bytes(b"GGUF" + bytes(4))  # the magic, then nothing a loader accepts
    lines: list[str] = []
    server = local.LocalServer(local.ServerSettings(broken), reporter=Reporter(lines.append))
    with pytest.raises(ProviderError, match=r"exited with status 1 before answering: broken.gguf is not a GGUF model"):
        server.start()
    assert gone(start_line(lines[0])[0]) and server.process is None
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(UsageError, match=f"port {port} on 127.0.0.1 is taken"):
            local.LocalServer(local.ServerSettings(fake, port=port)).start()
    with pytest.raises(UsageError, match="no such file"):
        wiring.local_settings(str(tmp_path / "missing.gguf"), wiring.LocalOptions())
    (tmp_path / "notes.gguf").write_text("plain text")
    with pytest.raises(UsageError, match="not a GGUF file"):
        wiring.local_settings(str(tmp_path / "notes.gguf"), wiring.LocalOptions())
    # a server that starts and never answers (a stand-in interpreter that only sleeps): the
    # startup timeout ends it, whatever the machine's load
    silent = tmp_path / "silent-python"
    silent.write_text("#!/bin/sh\nexec sleep 60\n")
    silent.chmod(0o755)
    slow = local.LocalServer(local.ServerSettings(fake, startup_timeout_s=0.5), python=str(silent))
    with pytest.raises(ProviderError, match="did not answer"):
        slow.start()
    assert slow.process is None


def test_the_extra_missing_is_one_line_and_exit_status_2(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name in local.SERVER_MODULES else real(name, *a))
    assert cli.main(["run", "cube-stacking", "--provider", "local", "--trials", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install --no-cache-dir 'lagrseq[local-llm]'" in err and "-DGGML_NATIVE=OFF" in err
    assert cli.main(["serve-llm"]) == 2
    assert "local-llm extra is not installed" in capsys.readouterr().err


def test_a_run_with_the_local_provider_logs_live_queries_and_leaves_nothing(fake: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["run", "cube-stacking", "--method", "lagr-seq", "--provider", f"local:{fake}", "--trials", "1",
                     "--set", "run.episodes=5", "--out", str(tmp_path / "runs"), "--quiet"])
    assert code == 0
    err = capfd.readouterr().err
    pid, _ = start_line(err)
    assert "ready" in err and "stopped" in err and gone(pid)
    queries = [q for p in find_logs([tmp_path / "runs"]) for q in read_topic(p, "/query") if q.get("queried")]
    assert queries and all(q["source"] == "live" and q["model"] == "tiny-model" for q in queries)
    assert all(q["prompt_tokens"] > 0 and q["completion_tokens"] > 0 and q["latency_s"] > 0 for q in queries)
    # the run says which samplers llama.cpp was sent (OpenAI's meaning of temperature)
    from lagrseq.logs.reader import read_info

    (log,) = find_logs([tmp_path / "runs"])
    assert json.loads(read_info(log).run["llm_samplers"]) == {"min_p": 0.0, "repeat_penalty": 1.0, "top_k": 0}


def lagrseq(*args: str, cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "lagrseq", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "MPLBACKEND": "Agg"}, preexec_fn=DEFAULT_SIGINT)


def wait_ready(process: subprocess.Popen[str]) -> str:
    """What the process wrote up to its server's "ready" line (on stderr, or on stdout when stderr
    is merged into it)."""
    stream = process.stderr if process.stderr is not None else process.stdout
    assert stream is not None
    seen = ""
    while "ready" not in seen:
        line = stream.readline()
        assert line, f"ended before the server was ready: {seen}"
        seen += line
    return seen


def test_ctrl_c_stops_the_run_and_its_server(fake: Path, tmp_path: Path) -> None:
    process = lagrseq("run", "cube-stacking", "--method", "lagr", "--provider", f"local:{fake}", "--trials", "1",
                      "--set", "run.episodes=100000", "--out", str(tmp_path / "runs"), "--quiet", cwd=tmp_path)
    seen = wait_ready(process)
    pid, log = start_line(seen)
    helper = helper_pid(log)
    time.sleep(0.5)  # queries under way
    process.send_signal(signal.SIGINT)
    _, rest = process.communicate(timeout=60)
    assert process.returncode == 130, seen + rest
    assert "interrupted" in rest and gone(pid) and gone(helper)


@pytest.mark.slow  # under tox a SIGTERM may arrive ignored or blocked by inheritance
def test_sigterm_ends_a_recording_and_its_server_keeping_the_answers(fake: Path, tmp_path: Path) -> None:
    """kill, timeout and batch schedulers send SIGTERM, which stops lagrseq as Ctrl-C does (exit
    143): its server dies with it (the kernel's parent-death signal is SIGKILL; with SIGTERM a real server waited
    for its request in flight and outlived lagrseq), and every answer already returned stays in
    the store."""
    from lagrseq.llm.store import RecordStore

    store = tmp_path / "s"
    process = subprocess.Popen(  # record says what its server does on stdout: read both streams as one
        [sys.executable, "-m", "lagrseq", "record", "cube-stacking", "--provider", f"local:{fake}", "--temperature", "1",
         "--samples", "500", "--store", str(store), "--quiet"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, preexec_fn=DEFAULT_SIGINT,
    )
    seen = wait_ready(process)
    pid, _ = start_line(seen)
    group = group_members(pid)  # the server and the helper it started in its process group
    time.sleep(1.0)  # answers under way
    process.send_signal(signal.SIGTERM)
    try:
        rest, _ = process.communicate(timeout=60)
    finally:
        process.kill()
        for member in group:  # the stand-in's helper is the server's child, not lagrseq's
            if member != pid:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(member, signal.SIGKILL)
    assert process.returncode == 143 and "stopped by SIGTERM" in rest, seen + rest
    assert gone(pid), seen + rest
    with RecordStore(store, create=False) as opened:
        kept = sum(len(e.samples) for e in opened.entries())
    assert 0 < kept < 8 * 500


def test_serve_llm_runs_until_sigterm(fake: Path, tmp_path: Path) -> None:
    import httpx

    process = lagrseq("serve-llm", str(fake), "--port", "0", cwd=tmp_path)
    assert process.stdout is not None
    url = process.stdout.readline().split()[0]
    assert httpx.get(f"{url}/models", timeout=10).json()["data"][0]["id"] == "tiny-model"
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    pid, _ = start_line(err)
    assert process.returncode == 143 and "stopped" in err and gone(pid)  # SIGTERM: 143


def test_lagrseq_killed_outright_takes_its_server_along(fake: Path, tmp_path: Path) -> None:
    code = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from lagrseq.llm.local import LocalServer, ServerSettings\n"
        "from lagrseq.progress import Reporter\n"
        "server = LocalServer(ServerSettings(Path(sys.argv[1])), reporter=Reporter(lambda line: print(line, file=sys.stderr, flush=True))).start()\n"
        "time.sleep(600)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", code, str(fake)], stderr=subprocess.PIPE, text=True)
    seen = wait_ready(process)  # type: ignore[arg-type]
    pid, log = start_line(seen)
    helper = helper_pid(log)
    try:
        process.kill()  # SIGKILL: no finally, no atexit; the kernel's parent-death signal remains
        process.wait()
        assert gone(pid)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(helper, signal.SIGKILL)  # the stand-in's helper is the server's child, not ours
        log.unlink(missing_ok=True)  # nobody was left to remove the temporary log


def test_record_with_the_local_server_keys_answers_under_local(fake: Path, tmp_path: Path) -> None:
    from lagrseq.llm.store import RecordStore
    from lagrseq.running import runner

    store = tmp_path / "s"
    code = cli.main(["record", "cube-stacking", "--provider", f"local:{fake}", "--temperature", "1", "--samples", "2",
                     "--concurrency", "2", "--store", str(store), "--quiet"])
    assert code == 0
    with RecordStore(store, create=False) as opened:
        entries = list(opened.entries())
    assert len(entries) == 8 and {e.request["endpoint"] for e in entries} == {"local"}
    assert {e.request["model"] for e in entries} == {"tiny-model"}
    assert all({name: e.request[name] for name in ("top_k", "min_p", "repeat_penalty")} == {"top_k": 0, "min_p": 0.0, "repeat_penalty": 1.0} for e in entries)
    assert all(len(e.samples) == 2 and all(s.origin == "live" for s in e.samples) for e in entries)
    # lagrseq record --mode none asks nobody and finds every pinned key
    assert cli.main(["record", "cube-stacking", "--provider", f"local:{fake}", "--temperature", "1", "--samples", "2",
                     "--mode", "none", "--store", str(store), "--quiet"]) == 0
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=3", "llm.model=tiny-model", "llm.temperature=1.0"])
    options = wiring.provider_options(f"recorded:{store}", {"base_url": "local"})
    assert runner.run_one(config, 0, 0, f"recorded:{store}", tmp_path / "a.mcap", log=False, provider_options=options).queries > 0
    assert cli.main(["cache", "export", "--store", str(store), "--out", str(tmp_path / "s.jsonl")]) == 0
    assert runner.run_one(config, 0, 0, f"recorded:{tmp_path / 's.jsonl'}", tmp_path / "b.mcap", log=False).queries > 0


def test_the_local_provider_has_the_live_limits(fake: Path) -> None:
    """--provider local asks its server through the live provider with the same limits as any
    server: the request deadline (on every read), the response size cap and the read timeout."""
    options = wiring.provider_options("local", {"request_deadline_s": 7.0, "max_response_bytes": 12345, "read_timeout_s": 3.0})
    provider = wiring.make_local(str(fake), options, np.random.default_rng(0))
    try:
        live = provider.inner.inner  # type: ignore[attr-defined]
        assert live.settings.request_deadline_s == 7.0 and live.settings.max_response_bytes == 12345
        assert live.settings.read_timeout_s == 3.0 and live.deadline_bound
    finally:
        provider.close()
