"""Throw-away plugin distributions for tests: a module and its ``.dist-info`` (with
``entry_points.txt``) in a folder put on PYTHONPATH, and the command line run with it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

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
    """``python -m lagrseq ARGS`` with ``site`` (if any) on PYTHONPATH before this checkout."""
    environ = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    environ["PYTHONPATH"] = os.pathsep.join([*([str(site)] if site is not None else []), str(ROOT)])
    environ.update(env or {})
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=environ, cwd=cwd, timeout=timeout)
