"""Throw-away plugin distributions for tests: a module and its ``.dist-info`` (with
``entry_points.txt``) written into a folder put on ``PYTHONPATH``, and the command line run in a
fresh interpreter that finds them, as ``pip install`` would leave them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

GOOD = '''
from lagrseq.registry import PolicySpec


class Coin:
    """Ask on every other decision."""

    def __init__(self):
        self.n = 0

    def decide(self, context):
        self.n += 1
        return self.n % 2

    def update(self, context, asked, query_reward):
        pass


def policy():
    return PolicySpec("coin", lambda section, seq_agent: Coin(), ("budget",), description="every other decision")
'''
"""A well-behaved plugin policy (``coin``)."""


def distribution(root: Path, name: str, version: str, module: str, source: str, entry_points: str) -> None:
    """Install a throw-away distribution under ``root``: its module and its dist-info."""
    (root / f"{module}.py").write_text(source)
    info = root / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(entry_points)


def lagrseq(site: Path, *args: str, cwd: Path, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``python -m lagrseq ARGS`` with ``site``'s plugins installed (and ``env`` added)."""
    full = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LAGRSEQ_PLUGIN_NOTICES_PID")}
    full["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    full.update(env or {})
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=full, cwd=cwd, timeout=timeout)


def skipped(stderr: str) -> dict[str, str]:
    """The skip line of each plugin named on ``stderr``, by the plugin's entry-point name (a
    plugin named twice fails the test)."""
    lines = [line for line in stderr.splitlines() if line.startswith("lagrseq: plugin ")]
    found: dict[str, str] = {}
    for line in lines:
        name = line.split("'")[1]
        assert name not in found, f"plugin {name} named twice: {lines}"
        found[name] = line
    return found
