"""Executors without dask: the missing extra in one line, a failing trial in the local pool that
does not stop the others, and what a rerun says before it starts. (Dask itself: tests/dask.)"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from lagrseq.cli import main
from lagrseq.errors import UsageError
from lagrseq.progress import Reporter, ignore
from lagrseq.running import executors

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


def test_a_sweep_runs_several_runs_in_one_pool_with_the_logs_of_one_process(tmp_path: Path) -> None:
    """run_sweep submits every run's trials at once (no worker waits for a run's last trial); the
    logs are byte for byte those of the runs made one after the other in this process, each run's
    progress counts exactly its own units, and a failing trial names its run while the others
    finish."""
    from lagrseq import config as cfg
    from lagrseq.errors import TrialsFailed
    from lagrseq.running import runner

    def runs(root: Path, progress: list[list[int]] | None = None) -> list[runner.SweepRun]:
        made = []
        for i, (method, sets) in enumerate((("lagr", []), ("lagr-seq", ['secondary.policy="thompson"', "secondary.budget=3"]))):
            config = cfg.load("cube-stacking", method, "upstream", overrides=["run.episodes=8", *sets])

            class Count:
                def __init__(self, box: list[int]) -> None:
                    self.box = box

                def update(self, n: int = 1) -> None:
                    self.box.append(n)

            bar = Count(progress[i]) if progress is not None else None
            made.append(runner.SweepRun(config, 3, 0, "mock", runner.run_directory(root, config, "mock", 0), progress=bar))
        return made

    counted: list[list[int]] = [[], []]
    pooled = runner.run_sweep(runs(tmp_path / "pool", counted), jobs=2)
    here = runner.run_sweep(runs(tmp_path / "here"), jobs=1)
    assert [[r.trial for r in results] for results in pooled] == [[0, 1, 2], [0, 1, 2]]
    assert [sum(c) for c in counted] == [3 * 8, 3 * 8]  # episodes of each run's own trials
    logs = {p.relative_to(tmp_path / "pool"): p.read_bytes() for p in (tmp_path / "pool").rglob("*.mcap")}
    assert len(logs) == 6
    assert logs == {p.relative_to(tmp_path / "here"): p.read_bytes() for p in (tmp_path / "here").rglob("*.mcap")}
    assert [r.queries for r in pooled[1]] == [r.queries for r in here[1]] and all(r.queries <= 3 for r in pooled[1])

    broken = runs(tmp_path / "broken")
    (broken[1].directory / "trial-002.mcap.partial").mkdir(parents=True)  # that trial cannot open its log
    warned: list[str] = []
    with pytest.raises(TrialsFailed, match=r"1 of 2 runs had failed trials: 1 of 3 trials failed \(trials 2;") as caught:
        runner.run_sweep(broken, jobs=2, reporter=Reporter(ignore, warned.append))
    assert str(broken[1].directory) in str(caught.value) and str(broken[0].directory) not in str(caught.value)
    assert len(warned) == 1 and warned[0].startswith(f"{broken[1].directory}: trial 2 (seed 0, config ")
    assert len(list(broken[0].directory.glob("*.mcap"))) == 3 and len(list(broken[1].directory.glob("*.mcap"))) == 2
