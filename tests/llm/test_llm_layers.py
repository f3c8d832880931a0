"""DESIGN section 2: llm/ knows nothing of RL. Each module is imported in a fresh interpreter and
must not pull in tasks, envs, agents, logs, the experiment, torch or gymnasium."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FORBIDDEN = [
    "lagrseq.tasks",
    "lagrseq.envs",
    "lagrseq.agents",
    "lagrseq.logs",
    "lagrseq.loop.experiment",
    "lagrseq.loop.lagr",
    "torch",
    "gymnasium",
    "mcap",
]
MODULES = ["base", "mock", "servers", "pricing", "store", "recorded", "budget", "live", "authors_cache"]


@pytest.mark.parametrize("module", MODULES)
def test_llm_modules_import_no_other_layer(module: str) -> None:
    code = f"import json, sys; import lagrseq.llm.{module}; print(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": str(ROOT)}, check=True)
    loaded = set(json.loads(done.stdout))
    assert not [name for name in FORBIDDEN if name in loaded]


def test_only_the_live_provider_needs_httpx() -> None:
    code = "import json, sys; import lagrseq.llm.recorded, lagrseq.llm.authors_cache; print(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": str(ROOT)}, check=True)
    assert "httpx" not in set(json.loads(done.stdout))
