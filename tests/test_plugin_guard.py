"""Plugins that misbehave while they load cannot take a command down (issue 37).

Each case is a real distribution (a dist-info directory on ``PYTHONPATH``) whose entry point
raises ``SystemExit``, ``KeyboardInterrupt`` or an exception whose ``str`` raises, sleeps in its
import, starts a non-daemon thread, or describes itself with an ANSI escape and a newline; every
command still does its work, names each broken plugin once (also with ``--jobs 2``), and exits.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq import registry
from tests.test_plugins import GOOD, ROOT, distribution

HOSTILE = {
    # name: (module source, entry-point group and object)
    "exit0": ("raise SystemExit(0)\n", "lagrseq.tasks", "task"),
    "exit3": ("def task():\n    raise SystemExit(3)\n", "lagrseq.tasks", "task"),
    "interrupt": ("raise KeyboardInterrupt\n", "lagrseq.policies", "policy"),
    "badstr": (
        "class Odd(Exception):\n    def __str__(self):\n        raise RuntimeError('no str for you')\n"
        "def policy():\n    raise Odd()\n",
        "lagrseq.policies", "policy",
    ),
    "sleeper": ("import time\ntime.sleep(3600)\n", "lagrseq.executors", "executor"),
}
THREAD = GOOD.replace(
    "from lagrseq.registry import PolicySpec\n",
    "from lagrseq.registry import PolicySpec\nimport threading, time\n"
    "threading.Thread(target=time.sleep, args=(3600,), daemon=False).start()\n",
).replace('PolicySpec("coin"', 'PolicySpec("threaded"').replace('description="every other decision"', 'description="\\x1b[31mred\\nFORGED line"')


@pytest.fixture()
def site(tmp_path: Path) -> Path:
    root = tmp_path / "site"
    root.mkdir()
    for name, (source, group, attribute) in HOSTILE.items():
        distribution(root, f"{name}-plugin", "0.1", f"{name}plug", source, f"[{group}]\n{name} = {name}plug:{attribute}\n")
    distribution(root, "thread-plugin", "1.0", "threadplug", THREAD, "[lagrseq.policies]\nthreaded = threadplug:policy\n")
    # a second entry point of the sleeping module, in a group loaded later: skipped at once
    with (root / "sleeper_plugin-0.1.dist-info" / "entry_points.txt").open("a") as entry_points:
        entry_points.write("[lagrseq.providers]\nsleeper2 = sleeperplug:provider\n")
    return root


def lagrseq(site: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", registry.NOTICES_ENV)}
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    env[registry.PLUGIN_TIMEOUT_ENV] = "1"
    # the timeout bounds a hang: a plugin sleeps an hour, and its thread would hold the exit
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=240)


def _skipped(stderr: str) -> dict[str, str]:
    lines = [line for line in stderr.splitlines() if line.startswith("lagrseq: plugin ")]
    found: dict[str, str] = {}
    for line in lines:
        name = line.split("'")[1]
        assert name not in found, f"plugin {name} named twice: {lines}"
        found[name] = line
    return found


def test_plugins_that_exit_interrupt_hang_or_spawn_threads_are_skipped_and_listed(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "plugins", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    skipped = _skipped(done.stderr)
    assert set(skipped) == {*HOSTILE, "sleeper2"}, done.stderr
    assert "SystemExit: 0" in skipped["exit0"] and "SystemExit: 3" in skipped["exit3"]
    assert "KeyboardInterrupt" in skipped["interrupt"]
    assert "Odd: (its message cannot be read: str() raised RuntimeError)" in skipped["badstr"]
    # providers load before executors: the first of the sleeping module's entry points waits 1 s
    assert "did not finish within 1 s" in skipped["sleeper2"] and registry.PLUGIN_TIMEOUT_ENV in skipped["sleeper2"]
    assert "its module sleeperplug did not finish importing for another entry point" in skipped["sleeper"]
    # the threaded plugin loads; its description is printed with its escape and newline escaped
    assert "  threaded " in done.stdout and "\\x1b[31mred\\nFORGED line" in done.stdout
    assert "\x1b" not in done.stdout and "\nFORGED" not in done.stdout
    assert f"skipped plugins: {len(HOSTILE) + 1}" in done.stdout
    assert "  cube-stacking " in done.stdout  # the built-ins are all there


def test_a_run_goes_on_past_hostile_plugins_and_names_each_once_with_two_workers(site: Path, tmp_path: Path) -> None:
    out = tmp_path / "runs"
    done = lagrseq(site, "run", "cube-stacking", "--method", "lagr-seq", "--trials", "2", "--jobs", "2",
                   "--set", "run.episodes=2", "--quiet", "--out", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert len(list(out.rglob("trial-*.mcap"))) == 2  # the command did its work
    skipped = _skipped(done.stderr)  # each broken plugin once, not once per worker process
    assert {"exit0", "exit3"} <= set(skipped), done.stderr
    assert "Traceback" not in done.stderr


def test_one_line_never_raises_on_a_hostile_exception() -> None:
    class Odd(Exception):
        def __str__(self) -> str:
            raise SystemExit(1)

    assert registry._one_line(Odd()) == "Odd: (its message cannot be read: str() raised SystemExit)"
    assert registry._one_line(ValueError("a\nb\x1b[2J")) == "ValueError: a b\\x1b[2J"


@pytest.mark.parametrize(
    ("text", "shown"),
    [
        ("plain text", "plain text"),
        ("é 中 ✓", "é 中 ✓"),
        ("a\nb", "a\\nb"),
        ("\x1b[31mred", "\\x1b[31mred"),
        ("right\u202eleft", "right\\u202eleft"),
        ("zero\u200bwidth", "zero\\u200bwidth"),
    ],
)
def test_printable_escapes_what_acts_on_a_terminal(text: str, shown: str) -> None:
    assert registry.printable(text) == shown
