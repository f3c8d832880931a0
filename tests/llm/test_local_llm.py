"""The real open LLM: llama.cpp's server started by lagrseq as a child process, SmolLM2-135M
answering, and no server left behind on any way out (normal end, error, Ctrl-C, SIGTERM, the
parent killed). Needs the local-llm extra: `tox -e local-llm` (marker local_llm)."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from lagrseq import config as cfg
from lagrseq.errors import LagrseqError, ProviderError, UsageError
from lagrseq.llm.local import LocalServer, ServerSettings, missing_extra, packaged_model
from lagrseq.logs.reader import find_logs, read_topic
from lagrseq.loop.lagr import query_for
from lagrseq.progress import Reporter
from lagrseq.running import runner, wiring

pytestmark = [
    pytest.mark.local_llm,
    pytest.mark.skipif(bool(missing_extra()), reason="needs the local-llm extra (pip install 'lagrseq[local-llm]')"),
    pytest.mark.timeout(600),
]
ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}

def DEFAULT_SIGINT() -> None:  # noqa: N802 (used like a constant)
    """In the child: Ctrl-C's default action, so Python raises KeyboardInterrupt there even when
    this test run itself was started as a background job (whose SIGINT is ignored and inherited)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)



def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def gone(pid: int, within_s: float = 15.0) -> bool:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        if not alive(pid):
            return True
        time.sleep(0.1)
    return False


def server_pid(text: str) -> int:
    match = re.search(r"\(pid (\d+),", text)
    assert match, text
    return int(match.group(1))


def settings(**changes: object) -> ServerSettings:
    values: dict[str, object] = {"model": packaged_model(), "n_threads": 1}
    values.update(changes)
    return ServerSettings(**values)  # type: ignore[arg-type]


def test_one_cube_prefix_answered_by_the_real_model_and_the_server_stopped() -> None:
    config = wiring.with_provider_model(cfg.load("cube-stacking", "lagr", "upstream"), "local")
    assert config.llm.model == "SmolLM2-135M-Instruct"
    task = wiring.make_task(config)
    provider = wiring.make_provider("local", config, __import__("numpy").random.default_rng(0), wiring.LocalOptions(threads=1))
    pid = provider.server.process.pid  # type: ignore[attr-defined]
    try:
        assert alive(pid)
        answer = provider.complete(query_for(task, config.llm, task.prefixes()[3]))
    finally:
        provider.close()
    assert answer.source == "live" and answer.text.strip()
    assert answer.usage is not None and answer.usage.prompt_tokens > 100 and answer.usage.completion_tokens > 0
    assert answer.latency_s is not None and answer.latency_s > 0 and answer.cost_usd == 0.0
    assert gone(pid)
    task.parse(answer.text)  # whatever the text, the parser answers (never raises)


def test_start_errors_are_one_line_and_leave_nothing(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="no such file"):
        wiring.local_settings(str(tmp_path / "missing.gguf"), wiring.LocalOptions())
    (tmp_path / "text.gguf").write_text("not a model")
    with pytest.raises(UsageError, match="not a GGUF file"):
        wiring.local_settings(str(tmp_path / "text.gguf"), wiring.LocalOptions())
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(UsageError, match="is taken"):
            LocalServer(settings(port=taken.getsockname()[1])).start()
    # a file that claims to be GGUF and is not: the server exits, its log's reason is the error
    (tmp_path / "broken.gguf").write_bytes(b"GGUF" + b"\0" * 64)
    lines: list[str] = []
    server = LocalServer(settings(model=tmp_path / "broken.gguf"), reporter=Reporter(lines.append))
    with pytest.raises(ProviderError, match="exited with status"):
        server.start()
    assert gone(server_pid(lines[0])) and server.process is None


def test_sigint_stops_the_run_and_its_server(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr", "--provider", "local",
               "--threads", "1", "--trials", "1", "--set", "run.episodes=100", "--out", str(tmp_path / "runs"), "--quiet"]
    process = subprocess.Popen(command, env=ENV, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=tmp_path, preexec_fn=DEFAULT_SIGINT)
    assert process.stderr is not None
    seen = ""
    while "ready" not in seen:
        line = process.stderr.readline()
        assert line, f"lagrseq ended before the server was ready: {seen}"
        seen += line
    time.sleep(2.0)  # some queries under way
    process.send_signal(signal.SIGINT)
    _, rest = process.communicate(timeout=60)
    assert process.returncode == 130, seen + rest
    assert "stopped" in rest and gone(server_pid(seen))


def test_a_killed_parent_takes_its_server_along(tmp_path: Path) -> None:
    code = (
        "import time\n"
        "from lagrseq.llm.local import LocalServer, ServerSettings, packaged_model\n"
        "from lagrseq.progress import Reporter\n"
        "server = LocalServer(ServerSettings(packaged_model(), n_threads=1), reporter=Reporter()).start()\n"
        "print('pid-of-server', server.process.pid, flush=True)\n"
        "time.sleep(600)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", code], env=ENV, stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    pid = 0
    log = None
    for line in process.stdout:
        found = re.search(r"; log (\S+)\)", line)
        log = Path(found.group(1)) if found else log
        if line.startswith("pid-of-server"):
            pid = int(line.split()[1])
            break
    assert pid and alive(pid)
    process.kill()  # SIGKILL: no finally, no atexit; the kernel's parent-death signal remains
    process.wait()
    assert gone(pid)
    if log is not None:
        log.unlink(missing_ok=True)  # nobody was left to remove the temporary log


def test_serve_llm_answers_until_sigterm(tmp_path: Path) -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "lagrseq", "serve-llm", "--port", "0", "--threads", "1"],
        env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert process.stdout is not None
    first = process.stdout.readline()
    url = first.split()[0]
    assert url.startswith("http://127.0.0.1:") and httpx.get(f"{url}/models", timeout=10).status_code == 200
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143 and "stopped" in err  # SIGTERM: 143
    assert gone(server_pid(err))


def test_run_against_the_real_model_logs_live_queries(tmp_path: Path) -> None:
    """One trial of 5 episodes against the real model."""
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ["run.episodes=5"])
    results = runner.run_trials(
        wiring.with_provider_model(config, "local"), 1, 0, "local", tmp_path / "run", provider_options=wiring.LocalOptions(threads=1)
    )
    assert results[0].episodes == 5
    queries = [q for p in find_logs([tmp_path / "run"]) for q in read_topic(p, "/query") if q.get("queried")]
    assert queries and all(q["source"] == "live" and q["model"] == "SmolLM2-135M-Instruct" for q in queries)
    assert all(q["prompt_tokens"] > 100 and q["completion_tokens"] > 0 and q["latency_s"] > 0 for q in queries)


def test_the_extra_missing_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "uvicorn" else real(name, *a))
    with pytest.raises(LagrseqError, match="local-llm extra is not installed"):
        wiring.local_settings("", wiring.LocalOptions())


CHOSEN = "qwen2.5-coder-1.5b-instruct-q4_k_m"
CHOSEN_SHA256 = "cc324af070c2ecbfd324a30884d2f951a7ff756aba85cb811a6ec436933bb046"


def test_a_screen_of_the_chosen_open_model_names_its_file(tmp_path: Path) -> None:
    """`lagrseq screen` live: Qwen2.5-Coder-1.5B-Instruct joined from its chunk packages (the
    tox env installs them, pinned), every prefix asked once, the answers' provenance naming the
    joined file's sha256, and the model right at least once (it is right at 4 and 5 of 8 cubes
    shown, and on the complete stack, at tau = 0: docs/open-models.md)."""
    import json

    from lagrseq.llm.gguf import chunk_files, known_package
    from lagrseq.study.screen import model_of_provenance

    package = known_package(CHOSEN)
    assert package is not None
    if chunk_files(package)[1]:
        pytest.skip(f"the chunk packages of {CHOSEN} are not installed (tox -e local-llm installs them)")
    answers = tmp_path / "a.jsonl"
    done = subprocess.run(
        [sys.executable, "-m", "lagrseq", "screen", "cube-stacking", "--provider", f"local:{CHOSEN}", "--threads", "1",
         "--prompts", "8", "--answers", str(answers), "--out", str(tmp_path / "out"), "--quiet"],
        capture_output=True, text=True, env=ENV, timeout=580,
    )
    assert done.returncode == 0, done.stderr
    records = [json.loads(line) for line in answers.read_text().splitlines()]
    assert len(records) == 8
    assert {model_of_provenance(r["sample"]["provenance"])[0] for r in records} == {CHOSEN_SHA256}
    assert "0/8 = 0%" not in (tmp_path / "out" / "screen-cube-stacking.md").read_text()
