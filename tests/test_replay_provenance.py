"""Every log names the distribution and version of its task, provider, policy and executor, and
``lagrseq replay`` shows them (the parts table); a report of a plugin's logs is titled by its
tasks, not as the paper's rebuild, and has no empty scoreboard; replayed where the plugin is
not installed, it names the plugin distribution its suite comes from and how to install it.
Real runs and replays of the example plugin (examples/lagrseq-numseq) in fresh interpreters."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from lagrseq import __version__
from lagrseq.logs.reader import read_info
from tests.support.plugins import ROOT, example_code, install, lagrseq

ENTRY_POINTS = (
    "[lagrseq.tasks]\nnumber-sequence = lagrseq_numseq:task_spec\n\n"
    "[lagrseq.policies]\nbackoff = lagrseq_numseq:policy_spec\n"
)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Logs of the number-sequence task made with the example plugin installed (as 0.1.0)."""
    root = tmp_path_factory.mktemp("numseq")
    site = root / "site"
    site.mkdir()
    install(site, "lagrseq-numseq", "0.1.0", "", "", ENTRY_POINTS)  # its code: a copy of the example's package
    example_code(root)
    out = root / "runs"
    done = lagrseq(site, "run", "number-sequence", "--method", "lagr-seq", "--set", 'secondary.policy="backoff"', "--trials", "2",
                   "--set", "run.episodes=3", "--quiet", "--jobs", "1", "--out", str(out), cwd=root, env={"PYTHONPATH": f"{site}:{root / 'example-code'}:{ROOT}"})
    assert done.returncode == 0, done.stderr
    return out


def test_each_log_names_its_parts_and_replay_shows_them(runs: Path, tmp_path: Path) -> None:
    (log, _) = sorted(runs.rglob("trial-*.mcap"))
    parts = json.loads(read_info(log).run["parts"])
    plugin = {"distribution": "lagrseq-numseq", "version": "0.1.0"}
    assert parts["task"] == {"name": "number-sequence", **plugin} and parts["policy"] == {"name": "backoff", **plugin}
    assert parts["provider"] == {"name": "mock", "distribution": "lagrseq", "version": __version__}
    site = runs.parent / "site"
    done = lagrseq(site, "replay", str(runs), "--out", str(tmp_path / "report"), cwd=tmp_path, env={"PYTHONPATH": f"{site}:{runs.parent / 'example-code'}:{ROOT}"})
    assert done.returncode == 0, done.stderr
    with (tmp_path / "report" / "tables" / "parts.csv").open() as file:
        rows = {(r["part"], r["name"]): (r["distribution"], r["version"], r["runs"]) for r in csv.DictReader(file)}
    assert rows[("task", "number-sequence")] == ("lagrseq-numseq", "0.1.0", "1")
    assert rows[("policy", "backoff")] == ("lagrseq-numseq", "0.1.0", "1")
    assert rows[("executor", "")] == ("lagrseq", __version__, "1")
    index = (tmp_path / "report" / "index.md").read_text()
    assert index.startswith("# lagrseq: runs of number-sequence, rebuilt from MCAP logs\n")
    assert "Scoreboard" not in index and "| number-sequence | lagrseq-numseq | 0.1.0 | 1 |" in index
    assert "<h1>lagrseq: runs of number-sequence, rebuilt from MCAP logs</h1>" in (tmp_path / "report" / "index.html").read_text()


def test_replay_without_the_plugin_names_the_distribution_its_suite_comes_from(runs: Path, tmp_path: Path) -> None:
    done = lagrseq(None, "replay", str(runs), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    said = ("the suite of task 'number-sequence' comes from plugin distribution lagrseq-numseq, which is not installed: "
            "pip install lagrseq-numseq")
    assert said in done.stdout and "0 of 0 suite items made" not in done.stdout, done.stdout
    assert done.stdout.strip().splitlines()[-1].startswith("no suite item covers these 2 logs")
    index = (tmp_path / "report" / "index.md").read_text()
    assert not index.startswith("# LaGR-SEQ") and said in index and "Scoreboard" not in index


def test_a_missing_task_is_named_by_what_its_logs_say_made_it() -> None:
    import pandas as pd

    from lagrseq.analysis.loading import Run, RunKey
    from lagrseq.analysis.replay import missing_plugin_notes

    def run(task: str, parts: dict[str, dict[str, str]]) -> Run:
        key = RunKey(task=task, method="lagr", preset="upstream", provider="mock", seed=0, digest="0", variant="")
        return Run(key, {}, (), (), pd.DataFrame(), pd.DataFrame(), 0, parts=parts)

    notes = missing_plugin_notes([
        run("cube-stacking", {"task": {"name": "cube-stacking", "distribution": "lagrseq", "version": "0"}}),  # installed: no line
        run("gone-builtin", {"task": {"name": "gone-builtin", "distribution": "lagrseq", "version": "0.0.1"}}),
        run("unnamed", {}),
    ])
    assert notes == (
        "task 'gone-builtin' was a built-in task of the lagrseq that made its logs, and this one has none of that name: "
        "its suite items cannot be listed",
        "task 'unnamed' is not installed and its logs do not name the plugin distribution that made it: "
        "install that plugin, then replay again to make its suite's items",
    )
