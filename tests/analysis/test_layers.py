"""The analysis layer imports no environment, agent, LLM provider, loop, runner, study or heavy
dependency (DESIGN section 2: replay needs only the logs, the suite's data and analysis code)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import lagrseq

ROOT = Path(lagrseq.__file__).resolve().parents[1]
FORBIDDEN = (
    "lagrseq.envs",
    "lagrseq.agents",
    "lagrseq.llm",
    "lagrseq.loop",
    "lagrseq.running",
    "lagrseq.study",
    "torch",
    "gymnasium",
    "httpx",
    "pybullet",
)


def test_analysis_imports_stay_in_their_layer() -> None:
    script = (
        "import json, sys\n"
        "import lagrseq.analysis.costs, lagrseq.analysis.figures, lagrseq.analysis.items\n"
        "import lagrseq.analysis.loading, lagrseq.analysis.replay, lagrseq.analysis.stats\n"
        "import lagrseq.analysis.tables, lagrseq.logs.recover, lagrseq.logs.foxglove\n"
        "import lagrseq.analysis.frontier, lagrseq.analysis.scoreboard, lagrseq.analysis.audit\n"
        f"print(json.dumps(sorted(m for m in sys.modules if m.startswith({FORBIDDEN!r}))))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == []
