"""The import rules of DESIGN section 2, checked in fresh interpreters."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def loaded_after_import(module: str) -> set[str]:
    code = f"import json, sys; import {module}; print(json.dumps(sorted(sys.modules)))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": str(ROOT)}, check=True
    )
    return set(json.loads(done.stdout))


@pytest.mark.parametrize(
    ("module", "forbidden"),
    [
        ("lagrseq.tasks.cube", ["lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", "lagrseq.experiment", "gymnasium", "torch", "mcap", "httpx"]),
        ("lagrseq.envs", ["lagrseq.llm", "lagrseq.agents", "lagrseq.logs", "torch", "mcap", "httpx"]),
        ("lagrseq.agents.tabular", ["lagrseq.tasks", "lagrseq.envs", "lagrseq.llm", "lagrseq.logs", "gymnasium", "mcap"]),
        ("lagrseq.llm.mock", ["lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.logs", "torch", "gymnasium"]),
        ("lagrseq.logs.reader", ["lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.experiment", "torch", "gymnasium", "httpx"]),
        ("lagrseq.lagr", ["lagrseq.llm.mock", "lagrseq.logs", "lagrseq.envs"]),
        ("lagrseq.seq", ["lagrseq.llm", "lagrseq.logs", "lagrseq.envs"]),
        ("lagrseq.cli", ["lagrseq.experiment", "gymnasium", "torch", "httpx", "mcap", "pandas", "matplotlib"]),
    ],
)
def test_layer_imports(module: str, forbidden: list[str]) -> None:
    loaded = loaded_after_import(module)
    bad = sorted(name for name in forbidden if name in loaded)
    assert not bad, f"importing {module} loads {bad}"
