"""``lagrseq reproduce`` when a run fails: every other item is still reported, the failed item is
marked FAILED on the index and the scoreboard with its reason and the command that reruns it
alone, the whole error goes to OUT/reproduce-errors.log, the terminal gets short lines and one
summary, and the exit status is the documented 3. A rerun prints the same plan."""

from __future__ import annotations

import functools
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import lagrseq
from lagrseq import cli
from lagrseq.progress import Reporter
from lagrseq.running import runner
from lagrseq.study import reproduce
from lagrseq.study.phases import audits

ROOT = Path(lagrseq.__file__).resolve().parents[1]

SUITE = """
[suite]
seed = 0
provider = "mock"

[[items]]
id = "curves"
title = "Returns"
render = "returns"
task = "cube-stacking"
preset = "upstream"
quick_trials = 2
quick_episodes = 8

[[items.runs]]
label = "LaGR-SEQ"
method = "lagr-seq"

[[items.runs]]
label = "Q-learning"
method = "baseline"

[[items]]
id = "asking"
title = "When to ask"
render = "frontier"
task = "cube-stacking"
preset = "upstream"
quick_trials = 2
quick_episodes = 8

[[items.runs]]
label = "never"
method = "baseline"

[[items.runs]]
label = "seq"
method = "lagr-seq"

[[items]]
id = "broken"
title = "Queries on a store that misses"
render = "query-table"
row_header = "τ"
task = "cube-stacking"
preset = "upstream"
quick_trials = 2
quick_episodes = 8
reference = { "0|LaGR-SEQ" = "126 ± 2.94" }

[[items.runs]]
label = "LaGR-SEQ"
method = "lagr-seq"
row = "0"
column = "LaGR-SEQ"
provider = "recorded:STORE"
"""


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
    )


@pytest.fixture(scope="module")
def failed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str], subprocess.CompletedProcess[str]]:
    root = tmp_path_factory.mktemp("failing-suite")
    # a store of one real answer to another model's prompt: every query of the run misses it
    store = root / "tiny-store.jsonl"
    first = (ROOT / "recorded_llm" / "smollm2-135m-cube-t0.jsonl").read_text(encoding="utf-8").splitlines()[0]
    store.write_text(first + "\n", encoding="utf-8")
    (root / "suite.toml").write_text(SUITE.replace("STORE", store.as_posix()), encoding="utf-8")
    args = ["reproduce", "--quick", "--suite", "suite.toml", "--out", "out", "--jobs", "1", "--quiet"]
    return root, args, _cli(*args, cwd=root)


def test_a_failed_item_leaves_the_others_reported_and_exits_3(failed) -> None:  # type: ignore[no-untyped-def]
    root, _args, result = failed
    assert result.returncode == cli.ITEMS_FAILED == 3, result.stderr
    reports = root / "out" / "reports"
    # every other item is made, with its figure
    assert (reports / "figures" / "curves.png").is_file() and (reports / "figures" / "asking.png").is_file()
    index_md = (reports / "index.md").read_text(encoding="utf-8")
    index_html = (reports / "index.html").read_text(encoding="utf-8")
    assert "## Returns (made)" in index_md and "## Queries on a store that misses (FAILED)" in index_md
    assert '<span class="status failed">FAILED</span>' in index_html
    rerun = "lagrseq reproduce --quick --items broken --suite suite.toml --out out"
    for page in (index_md, index_html):
        assert "2 of 2 trials of cube-stacking lagr-seq" in page and "no recorded answer in tiny-store.jsonl" in page
        assert rerun in page
        assert "run the same command again" not in page  # a store's miss is deterministic
        failure = next(line for line in page.splitlines() if "trials of cube-stacking lagr-seq" in line)
        assert str(root) not in failure  # no absolute path in a report file
    # the scoreboard has its row, FAILED, with the command that reruns it
    board = (reports / "scoreboard.md").read_text(encoding="utf-8")
    row = next(line for line in board.splitlines() if line.startswith("| Queries on a store that misses"))
    assert "FAILED" in row and rerun in row and "1 value" in row
    assert "failed" in (reports / "tables" / "scoreboard.csv").read_text(encoding="utf-8")


def test_the_terminal_gets_short_lines_and_the_log_the_whole_text(failed) -> None:  # type: ignore[no-untyped-def]
    root, _args, result = failed
    errors = result.stderr.splitlines()
    runs = [line for line in errors if line.startswith("failed: broken:")]
    assert len(runs) == 1, result.stderr
    assert len(runs[0]) <= reproduce.LINE_WIDTH
    assert runner.MISS_ADVICE in runs[0] and "run the same command again" not in runs[0]
    # one summary line at the end, naming the item, its failed runs and the log
    assert errors[-1] == (
        "lagrseq reproduce: 1 of 3 items failed: broken (1 run); details in out/reproduce-errors.log"
    )
    assert max(map(len, errors)) <= reproduce.LINE_WIDTH
    assert not any(line.startswith("warning:") for line in errors)  # the failed trials' logs: said above
    log = (root / "out" / "reproduce-errors.log").read_text(encoding="utf-8")
    trials = re.findall(r"^trial (\d) \(seed 0, config [0-9a-f]+\) failed: no recorded answer in (\S+)", log, re.M)
    assert [t for t, _ in trials] == ["0", "1"] and trials[0][1] == str(root / "tiny-store.jsonl")
    assert "nearest recorded keys" in log  # the whole text, which the terminal line cuts short
    assert f"what to do: {runner.MISS_ADVICE}" in log
    assert "run: runs/cube-stacking/lagr-seq/" in log  # paths inside OUT relative to it
    assert "2 of 2 trials failed" in log
    assert log.endswith("== to rerun each alone\nbroken: lagrseq reproduce --quick --items broken --suite suite.toml --out out\n")


def test_a_rerun_prints_the_first_runs_plan_and_fails_the_same_way(failed) -> None:  # type: ignore[no-untyped-def]
    root, args, first = failed
    again = _cli(*args, cwd=root)
    assert again.returncode == 3, again.stderr

    def plan(result: subprocess.CompletedProcess[str]) -> str:
        line = next(line for line in result.stdout.splitlines() if line.startswith("quick suite:"))
        return re.sub(r"\d+ to run \(\d+ already complete\)|, \d+ already complete\)|; expected about .*", "", line)

    # the frontier's matched-rate random run was made after the first plan and is planned with
    # the others by the rerun: both count it apart, by the policy it follows
    assert plan(first) == plan(again) == (
        "quick suite: 3 runs, 6 trial logs, , then up to 1 run of random at the frontier policies' "
        "matched query rates (2 trial logs"
    )
    assert "3 runs, 6 trial logs, 2 to run (4 already complete), then up to 1 run of" in again.stdout
    assert "(2 trial logs, 2 already complete)" in again.stdout
    # the store still misses: the same item fails, and nothing else ran again
    assert again.stderr.splitlines()[-1] == first.stderr.splitlines()[-1]


def test_a_run_that_cannot_start_fails_its_items_and_not_the_suite(tmp_path: Path) -> None:
    """Any failing run, not only a store's miss: here a run directory holding another run's log."""
    from lagrseq.suite import load_suite

    suite_file = tmp_path / "suite.toml"
    suite_file.write_text(SUITE.split("[[items]]\nid = \"asking\"")[0], encoding="utf-8")
    suite = load_suite(suite_file)
    the_plan = reproduce.plan(suite, quick=True, provider=None, runs_dir=tmp_path / "runs", seed=0)
    first, second = the_plan.runs
    # a complete log of the baseline run where the lagr-seq run's trial 0 goes: refused before it starts
    runner.run_trials(second.config, 1, 0, second.provider, second.path)
    first.path.mkdir(parents=True)
    runner.trial_path(second.path, 0).rename(runner.trial_path(first.path, 0))
    failures: list[reproduce.RunFailure] = []
    reproduce.execute(the_plan, jobs=2, failures=failures)
    assert [f.items for f in failures] == [("curves",)]
    assert failures[0].failed == failures[0].total == 2
    assert failures[0].advice == runner.FIX_ADVICE and len(failures[0].line()) <= reproduce.LINE_WIDTH
    assert runner.trial_path(second.path, 1).is_file()  # the other run went on


def test_a_suite_whose_every_run_failed_still_writes_a_report_listing_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    store = tmp_path / "tiny-store.jsonl"
    store.write_text((ROOT / "recorded_llm" / "smollm2-135m-cube-t0.jsonl").read_text(encoding="utf-8").splitlines()[0] + "\n")
    head, broken = SUITE.split("[[items]]")[0], SUITE[SUITE.index('[[items]]\nid = "broken"'):]
    (tmp_path / "suite.toml").write_text(head + broken.replace("STORE", store.as_posix()), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    status = cli.main(["reproduce", "--quick", "--suite", "suite.toml", "--out", "out", "--jobs", "1", "--quiet"])
    err = capsys.readouterr().err.splitlines()
    assert status == 3
    assert err[-1] == "lagrseq reproduce: 1 of 1 items failed: broken (1 run); details in out/reproduce-errors.log"
    index = (tmp_path / "out" / "reports" / "index.md").read_text(encoding="utf-8")
    assert "## Queries on a store that misses (FAILED)" in index
    assert "rerun it alone: `lagrseq reproduce --quick --items broken --suite suite.toml --out out`" in index
    # a later run in which nothing fails removes the stale log (here: the item left out)
    (tmp_path / "suite.toml").write_text(SUITE.split('[[items]]\nid = "asking"')[0], encoding="utf-8")
    assert cli.main(["reproduce", "--quick", "--suite", "suite.toml", "--out", "out", "--jobs", "1", "--quiet"]) == 0
    assert not (tmp_path / "out" / "reproduce-errors.log").exists()
    assert "FAILED" not in (tmp_path / "out" / "reports" / "index.md").read_text(encoding="utf-8")


def test_a_failed_audit_run_is_reported_and_the_audit_goes_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The cube audit at 1 trial of 2 episodes, one of its run folders holding another run's log."""
    from lagrseq.analysis.replay import replay
    from lagrseq.suite import load_suite

    monkeypatch.setitem(reproduce.SUITE_AUDITS, "cube-stacking", reproduce.SuiteAudit("mock:authors-t0", (1, 2, -1), (1, 2, -1)))
    runs_dir = tmp_path / "runs"
    planned, _ = audits._audit_plan("cube-stacking", runs_dir, True, 0, Reporter.silent())
    victim, donor = planned[0], planned[1]
    runner.run_trials(donor.config, 1, 0, donor.provider, donor.path)
    victim.path.mkdir(parents=True)
    runner.trial_path(donor.path, 0).rename(runner.trial_path(victim.path, 0))
    failures: list[reproduce.RunFailure] = []
    reproduce.run_suite_audit("cube-stacking", runs_dir, True, 1, 0, Reporter.silent(), failures=failures)
    assert [(f.audit, f.items, f.path) for f in failures] == [("cube-stacking", (), victim.path)]
    assert all(runner.trial_path(r.path, 0).is_file() for r in planned[1:])  # the others ran
    # the report names it (and is written), with the command that reruns that audit alone
    rerun = functools.partial(
        reproduce.rerun_command, quick=True, suite_path=None, provider=None, out=tmp_path / "out", seed=None, authors_caches=None,
    )
    failed, problems = reproduce.item_failures(failures, rerun)
    assert failed == {} and list(problems) == ["cube-stacking audit"]
    assert problems["cube-stacking audit"].rerun == f"lagrseq reproduce --quick --items audit-cube-stacking --out {tmp_path / 'out'}"
    suite_file = tmp_path / "suite.toml"
    suite_file.write_text(SUITE.split("[[items]]")[0] + "[[items]]" + SUITE.split("[[items]]")[1], encoding="utf-8")
    (tmp_path / "no-runs").mkdir()  # the failure alone (the audit's tables: test_audit.py)
    report = replay([tmp_path / "no-runs"], tmp_path / "report", suite=load_suite(suite_file), problems=problems, jobs=1)
    assert report.problems and "cube-stacking audit: FAILED: 1 of 1 trials of cube-stacking" in (tmp_path / "report" / "index.md").read_text()


def test_the_exit_status_is_documented_in_the_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["reproduce", "--help"])
    assert f"{cli.ITEMS_FAILED} finished, but some items failed (one summary line on stderr)" in capsys.readouterr().out
    text = (ROOT / "docs" / "reproduce.md").read_text(encoding="utf-8")
    assert f"| {cli.ITEMS_FAILED} | finished, but some items failed" in text and reproduce.ERRORS_LOG in text


@pytest.mark.parametrize(
    ("text", "shown"),
    [
        ("no recorded answer in /tmp/x/store.jsonl for task t", "no recorded answer in store.jsonl for task t"),
        ("recorded:/srv/a b/s.jsonl (config 1)", "recorded:a b/s.jsonl (config 1)"),
        ("a log at /home/u/out/runs/t/trial-000.mcap.", "a log at trial-000.mcap."),
        ("relative recorded_llm/s.jsonl, http://127.0.0.1:8080/v1 and ~/x stay", "relative recorded_llm/s.jsonl, http://127.0.0.1:8080/v1 and ~/x stay"),
    ],
)
def test_a_failure_in_a_report_names_no_absolute_path(text: str, shown: str) -> None:
    assert reproduce.without_absolute_paths(text) == shown
