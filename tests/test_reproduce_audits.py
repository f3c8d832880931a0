"""The suite's paper-vs-code audits: the whole suite runs the cube audit, the
grid audits run on request (``--items audit-TASK``), and the report's audit section says how to
run an audit not run and about how long it takes here."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import cli
from lagrseq.errors import ConfigError
from lagrseq.progress import Reporter
from lagrseq.running import runner
from lagrseq.study import reproduce
from lagrseq.study.phases import audits, timing
from lagrseq.suite import Suite, load_suite

TINY_CUBE_AUDIT = reproduce.SuiteAudit("mock:authors-t0", (1, 2, -1), (1, 2, -1))
"""The cube audit at 1 trial of 2 episodes (its 60-odd runs in a few seconds)."""


def test_the_whole_suite_runs_the_cube_audit_and_leaves_the_grid_audits_to_a_request(tmp_path: Path) -> None:
    assert [task for task, audit in reproduce.SUITE_AUDITS.items() if audit.in_suite] == ["cube-stacking"]
    for quick in (True, False):  # the quick suite leaves its reduced grid audits out too
        assert [task for task, _, _ in reproduce.suite_audits(tmp_path, quick, 0)] == ["cube-stacking"]
    assert reproduce.audit_items() == {
        "audit-cube-stacking": "cube-stacking",
        "audit-image-completion": "image-completion",
        "audit-object-arrangement": "object-arrangement",
    }
    chosen = reproduce.suite_audits(tmp_path, True, 0, ["object-arrangement"])
    assert [task for task, _, _ in chosen] == ["object-arrangement"] and len(chosen[0][1]) > 1


def test_items_take_audit_ids_beside_the_suites_items_and_name_them_when_unknown() -> None:
    suite = load_suite()
    assert reproduce.split_items(suite, ["fig6a", "audit-image-completion"]) == (["fig6a"], ["image-completion"])
    assert reproduce.split_items(suite, ["audit-cube-stacking"]) == ([], ["cube-stacking"])
    with pytest.raises(ConfigError) as caught:
        reproduce.split_items(suite, ["fig6a", "audit-tower-of-hanoi"])
    text = str(caught.value)
    assert "\n" not in text and "unknown suite item 'audit-tower-of-hanoi'" in text
    assert "fig6a" in text and "audits (run on request): audit-cube-stacking, audit-image-completion, audit-object-arrangement" in text


def test_the_audit_section_says_how_to_run_an_audit_not_run_and_about_how_long(tmp_path: Path) -> None:
    rerun = lambda items: reproduce.rerun_command(  # noqa: E731
        items, quick=False, suite_path=None, provider=None, out=Path("lagrseq-out"), seed=None, authors_caches=None,
    )
    stem, table, figure = reproduce.audit_section(
        ["cube-stacking"], {"image-completion": 1234.0, "object-arrangement": None}, 2, "local", rerun,
    )
    assert stem == "audits" and figure is None
    rows = {row[0]: row for row in table.rows}
    assert rows["cube-stacking"][1] == "run here: tables audit-cube-stacking below"
    image = rows["image-completion"]
    assert image[1] == (
        "not run: on request (not in the default suite); a table audit-image-completion below, if any, "
        "holds only the one-field switches the suite's own runs make"
    )
    assert image[2] == "`lagrseq reproduce --items audit-image-completion` (or `lagrseq audit image-completion`)"
    assert image[3] == "about 20.6 min on this machine with 2 processes, estimated before the runs"
    assert rows["object-arrangement"][3] == "not estimated here"
    assert list(table.data["estimated_seconds"].isna()) == [True, False, True]


def test_reproduce_items_audit_runs_that_audit_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(reproduce.SUITE_AUDITS, "cube-stacking", TINY_CUBE_AUDIT)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["reproduce", "--quick", "--items", "audit-cube-stacking", "--out", "out", "--jobs", "1", "--quiet"]) == 0
    reports = tmp_path / "out" / "reports"
    planned, _ = audits._audit_plan("cube-stacking", tmp_path / "out" / "runs", True, 0, Reporter.silent())
    assert all(runner.trial_path(run.path, 0).is_file() for run in planned)
    # only the audit's runs: no suite item was planned
    assert {path.parent for path in (tmp_path / "out" / "runs").rglob("*.mcap")} == {run.path for run in planned}
    assert (reports / "tables" / "audit-cube-stacking.md").is_file()
    section = (reports / "tables" / "audits.md").read_text(encoding="utf-8")
    assert "| cube-stacking | run here: tables audit-cube-stacking below | `lagrseq reproduce --quick --items audit-cube-stacking --out out`" in section
    assert "Audits of paper vs code" in (reports / "index.md").read_text(encoding="utf-8")


def test_the_whole_suite_times_an_audit_it_leaves_to_a_request_and_the_report_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The packaged suite stood in for by one small cube item, its cube audit left to a request:
    the audit is timed with the suite's experiments, not run, and the terminal and the report's
    audit section give its command and its estimated time."""
    import lagrseq.suite
    from lagrseq.study import screen

    small = load_suite().select(["fig6a"])
    monkeypatch.setattr(lagrseq.suite, "load_suite", lambda path=None: Suite(small.seed, small.provider, small.items))
    monkeypatch.setattr(screen, "report_sections", lambda: ([], "open models: not made in this test"))
    for task in list(reproduce.SUITE_AUDITS):
        monkeypatch.delitem(reproduce.SUITE_AUDITS, task)
    monkeypatch.setitem(reproduce.SUITE_AUDITS, "cube-stacking", reproduce.SuiteAudit("mock:authors-t0", (1, 2, -1), (1, 2, -1), in_suite=False))
    monkeypatch.setattr(timing, "EPISODES_CALIBRATION_STEPS", 300)
    out = tmp_path / "out"
    reproduce.reproduce(reproduce.Request(None, None, True, None, out, 1), Reporter(quiet=True))
    said = capsys.readouterr().out
    line = next(line for line in said.splitlines() if line.startswith("cube-stacking audit: not in the suite; run it with "))
    assert "`lagrseq reproduce --quick --items audit-cube-stacking --out " in line and "on this machine with 1 process" in line
    planned, _ = audits._audit_plan("cube-stacking", out / "runs", True, 0, Reporter.silent())
    assert not any(run.path.exists() for run in planned)  # timed, not run
    section = (out / "reports" / "tables" / "audits.csv").read_text(encoding="utf-8").splitlines()
    assert section[0] == "audit,run,command,estimated_seconds"
    audit, ran, command, seconds = section[1].split(",")
    assert (audit, ran) == ("cube-stacking", "False") and "--items audit-cube-stacking" in command and float(seconds) > 0
    assert "not run: on request (not in the default suite)" in (out / "reports" / "index.md").read_text(encoding="utf-8")


@pytest.mark.parametrize(("cpus", "jobs", "reading", "replaying"), [(2, 2, 1, 1), (2, 8, 1, 1), (4, 2, 4, 1), (4, 4, 4, 4), (16, 8, 8, 8)])
def test_replay_reads_in_one_process_where_fewer_than_three_can_run(
    monkeypatch: pytest.MonkeyPatch, cpus: int, jobs: int, reading: int, replaying: int
) -> None:
    """On 2 cores, worker processes cost replay more than they save (benchmarks/bench_replay_jobs.py):
    `lagrseq replay`'s default and `reproduce`'s replay read the logs in one process there."""
    import os

    from lagrseq.analysis import loading

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cpus)))
    assert loading.default_jobs() == reading
    assert reproduce.replay_jobs(jobs) == replaying
