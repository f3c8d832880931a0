"""Another machine, simulated: the quick suite's recorded-store items under
``LAGRSEQ_NUMERICS=perturbed`` must finish with a report, and that report is compared with the
committed reference by its verdicts (docs/reproduce.md, "Another machine").

A recorded store holds the prompts the recording machine's runs met; on another CPU the DQN's
numbers differ, its grid trajectories part and meet other prompts. Every item that runs on a
recorded store is taken from the suite itself, so a new one is covered without editing this test.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq.suite import load_suite

REPO = Path(__file__).resolve().parents[1]
REFERENCE = REPO / "docs" / "reference-report"


def recorded_store_items() -> list[str]:
    """The suite's items with at least one run on a recorded store (``recorded:...``)."""
    return [
        item.id for item in load_suite().items
        if any((run.provider or "").startswith("recorded:") for run in item.runs)
    ]


def test_the_suite_has_recorded_store_items_and_one_of_them_trains_a_network() -> None:
    items = recorded_store_items()
    assert "table3" in items  # SmolLM2's answers on image completion: a DQN task
    grid = {run.task for item in load_suite().items if item.id in items for run in item.runs}
    assert "image-completion" in grid


@pytest.mark.torch
def test_recorded_store_items_finish_with_a_report_under_perturbed_numerics(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from lagrseq.logs.reader import read_info

    items = recorded_store_items()
    out = tmp_path / "other-cpu"
    env = {**os.environ, "LAGRSEQ_NUMERICS": "perturbed", "MPLBACKEND": "Agg"}
    command = [sys.executable, "-m", "lagrseq", "reproduce", "--quick", "--items", ",".join(items), "--out", str(out),
               "--jobs", "2", "--quiet"]
    result = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=540)
    assert result.returncode == 0, result.stderr[-1500:]
    reports = out / "reports"
    assert (reports / "index.md").is_file()
    with (reports / "tables" / "table3.csv").open(encoding="utf-8", newline="") as f:
        rows = list(csv.DictReader(f))
    smollm2 = [r for r in rows if "SmolLM2" in r["row"]]  # both modes on SmolLM2's recorded answers
    assert sorted(r["column"] for r in smollm2) == ["LaGR (without SEQ)", "LaGR-SEQ"]
    assert all(int(r["n"]) == 2 for r in smollm2)
    # every image log says it was made under the simulated machine's numerics
    logs = sorted((out / "runs" / "image-completion").rglob("trial-*.mcap"))
    assert logs and all(read_info(path).run.get("numerics") == "perturbed" for path in logs)
    if (REFERENCE / "tables").is_dir():  # the comparison runs on this report (its verdicts: the note's)
        compared = subprocess.run([sys.executable, "-m", "lagrseq", "compare", str(reports), str(REFERENCE)],
                                  cwd=REPO, capture_output=True, text=True, timeout=120)
        assert compared.returncode in (0, 4), compared.stderr  # 4: a verdict flips (the note lists them)
        assert " agree, " in compared.stdout.splitlines()[-1]
