"""Plugins load the Gymnasium way: each entry point is loaded, called and registered, and nothing
process-wide is changed for it. Each case is a real distribution (a dist-info directory on
``PYTHONPATH``) whose entry point raises, exits, sleeps past the bound, or describes itself with
an ANSI escape and a newline: every command still does its work, names each broken plugin once
(also with ``--jobs 2``), and exits; ``threading.Thread.start`` and the signal handlers are what
they were before the plugins loaded."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq import registry
from tests.support.plugins import GOOD, ROOT, distribution, lagrseq, skipped

HOSTILE = {
    # name: (module source, entry-point group and object)
    "exit0": ("raise SystemExit(0)\n", "lagrseq.tasks", "task"),
    "exit3": ("def task():\n    raise SystemExit(3)\n", "lagrseq.tasks", "task"),
    "raises": ("raise RuntimeError('broken at import')\n", "lagrseq.providers", "provider"),
    "badstr": (
        "class Odd(Exception):\n    def __str__(self):\n        raise RuntimeError('no str for you')\n"
        "def policy():\n    raise Odd()\n",
        "lagrseq.policies", "policy",
    ),
    "signals": ("import signal\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n", "lagrseq.policies", "policy"),
    "sleeper": ("import time\ntime.sleep(3600)\n", "lagrseq.executors", "executor"),
}
ODD = GOOD.replace('PolicySpec("coin"', 'PolicySpec("odd"').replace('description="every other decision"', 'description="\\x1b[31mred\\nFORGED line"')
BOUND = {registry.PLUGIN_TIMEOUT_ENV: "1"}  # a plugin sleeps an hour: its load is abandoned after 1 s


@pytest.fixture()
def site(tmp_path: Path) -> Path:
    root = tmp_path / "site"
    root.mkdir()
    for name, (source, group, attribute) in HOSTILE.items():
        distribution(root, f"{name}-plugin", "0.1", f"{name}plug", source, f"[{group}]\n{name} = {name}plug:{attribute}\n")
    distribution(root, "odd-plugin", "1.0", "oddplug", ODD, "[lagrseq.policies]\nodd = oddplug:policy\n")
    # a second entry point of the sleeping module, in a group loaded later: skipped at once
    with (root / "sleeper_plugin-0.1.dist-info" / "entry_points.txt").open("a") as entry_points:
        entry_points.write("[lagrseq.providers]\nsleeper2 = sleeperplug:provider\n")
    return root


def test_plugins_that_raise_exit_or_hang_are_one_line_each_and_skipped(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "plugins", cwd=tmp_path, env=BOUND, timeout=240)
    assert done.returncode == 0, done.stderr
    found = skipped(done.stderr)
    assert set(found) == {*HOSTILE, "sleeper2"}, done.stderr
    assert len(done.stderr.splitlines()) == len(found)  # one line each, no traceback
    assert "SystemExit: 0" in found["exit0"] and "SystemExit: 3" in found["exit3"]
    assert "RuntimeError: broken at import" in found["raises"] and "raises-plugin 0.1" in found["raises"]
    assert "Odd: (its message cannot be read: str() raised RuntimeError)" in found["badstr"]
    assert "ValueError" in found["signals"]  # it loads off the main thread: it cannot install a handler
    # providers load before executors: the first of the sleeping module's entry points waits 1 s
    assert "did not finish within 1 s" in found["sleeper2"] and registry.PLUGIN_TIMEOUT_ENV in found["sleeper2"]
    assert "its module sleeperplug did not finish importing for another entry point" in found["sleeper"]
    # the odd plugin loads; its description is printed with its escape and newline escaped
    assert "  odd " in done.stdout and "\\x1b[31mred\\nFORGED line" in done.stdout
    assert "\x1b" not in done.stdout and "\nFORGED" not in done.stdout
    assert f"skipped plugins: {len(HOSTILE) + 1}" in done.stdout
    assert "  cube-stacking " in done.stdout  # the built-ins are all there


def test_a_run_goes_on_past_hostile_plugins_and_names_each_once_with_two_workers(site: Path, tmp_path: Path) -> None:
    out = tmp_path / "runs"
    done = lagrseq(site, "run", "cube-stacking", "--method", "lagr-seq", "--set", 'secondary.policy="odd"', "--trials", "2", "--jobs", "2",
                   "--set", "run.episodes=2", "--quiet", "--out", str(out), cwd=tmp_path, env=BOUND, timeout=240)
    assert done.returncode == 0, done.stderr
    assert len(list(out.rglob("trial-*.mcap"))) == 2  # the command did its work, with the plugin policy
    assert {"exit0", "exit3"} <= set(skipped(done.stderr)), done.stderr  # each once, not once per worker
    assert "Traceback" not in done.stderr


PROBE = """
import json, signal, sys, threading
watched = [signal.SIGINT, signal.SIGTERM, signal.SIGCHLD]
before = [threading.Thread.start, threading.excepthook, sys.excepthook] + [signal.getsignal(s) for s in watched]
from lagrseq import registry
for one in registry.REGISTRIES.values():
    one.names()
after = [threading.Thread.start, threading.excepthook, sys.excepthook] + [signal.getsignal(s) for s in watched]
print(json.dumps({"same": [a is b for a, b in zip(before, after)], "coin": "coin" in registry.POLICIES,
                  "skipped": sorted(f.entry_point for f in registry.FAILURES)}))
"""


def test_loading_plugins_leaves_threading_and_signal_handling_as_they_were(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    distribution(site, "good-plugin", "1.2", "goodplug", GOOD, "[lagrseq.policies]\ncoin = goodplug:policy\n")
    distribution(site, "exit-plugin", "0.1", "exitplug", "raise SystemExit(1)\n", "[lagrseq.tasks]\nexits = exitplug:task\n")
    distribution(site, "raise-plugin", "0.1", "raiseplug", "raise ImportError('gone')\n", "[lagrseq.executors]\nraises = raiseplug:x\n")
    env = {"PYTHONPATH": f"{site}:{ROOT}", registry.PLUGIN_TIMEOUT_ENV: "5"}
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    assert seen["same"] == [True] * 6 and seen["coin"] and seen["skipped"] == ["exits", "raises"], seen
    assert [line.split(" skipped: ")[1] for line in done.stderr.splitlines()] == ["SystemExit: 1", "ImportError: gone"]


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
