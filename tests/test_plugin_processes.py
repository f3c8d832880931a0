"""A plugin that starts processes while it loads leaves none running (issue 37).

Real distributions on ``PYTHONPATH`` whose import starts a child (``subprocess.Popen``), double-forks
a daemon (fork, setsid, fork; the middle process exits), or does both and then hangs past
``LAGRSEQ_PLUGIN_TIMEOUT_S``. Each writes the pids it started to a file; after a real
``lagrseq plugins`` process returns, none of them is running. A process that existed before a
plugin loaded is never touched (:class:`lagrseq.lifetime.ProcessWindow`).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from lagrseq import registry
from lagrseq.lifetime import ProcessWindow, descendants
from tests.test_plugins import GOOD, ROOT, distribution

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the process window needs Linux (prctl, /proc)")

PIDS_ENV = "LAGRSEQ_TEST_PLUGIN_PIDS"
SLEEP = "import time; time.sleep(60)"
CHILD = f"""
import os, subprocess, sys
_child = subprocess.Popen([sys.executable, "-c", {SLEEP!r}])
with open(os.environ[{PIDS_ENV!r}], "a") as _pids:
    _pids.write(f"{{_child.pid}}\\n")
"""
DAEMON = f"""
import os, time
_middle = os.fork()
if _middle == 0:
    try:
        os.setsid()
        _daemon = os.fork()
        if _daemon == 0:
            time.sleep(60)
            os._exit(0)
        with open(os.environ[{PIDS_ENV!r}], "a") as _pids:
            _pids.write(f"{{_daemon}}\\n")
    finally:
        os._exit(0)
os.waitpid(_middle, 0)
"""
HANG = CHILD + DAEMON + "time.sleep(3600)\n"


def _policy(source: str, name: str) -> str:
    return source + GOOD.replace('PolicySpec("coin"', f'PolicySpec("{name}"')


@pytest.fixture()
def site(tmp_path: Path) -> Path:
    root = tmp_path / "site"
    root.mkdir()
    distribution(root, "child-plugin", "0.1", "childplug", _policy(CHILD, "child"), "[lagrseq.policies]\nchild = childplug:policy\n")
    distribution(root, "daemon-plugin", "0.1", "daemonplug", _policy(DAEMON, "daemon"), "[lagrseq.policies]\ndaemon = daemonplug:policy\n")
    distribution(root, "hang-plugin", "0.1", "hangplug", _policy(HANG, "hang"), "[lagrseq.policies]\nhang = hangplug:policy\n")
    return root


def _running(pid: int) -> bool:
    """``pid`` exists and is not a zombie (a zombie has ended; one whose parent is gone may wait
    for an init that does not reap)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as file:
            data = file.read()
    except OSError:
        return False
    return data[data.rfind(b")") + 2 :].split()[0] != b"Z"


def _still_running(pids: list[int], wait_s: float = 5.0) -> list[int]:
    """The pids still running after up to ``wait_s`` (a killed process needs a moment to go)."""
    deadline = time.monotonic() + wait_s
    while True:
        left = [pid for pid in pids if _running(pid)]
        if not left or time.monotonic() > deadline:
            return left
        time.sleep(0.05)


def _subreaper(on: int) -> int:
    """Set this process's child-subreaper flag; the earlier value."""
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    previous = ctypes.c_int(0)
    assert prctl(37, ctypes.byref(previous), 0, 0, 0) == 0  # PR_GET_CHILD_SUBREAPER
    assert prctl(36, ctypes.c_ulong(on), 0, 0, 0) == 0  # PR_SET_CHILD_SUBREAPER
    return previous.value


@pytest.fixture()
def pid_file(tmp_path: Path) -> Iterator[Path]:
    """The file the plugins write their pids to. The test process is a child subreaper meanwhile:
    a process orphaned by lagrseq's exit is reparented here, and stays visible, instead of to an
    init that may kill or reap it on its own (this machine's does), hiding a leftover."""
    path = tmp_path / "pids.txt"
    previous = _subreaper(1)
    try:
        yield path
    finally:
        for pid in _read(path):  # a failing test leaves no sleeper and no zombie behind
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
        _subreaper(previous)


def _read(path: Path) -> list[int]:
    return [int(line) for line in path.read_text().split()] if path.exists() else []


def test_processes_a_plugin_starts_while_it_loads_are_stopped(site: Path, pid_file: Path, tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", registry.NOTICES_ENV)}
    env.update({"PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]), registry.PLUGIN_TIMEOUT_ENV: "2", PIDS_ENV: str(pid_file)})
    # files, not pipes: a leftover process holding a pipe would make run() wait for it to end
    with (tmp_path / "out.txt").open("w+") as out, (tmp_path / "err.txt").open("w+") as err:
        code = subprocess.run([sys.executable, "-m", "lagrseq", "plugins"], stdout=out, stderr=err, env=env, cwd=tmp_path, timeout=240).returncode
    done = subprocess.CompletedProcess([], code, (tmp_path / "out.txt").read_text(), (tmp_path / "err.txt").read_text())
    assert done.returncode == 0, done.stderr
    pids = _read(pid_file)
    assert len(pids) == 4, (pids, done.stderr)  # child: 1, daemon: 1, hang: 2 (and it hung)
    assert _still_running(pids) == [], done.stderr
    lines = [line for line in done.stderr.splitlines() if line.startswith("lagrseq: plugin ")]
    assert len(lines) == 3, done.stderr  # one line per plugin
    by_name = {line.split("'")[1]: line for line in lines}
    assert "loaded, but it left 1 process running when it loaded; it was stopped (SIGKILL)" in by_name["child"]
    assert "loaded, but it left 1 process running" in by_name["daemon"]
    assert "skipped: its loading did not finish within 2 s" in by_name["hang"]
    assert "it left 2 processes running when it loaded; they were stopped (SIGKILL)" in by_name["hang"]
    assert "  child " in done.stdout and "  daemon " in done.stdout  # the well-behaved rest of them loads


def test_the_window_never_touches_a_process_that_was_there_before() -> None:
    sleep = [sys.executable, "-c", SLEEP]
    before = subprocess.Popen(sleep)  # like a pool worker or multiprocessing's resource tracker
    try:
        window = ProcessWindow().open()
        during = subprocess.Popen(sleep)
        finished = subprocess.Popen([sys.executable, "-c", "pass"])
        finished.wait()  # ended and reaped inside the window: nothing to stop
        assert window.close() == 1
        assert _still_running([during.pid], wait_s=2.0) == []
        assert during.pid not in descendants()  # reaped by the window, no zombie left
        assert before.poll() is None and _running(before.pid)
    finally:
        before.kill()
        before.wait()


def test_a_window_where_nothing_starts_stops_nothing() -> None:
    window = ProcessWindow().open()
    assert window.close() == 0
