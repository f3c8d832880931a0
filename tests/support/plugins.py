"""Throw-away plugin distributions for tests: a module and its ``.dist-info`` (with
``entry_points.txt``) written into a folder put on ``PYTHONPATH``, and the command line run in a
fresh interpreter that finds them, as ``pip install`` would leave them."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def example_code(root: Path) -> Path:
    """A folder under ``root`` holding the example plugin's package (``lagrseq_numseq``) and
    nothing else, to put on ``PYTHONPATH``: the example's own ``src`` may also hold the metadata
    an editable install of it left there (tox's plugin environment does), which would make the
    example a second, installed distribution."""
    code = root / "example-code"
    shutil.copytree(ROOT / "examples" / "lagrseq-numseq" / "src" / "lagrseq_numseq", code / "lagrseq_numseq",
                    ignore=shutil.ignore_patterns("__pycache__"))
    return code

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


NOISY_ORACLE = '''
from dataclasses import dataclass, field

from lagrseq.registry import ProviderKind, flag


@dataclass(frozen=True)
class NoisyOptions:
    oracle_p: float = field(default=1.0, metadata=flag("--oracle-p", "share of answers the ideal mock gives; the others are empty (default {default})", metavar="P", type=float))
    oracle_label: str = field(default="noisy", metadata=flag("--oracle-label", "the model name its answers carry (default {default})", metavar="TEXT"))


def make(spec, config, rng, options):
    from lagrseq.llm.mock import MockProvider
    from lagrseq.running.wiring import extrapolator

    ideal = extrapolator(config, "ideal")

    def answer(prompt, temperature, generator):
        return ideal(prompt, temperature, generator) if generator.random() < options.oracle_p else ""

    return MockProvider(answer, rng, name=f"{options.oracle_label}/{options.oracle_p:g}")


def provider():
    return ProviderKind("noisy-oracle", "noisy-oracle", make, options=NoisyOptions, source="mock", synthetic=True, description="the ideal mock, right with probability --oracle-p")
'''


def install(root: Path, name: str, version: str, module: str, source: str, entry_points: str) -> None:
    """Install a throw-away distribution under ``root``: its module (none where ``module`` is
    empty: its code is elsewhere on the path) and its dist-info (an earlier version of the same
    distribution is removed)."""
    if module:
        (root / f"{module}.py").write_text(source)
    stem = name.replace("-", "_")
    for old in root.glob(f"{stem}-*.dist-info"):
        for file in old.iterdir():
            file.unlink()
        old.rmdir()
    info = root / f"{stem}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(entry_points)


def install_noisy_oracle(root: Path, version: str = "0.1") -> None:
    install(root, "noisy-oracle-plugin", version, "noisyoracle", NOISY_ORACLE, "[lagrseq.providers]\nnoisy-oracle = noisyoracle:provider\n")


def lagrseq(site: Path | None, *args: str, cwd: Path, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``python -m lagrseq ARGS`` with ``site``'s plugins (if any) on PYTHONPATH before this
    checkout, and ``env`` added."""
    environ = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "LAGRSEQ_PLUGIN_NOTICES_PID")}
    environ["PYTHONPATH"] = os.pathsep.join([*([str(site)] if site is not None else []), str(ROOT)])
    environ.update(env or {})
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=environ, cwd=cwd, timeout=timeout)


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
