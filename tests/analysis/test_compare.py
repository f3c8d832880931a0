"""lagrseq compare: two reports by their verdicts (lagrseq/analysis/compare.py, docs/reproduce.md).

Real reports: one made by replay from the shared cube runs, and the committed reference report
(scoreboard and frontier tables); the second report of each pair is a copy with one cell edited.
Exit status 0 when every verdict agrees, 3 when one flips, 2 for a folder that is not a report or
a damaged table (one line).
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

from lagrseq.analysis import compare
from lagrseq.analysis.replay import replay
from lagrseq.cli import COMPARE_FLIPPED, main

REPO = Path(__file__).resolve().parents[2]
REFERENCE = REPO / "docs" / "reference-report"


@pytest.fixture(scope="module")
def cube_report(runs_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("compare") / "report"
    replay([runs_dir], out, jobs=1)
    return out


def copy_report(source: Path, to: Path) -> Path:
    shutil.copytree(source, to, ignore=shutil.ignore_patterns("*.png", "*.gif", "*.html"))
    return to


def edit(path: Path, change) -> None:  # type: ignore[no-untyped-def]
    """Rewrite the CSV table ``path`` with ``change(rows)`` applied to its list of row dicts."""
    with path.open(encoding="utf-8", newline="") as f:
        reader = csv.DictReader(f)
        header, rows = list(reader.fieldnames or []), list(reader)
    rows = change(rows)
    with path.open("w", encoding="utf-8", newline="") as f:
        writer = csv.DictWriter(f, header, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    status = main(["compare", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.skipif(not (REFERENCE / "tables").is_dir(), reason="no committed docs/reference-report/")
def test_a_report_agrees_with_itself(capsys: pytest.CaptureFixture[str]) -> None:
    report = compare.read_report(REFERENCE)
    tables = {e.table for e in report.entries}
    assert "scoreboard" in tables and {"frontier-cube", "frontier-image", "frontier-arrangement"} <= tables
    status, out, err = run(capsys, REFERENCE, REFERENCE)
    assert status == 0 and not err
    n = len(report.entries)
    assert f"{n} rows: {n} agree, 0 flip, 0 only in A, 0 only in B" in out
    # both values with interval and n, the overlap and both verdicts, per row
    entry = next(e for e in report.entries if e.row.startswith("Appendix table: 8 cubes"))
    row = next(line for line in out.splitlines() if line.startswith("Appendix table: 8 cubes"))
    verdict = entry.value.verdict
    assert row.count(entry.value.text()) == 2 and row.split()[-3:] == [verdict, verdict, "agrees"]
    assert entry.value.n == 10 and entry.value.low < entry.value.mean < entry.value.high


def test_a_changed_verdict_flips_with_status_4(cube_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    other = copy_report(cube_report, tmp_path / "other")
    rows = compare.read_report(cube_report).entries
    assert rows and rows[0].table == "scoreboard"
    was = rows[0].value.verdict
    now = "reproduced" if was != "reproduced" else "differs"

    def flip(table: list[dict[str, str]]) -> list[dict[str, str]]:
        table[0]["verdict"] = now
        return table

    edit(other / "tables" / "scoreboard.csv", flip)
    status, out, err = run(capsys, cube_report, other, "--csv", tmp_path / "c.csv", "--markdown", tmp_path / "c.md")
    assert status == COMPARE_FLIPPED == 4
    flipped = [line for line in out.splitlines() if line.rstrip().endswith("FLIPS")]
    assert len(flipped) == 1 and was in flipped[0] and now in flipped[0]
    assert err.strip() == "lagrseq compare: 1 verdict(s) flip between the reports (exit status 4)"
    with (tmp_path / "c.csv").open(encoding="utf-8", newline="") as f:
        written = list(csv.DictReader(f))
    assert [r["status"] for r in written].count("flips") == 1
    assert written[0]["a_verdict"] == was and written[0]["b_verdict"] == now and written[0]["intervals_overlap"] == "true"
    assert "| FLIPS |" in (tmp_path / "c.md").read_text(encoding="utf-8")


def test_a_row_in_one_report_only_is_listed_and_no_flip(cube_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    other = copy_report(cube_report, tmp_path / "other")
    edit(other / "tables" / "scoreboard.csv", lambda rows: rows[1:])
    status, out, _ = run(capsys, other, cube_report, "--differences")
    assert status == 0
    assert "only in B" in out and "0 flip" in out and "1 only in B" in out


def test_an_output_folder_is_read_through_its_reports_folder(cube_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy_report(cube_report, tmp_path / "out" / "reports")
    status, out, _ = run(capsys, tmp_path / "out", cube_report)
    assert status == 0 and f"A: {tmp_path / 'out' / 'reports'}" in out


@pytest.mark.skipif(not (REFERENCE / "tables").is_dir(), reason="no committed docs/reference-report/")
def test_frontier_points_flip_and_matched_random_points_pair_by_order(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    other = copy_report(REFERENCE, tmp_path / "other")

    def change(rows: list[dict[str, str]]) -> list[dict[str, str]]:
        for row in rows:
            if row["policy"] == "random" and row["knobs"] == "p 0.35":
                row["knobs"] = "p 0.36"  # the matched rate moves with the point it is matched to
            if row["policy"] == "thompson":
                row["vs_always"] = "inconclusive" if row["vs_always"] != "inconclusive" else "non-inferior"
        return rows

    edit(other / "tables" / "frontier-cube.csv", change)
    status, out, _ = run(capsys, REFERENCE, other, "--differences")
    assert status == COMPARE_FLIPPED == 4
    lines = out.splitlines()
    section = lines[lines.index("frontier-cube:"):]
    assert [line.split()[0] for line in section if line.rstrip().endswith("FLIPS")] == ["thompson"]
    status, out, _ = run(capsys, REFERENCE, other)
    paired = [line for line in out.splitlines() if line.startswith("random (p 0.35) / random (p 0.36)")]
    assert len(paired) == 3 and all(line.rstrip().endswith("agrees") for line in paired)
    assert "only in" not in out.split("frontier-cube:")[1].split("\n\n")[0]


def _damage(kind: str, folder: Path) -> Path:
    """A report folder (or path) with one kind of defect."""
    if kind == "missing":
        return folder / "nothing-here"
    if kind == "a file":
        path = folder / "report.txt"
        path.write_text("not a folder\n", encoding="utf-8")
        return path
    if kind == "not a report":
        (folder / "empty").mkdir()
        return folder / "empty"
    tables = folder / "report" / "tables"
    tables.mkdir(parents=True)
    scoreboard = tables / "scoreboard.csv"
    header = ",".join(compare.SCOREBOARD_COLUMNS)
    good = "table2,Table 2,\"τ = 0, LaGR: queries\",mock,130,120,140,10,reproduced"
    text = {
        "missing column": header.replace(",verdict", "") + "\n" + good.rsplit(",", 1)[0] + "\n",
        "extra cell": header + "\n" + good + ",surplus\n",
        "short row": header + "\n" + good.rsplit(",", 2)[0] + "\n",
        "not a number": header + "\n" + good.replace(",130,", ",lots,") + "\n",
        "not a count": header + "\n" + good.replace(",10,", ",-3,") + "\n",
        "quote never closed": header + "\n" + good + "\n\"table2,\n",
    }.get(kind)
    if text is not None:
        scoreboard.write_text(text, encoding="utf-8")
    elif kind == "binary":
        scoreboard.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe" * 64)
    elif kind == "huge":
        with scoreboard.open("wb") as f:
            f.truncate(compare.MAX_CSV_BYTES + 1)  # sparse: no disk, still too large
    return folder / "report"


@pytest.mark.parametrize(
    "kind",
    ["missing", "a file", "not a report", "missing column", "extra cell", "short row", "not a number", "not a count",
     "quote never closed", "binary", "huge"],
)
def test_hostile_input_is_one_line_and_status_2(kind: str, cube_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = _damage(kind, tmp_path)
    for args in ((bad, cube_report), (cube_report, bad)):
        status, out, err = run(capsys, *args, "--csv", tmp_path / "written.csv")
        assert status == 2, (kind, out, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("lagrseq compare: error: ") and len(lines[0]) < 400
        assert "Traceback" not in err and not out
        assert not (tmp_path / "written.csv").exists()  # nothing written from bad input


def test_an_output_file_in_a_missing_folder_is_refused_before_reading(cube_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status, _, err = run(capsys, cube_report, cube_report, "--markdown", tmp_path / "no" / "such" / "c.md")
    assert status == 2 and "--markdown" in err and len(err.strip().splitlines()) == 1


def test_compare_never_writes_its_tables_through_a_link(cube_report: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the rule for every output: a link planted where --csv points is refused, the file it
    # points at untouched
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    link = tmp_path / "c.csv"
    link.symlink_to(victim)
    status, _, err = run(capsys, cube_report, cube_report, "--csv", link)
    assert status == 2 and err.count("\n") == 1 and "symbolic link" in err
    assert victim.read_text() == "keep me" and link.is_symlink()
    status, _, _ = run(capsys, cube_report, cube_report, "--csv", tmp_path / "ok.csv")
    assert status == 0 and (tmp_path / "ok.csv").read_text(encoding="utf-8").startswith("table,")
