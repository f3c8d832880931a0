"""lagrseq compare on hostile reports and output paths: it never writes over what it reads or
writes two outputs to one path; report text reaches the terminal, Markdown and CSV escaped for
each (and without any guarded API key); a table with a byte-order mark is read, a huge cell does
not pad every row, a FIFO or a link to a device is refused without blocking, and non-finite
numbers or a ``tables`` that is a file are one line with status 2."""

from __future__ import annotations

import csv
import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq import cli
from lagrseq.analysis import compare
from lagrseq.cli import main

KEY = "sk-canaryQ7x9Lm2Pz4Rt8Vw3Yb6Nc1Df5Gh0Jk"
ROOT = Path(__file__).resolve().parents[2]


def report(folder: Path, rows: list[dict[str, str]], bom: bool = False) -> Path:
    """A report folder whose scoreboard holds ``rows`` (each over a plain row's cells)."""
    plain = {"item": "table2", "title": "Table 2", "what": "queries", "source": "mock", "mean": "130",
             "ci_low": "120", "ci_high": "140", "trials": "10", "verdict": "reproduced"}
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, compare.SCOREBOARD_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({**plain, **row} for row in rows)
    (folder / "tables").mkdir(parents=True)
    (folder / "tables" / "scoreboard.csv").write_text(("\ufeff" if bom else "") + buffer.getvalue(), encoding="utf-8")
    (folder / "scoreboard.md").write_text("### Scoreboard\n", encoding="utf-8")
    return folder


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    status = main(["compare", *map(str, args)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def refused(status: int, out: str, err: str) -> str:
    assert status == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, (out, err)
    return err


@pytest.mark.parametrize("target", ["tables/scoreboard.csv", "scoreboard.md"])
def test_an_output_naming_a_file_of_an_input_report_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str], target: str) -> None:
    a, b = report(tmp_path / "a", [{}]), report(tmp_path / "b", [{}])
    before = (b / target).read_bytes()
    for flag in ("--csv", "--markdown"):
        err = refused(*run(capsys, a, b, flag, b / target))
        assert "input" in err
        assert (b / target).read_bytes() == before


def test_two_outputs_on_one_path_are_refused_before_either_is_written(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = report(tmp_path / "a", [{}])
    err = refused(*run(capsys, a, a, "--csv", tmp_path / "same", "--markdown", tmp_path / "same"))
    assert "--csv" in err and "--markdown" in err and not (tmp_path / "same").exists()


def test_report_text_is_escaped_for_each_medium(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    hostile = {"title": "=HYPERLINK(\"http://x\")<script>alert(1)</script>|x", "source": "@SUM(A1)",
               "verdict": "\x1b]0;owned\x07\x1b[2Jreproduced"}
    a = report(tmp_path / "a", [hostile])
    status, out, _ = run(capsys, a, a, "--csv", tmp_path / "c.csv", "--markdown", tmp_path / "c.md")
    assert status == 0
    assert "\x1b" not in out and "\x07" not in out and "\\x1b]0;owned" in out
    markdown = (tmp_path / "c.md").read_text(encoding="utf-8")
    assert "<script>" not in markdown and "&lt;script&gt;" in markdown and "\\|x" in markdown and "\x1b" not in markdown
    cells = next(csv.reader(io.StringIO((tmp_path / "c.csv").read_text(encoding="utf-8").splitlines()[1])))
    assert cells[0] == "scoreboard" and cells[1].startswith("'=HYPERLINK")


def test_a_key_in_a_report_title_or_source_reaches_no_output(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    body = KEY[3:]
    spaced = "\u200b".join(body[i : i + 3] for i in range(0, len(body), 3))
    a = report(tmp_path / "a", [{"title": f"{body} {body.upper()}", "source": spaced, "verdict": body[-12:]}])
    status, out, err = run(capsys, a, a, "--csv", tmp_path / "c.csv", "--markdown", tmp_path / "c.md")
    assert status == 0
    for text in (out, err, (tmp_path / "c.csv").read_text(encoding="utf-8"), (tmp_path / "c.md").read_text(encoding="utf-8")):
        plain = text.replace("\u200b", "").replace("\\u200b", "").lower()
        assert body[:12].lower() not in plain and body[-12:].lower() not in plain


def test_a_scoreboard_saved_with_a_byte_order_mark_is_read(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = report(tmp_path / "a", [{}], bom=True)
    assert [e.value.verdict for e in compare.read_report(a).entries] == ["reproduced"]
    status, out, _ = run(capsys, a, report(tmp_path / "b", [{}]))
    assert status == 0 and "1 agree" in out


def test_one_huge_cell_does_not_pad_every_row(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = [{"title": "T" * 131_000, "item": "long"}] + [{"item": f"i{k}"} for k in range(2000)]
    a = report(tmp_path / "a", rows)
    status, out, _ = run(capsys, a, a)
    assert status == 0 and "…" in out
    assert len(out) < 2001 * 2 * (compare.CELL_WIDTH * 3 + 100)  # not 2,000 rows padded to 131,000
    assert max(map(len, out.splitlines())) < 10 * compare.CELL_WIDTH


@pytest.mark.parametrize("kind", ["fifo", "link to /dev/zero"])
def test_a_table_that_is_no_file_is_refused_without_blocking(tmp_path: Path, kind: str) -> None:
    a = tmp_path / "a"
    (a / "tables").mkdir(parents=True)
    table = a / "tables" / "scoreboard.csv"
    if kind == "fifo":
        os.mkfifo(table)
    else:
        table.symlink_to("/dev/zero")
    done = subprocess.run(
        [sys.executable, "-m", "lagrseq", "compare", str(a), str(a)], capture_output=True, text=True, timeout=60,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert ("FIFO" if kind == "fifo" else "device") in done.stderr


@pytest.mark.parametrize("cell", [("trials", "inf"), ("trials", "1e400"), ("mean", "1e400"), ("ci_high", "-inf")])
def test_a_non_finite_number_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], cell: tuple[str, str]) -> None:
    a = report(tmp_path / "a", [dict([cell])])
    err = refused(*run(capsys, a, a))
    assert cell[0] in err and "finite" in err or "count" in err


def test_a_report_whose_tables_is_a_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = tmp_path / "a"
    a.mkdir()
    (a / "index.md").write_text("# a report\n", encoding="utf-8")
    (a / "tables").write_text("not a folder\n", encoding="utf-8")
    err = refused(*run(capsys, a, a))
    assert "tables" in err and "not a folder" in err


def test_the_way_out_of_a_stopped_command_imports_nothing(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    # a second SIGTERM arriving while the first one's exit path imported a module raised a
    # second traceback: the way out must import nothing
    imported: list[str] = []

    def stop(_args: object) -> int:
        raise cli.Terminated

    def watch(name: str, *args: object, **kwargs: object) -> object:
        imported.append(name)
        return real_import(name, *args, **kwargs)

    import builtins

    real_import = builtins.__import__
    monkeypatch.setitem(cli.COMMANDS, "compare", stop)
    monkeypatch.setattr(builtins, "__import__", watch)
    try:
        status = cli._dispatch(cli.build_parser("compare").parse_args(["compare", "a", "b"]), ["compare", "a", "b"])
    finally:
        monkeypatch.setattr(builtins, "__import__", real_import)
        import signal

        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    assert status == 143 and "stopped by SIGTERM" in capsys.readouterr().err
    assert not [name for name in imported if name.startswith("lagrseq.running")]
