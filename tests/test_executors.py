"""Executors without dask: the missing extra in one line, a failing trial in the local pool that
does not stop the others, and what a rerun says before it starts. (Dask itself: tests/dask.)"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from lagrseq import executors
from lagrseq.cli import main
from lagrseq.errors import UsageError

SMALL = ["--set", "run.episodes=20", "--quiet"]


def test_executor_dask_without_the_extra_says_what_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else find_spec(name, *a))
    with pytest.raises(UsageError, match=r"pip install 'lagrseq\[dask\]'"):
        executors.make_executor("dask", 2)
    assert main(["run", "cube-stacking", "--executor", "dask", "--trials", "2", "--out", str(tmp_path), *SMALL]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["lagrseq run: error: --executor dask needs dask distributed, which is not installed: pip install 'lagrseq[dask]'"]
    assert not list(tmp_path.rglob("*.mcap"))


def test_task_keys_are_the_run_digest_and_the_trial() -> None:
    digest = executors.run_digest('{"a": 1}', 0, "mock", "runs/x")
    assert digest == executors.run_digest('{"a": 1}', 0, "mock", "runs/x") != executors.run_digest('{"a": 1}', 1, "mock", "runs/x")
    assert executors.task_key(digest, 7) == f"lagrseq-trial-{digest}-007"
    assert executors.task_key(digest, 7, attempt=1) == f"lagrseq-trial-{digest}-007-retry1"


def test_a_failing_trial_in_the_pool_is_named_the_others_finish_and_a_rerun_runs_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["run", "cube-stacking", "--trials", "3", "--jobs", "2", "--out", str(tmp_path), "--name", "r", *SMALL]
    directory = tmp_path / "cube-stacking" / "lagr-seq" / "r"
    (directory / "trial-001.mcap.partial").mkdir(parents=True)  # trial 1 cannot open its log
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("lagrseq run: error: 1 of 3 trials failed (trials 1; first: trial 1 (seed 0, config ")
    assert "IsADirectoryError" in err[0] and "run the same command again" in err[0]
    assert sorted(p.name for p in directory.glob("*.mcap")) == ["trial-000.mcap", "trial-002.mcap"]
    (directory / "trial-001.mcap.partial").rmdir()
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "resuming: 2 trials complete (skipped), 1 missing and 0 unfinished (cut short, failed or recovered) to run" in out
    assert "3 trial logs in" in out and "(2 already complete, skipped)" in out
