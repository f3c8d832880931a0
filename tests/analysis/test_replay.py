"""lagrseq replay: same logs -> same bytes, core dependencies only, bad logs skipped."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from matplotlib.figure import Figure

import lagrseq
from lagrseq.analysis import replay as replay_module
from lagrseq.analysis.replay import MANIFEST as MANIFEST_NAME
from lagrseq.analysis.replay import replay
from lagrseq.errors import UsageError

ROOT = Path(lagrseq.__file__).resolve().parents[1]
HEAVY = ("torch", "gymnasium", "httpx", "pybullet")


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
    )


def _files(root: Path) -> dict[str, bytes]:
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_same_logs_give_byte_identical_outputs(runs_dir: Path, tmp_path: Path) -> None:
    first = replay([runs_dir], tmp_path / "a", formats=["png", "svg", "pdf"])
    second = replay([runs_dir], tmp_path / "b", formats=["svg", "pdf", "png"])
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert a == b
    assert {
        "figures/fig5a.png",
        "figures/fig5a.svg",
        "figures/fig5a.pdf",
        "index.html",
        "index.md",
    } <= set(a)
    assert {
        "tables/fig6a.md",
        "tables/fig6a.csv",
        "tables/costs-by-run.csv",
        "tables/runs.csv",
    } <= set(a)
    assert sorted(p.relative_to(tmp_path / "a").as_posix() for p in first.written) == sorted(
        p.relative_to(tmp_path / "b").as_posix() for p in second.written
    )
    assert b"Software" not in a["figures/fig5a.png"][:2000]
    assert b"CreationDate" not in a["figures/fig5a.pdf"]


def test_figures_drawn_in_a_worker_process_are_the_same_bytes(
    runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``replay --jobs 2`` draws the figures in a spawned worker process (the figures are pickled
    there): every file, PNG, SVG and PDF, a section's figure included, is byte for byte what
    one process writes."""
    import pandas as pd

    from lagrseq.analysis import figures, loading
    from lagrseq.analysis.tables import Table

    def section() -> tuple[str, Table, Figure]:
        axes = figures.new_axes()
        axes.plot([0, 1, 2], [1.0, 0.5, 0.75], label="a section")
        axes.legend()
        return ("open-models", Table("A section", ("x",), (("1",),), pd.DataFrame({"x": [1]})), axes.figure)  # type: ignore[return-value]

    one = replay([runs_dir], tmp_path / "one", formats=["png", "svg", "pdf"], jobs=1, sections=[section()])
    drawn: list[str] = []
    monkeypatch.setattr(loading, "PARALLEL_MIN_LOGS", 1)  # a few logs: worker processes all the same
    monkeypatch.setattr(replay_module._Painter, "wait", _counting(replay_module._Painter.wait, drawn))
    two = replay([runs_dir], tmp_path / "two", formats=["png", "svg", "pdf"], jobs=2, sections=[section()])
    assert drawn == ["worker"]
    assert _files(tmp_path / "one") == _files(tmp_path / "two")
    assert "figures/open-models.png" in _files(tmp_path / "two")
    assert [p.relative_to(one.out) for p in one.written] == [p.relative_to(two.out) for p in two.written]


def _counting(wait, drawn):  # type: ignore[no-untyped-def]
    def counted(self):  # type: ignore[no-untyped-def]
        if self.pool is not None and self.pending:
            drawn.append("worker")
        return wait(self)

    return counted


def test_replay_needs_no_torch_gymnasium_httpx_or_pybullet(runs_dir: Path, tmp_path: Path) -> None:
    script = (
        "import json, sys\n"
        "from lagrseq.cli import main\n"
        f"code = main(['replay', {str(runs_dir)!r}, '--out', {str(tmp_path / 'out')!r}])\n"
        f"print(json.dumps([code, sorted(m for m in {list(HEAVY)!r} if m in sys.modules)]))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    code, loaded = json.loads(result.stdout.strip().splitlines()[-1])
    assert code == 0
    assert loaded == [], f"replay imported {loaded}"
    assert (tmp_path / "out" / "index.html").exists()


def test_unfinished_and_damaged_logs_are_skipped_with_a_warning(
    runs_dir: Path, tmp_path: Path
) -> None:
    clean = replay([runs_dir], tmp_path / "clean")
    root = tmp_path / "runs"
    shutil.copytree(runs_dir, root)
    trial = sorted(root.rglob("lagr-seq/*/trial-000.mcap"))[0]
    data = trial.read_bytes()
    # cut from a longer trial: in log format 3 a short cube trial's transitions are one chunk,
    # so the first half of its file holds no finished episode
    from lagrseq import config as cfg
    from lagrseq.running import runner

    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=150"])
    longer = runner.run_one(config, 6, 0, "mock", tmp_path / "longer" / "trial-006.mcap").path.read_bytes()
    (trial.parent / "trial-005.mcap.partial").write_bytes(longer[: len(longer) // 2])
    (trial.parent / "trial-006.mcap").write_bytes(longer[: len(longer) // 2])
    flipped = bytearray(data)
    for i in range(len(data) // 2, len(data) // 2 + 32):
        flipped[i] ^= 0xFF
    (trial.parent / "trial-007.mcap").write_bytes(bytes(flipped))
    result = _cli("replay", str(root), "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) >= 2
    assert any("trial-005.mcap.partial" in w and "lagrseq recover" in w for w in warnings)
    assert any("trial-006.mcap" in w for w in warnings)
    assert "Traceback" not in result.stderr
    # the complete trials still give the same tables
    for name in ("fig6a.csv", "appendix-stack-size.csv", "runs.csv"):
        assert (tmp_path / "out" / "tables" / name).read_bytes() == (
            clean.out / "tables" / name
        ).read_bytes()
    page = (tmp_path / "out" / "index.html").read_text()
    assert "trial-005.mcap.partial" in page
    # full paths, and a recover command that runs as written
    assert any(w.startswith(f"warning: {trial.parent / 'trial-006.mcap'}: ") for w in warnings)
    assert any(f"`lagrseq recover {trial.parent / 'trial-006.mcap'}` to repair it" in w for w in warnings)
    assert any(
        w.startswith(f"warning: {trial.parent / 'trial-007.mcap'}: trial 0 of ")
        and w.endswith(f"also in {trial}; skipped")
        for w in warnings
    )
    # the header's totals are those of the logs read; the skipped ones are counted apart
    header = (tmp_path / "out" / "index.md").read_text().splitlines()[2]
    clean_header = (clean.out / "index.md").read_text().splitlines()[2]
    assert "skipped" not in clean_header
    totals = clean_header.split("; lagrseq")[0]
    assert header.startswith(f"{totals}, 3 more skipped (see the warnings); lagrseq")


def test_a_flipped_chunk_length_skips_that_log_only(runs_dir: Path, tmp_path: Path) -> None:
    """One flipped bit in a chunk's data length made replay die of MemoryError."""
    from lagrseq.logs.mcap_reader import McapFile

    root = tmp_path / "runs"
    shutil.copytree(runs_dir, root)
    trial = sorted(root.rglob("lagr-seq/*/trial-001.mcap"))[0]
    with McapFile(trial) as log:
        summary = log.summary()
        assert summary is not None
        episode = next(c for c, ch in summary.channels.items() if ch.topic == "/episode")
        index = next(i for i in summary.chunk_indexes if episode in i.message_index_offsets)
    data = bytearray(trial.read_bytes())
    data[index.chunk_start_offset + 9 + 32 + len("zstd") + 7] ^= 0x40  # data length + 2**62
    trial.write_bytes(bytes(data))
    report = replay([root], tmp_path / "out")
    assert (tmp_path / "out" / "index.html").is_file()
    assert report.logs.skipped == 1
    (warning,) = report.warnings
    assert warning.startswith(f"{trial}: damaged MCAP log (")
    assert "cannot repair it (corrupt at byte" in warning and warning.endswith("; skipped")
    run = next(r for r in report.logs.runs if r.key.method == "lagr-seq")
    assert 1 not in run.trials and len(run.trials) == 2


def test_no_logs_is_one_line_and_status_2(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    result = _cli("replay", str(tmp_path / "empty"), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert (
        len(result.stderr.strip().splitlines()) == 1
        and "no complete lagrseq trial logs" in result.stderr
    )


def test_unknown_format_is_refused(runs_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="unknown figure format 'gif'"):
        replay([runs_dir], tmp_path / "out", formats=["gif"])


def test_index_links_only_to_files_that_exist(runs_dir: Path, tmp_path: Path) -> None:
    report = replay([runs_dir], tmp_path / "out", formats=["png", "svg"])
    page = (tmp_path / "out" / "index.html").read_text()
    targets = re.findall(r'(?:src|href)="([^"#]+)"', page)
    assert targets and all((tmp_path / "out" / t).is_file() for t in targets)
    made = {r.item.id for r in report.items if r.status != "not run"}
    assert {"fig5a", "fig6a", "fig4", "appendix-stack-size"} <= made  # Table 2 runs on mock:authors-t0
    assert "no logs of `image-completion" in page
    from PIL import Image

    for src, width, height in re.findall(
        r'<img src="([^"]+)"[^>]* width="(\d+)" height="(\d+)"', page
    ):
        with Image.open(tmp_path / "out" / src) as image:
            assert image.size == (int(width), int(height))
    markdown = (tmp_path / "out" / "index.md").read_text()
    assert "![Fig. 5(a)" in markdown


def test_a_report_folder_keeps_no_files_of_items_the_latest_replay_did_not_make(runs_dir: Path, tmp_path: Path) -> None:
    import hashlib

    from lagrseq.analysis.replay import MANIFEST

    out = tmp_path / "report"
    first = replay([runs_dir], out)
    made = {p.relative_to(out).as_posix() for p in first.written}
    listed = [line.split("  ", 1) for line in (out / MANIFEST).read_text().splitlines()]
    assert [name for _, name in listed] == sorted(made)
    assert all(digest == hashlib.sha256((out / name).read_bytes()).hexdigest() for digest, name in listed)
    # an item an earlier run made and this one does not (the arm items without the arm extra),
    # and a file of the user's, which replay never wrote
    stale = ["figures/fig5c-arm.png", "figures/fig5c-arm-arm.gif", "tables/fig6c-arm.md"]
    for name in stale:
        (out / name).write_bytes(b"old")
    old = hashlib.sha256(b"old").hexdigest()
    lines = [f"{digest}  {name}" for digest, name in listed] + [f"{old}  {name}" for name in stale]
    (out / MANIFEST).write_text("\n".join([*lines, f"{old}  ../outside.txt", f"{old}  notes/mine.txt"]) + "\n")
    (tmp_path / "outside.txt").write_bytes(b"old")
    (out / "notes").mkdir()
    (out / "notes" / "mine.txt").write_bytes(b"old")
    (out / "figures" / "my-sketch.png").write_bytes(b"mine")
    again = replay([runs_dir], out)
    assert {p.relative_to(out).as_posix() for p in again.written} == made
    assert not any((out / name).exists() for name in stale)
    assert (tmp_path / "outside.txt").exists() and (out / "notes" / "mine.txt").exists()
    assert (out / "figures" / "my-sketch.png").exists()


def test_a_planted_manifest_entry_never_deletes_a_file_replay_did_not_write(runs_dir: Path, tmp_path: Path) -> None:
    from lagrseq.analysis.replay import MANIFEST

    out = tmp_path / "report"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "fig5c-arm.png").write_bytes(b"the user's own figure")
    (out / "tables").mkdir()
    (out / "tables" / "notes.md").write_bytes(b"mine")
    # listed without a digest, and with the digest of other bytes
    (out / MANIFEST).write_text("figures/fig5c-arm.png\n" + "0" * 64 + "  tables/notes.md\n")
    replay([runs_dir], out)
    assert (out / "figures" / "fig5c-arm.png").read_bytes() == b"the user's own figure"
    assert (out / "tables" / "notes.md").read_bytes() == b"mine"


def test_a_report_folder_without_a_manifest_loses_nothing(runs_dir: Path, tmp_path: Path) -> None:
    from lagrseq.analysis.replay import MANIFEST

    out = tmp_path / "report"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "fig5c-arm-arm.gif").write_bytes(b"old")
    (out / "figures" / "my-sketch.png").write_bytes(b"mine")
    replay([runs_dir], out)
    assert (out / "figures" / "fig5c-arm-arm.gif").exists() and (out / "figures" / "my-sketch.png").exists()
    assert (out / MANIFEST).is_file()


@pytest.mark.parametrize("name", ["index.html", "index.md", MANIFEST_NAME])
def test_replay_never_writes_through_a_link_planted_in_the_report_folder(runs_dir: Path, tmp_path: Path, name: str) -> None:
    out = tmp_path / "report"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (out / name).symlink_to(victim)
    with pytest.raises(UsageError, match="symbolic link"):
        replay([runs_dir], out)
    assert victim.read_text() == "precious"


def _absolute_paths_in(report: Path, places: list[Path]) -> list[str]:
    """Every report file that holds one of ``places`` (absolute folders) or the home folder, in
    any spelling a report could use (as written, resolved, URL-quoted)."""
    import urllib.parse

    needles = set()
    for place in [*places, Path.home()]:
        for spelling in {str(place), str(place.resolve())}:
            needles |= {spelling.encode(), urllib.parse.quote(spelling).encode()}
    found = []
    for path in sorted(report.rglob("*")):
        if path.is_file():
            data = path.read_bytes()
            found += [f"{path.relative_to(report)}: {n.decode()}" for n in needles if n in data]
    return found


def test_no_report_file_holds_an_absolute_path(runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # a report's bytes do not depend on where its logs sat. The logs are given by their
    # absolute path, and some are unfinished, damaged or duplicated, so that the warnings (which
    # name logs, and suggest `lagrseq recover` commands) are in the report too.
    root = tmp_path / "somewhere" / "runs"
    shutil.copytree(runs_dir, root)
    trial = sorted(root.rglob("lagr-seq/*/trial-000.mcap"))[0]
    data = trial.read_bytes()
    (trial.parent / "trial-005.mcap.partial").write_bytes(data[: len(data) // 2])
    (trial.parent / "trial-006.mcap").write_bytes(data[: len(data) // 2])
    (trial.parent / "trial-007.mcap").write_bytes(data)  # trial 0 again
    monkeypatch.chdir(tmp_path)
    report = replay([root.absolute()], tmp_path / "out", formats=["png", "svg", "pdf"])
    assert len(report.logs.warnings) == 3
    assert _absolute_paths_in(tmp_path / "out", [tmp_path, root]) == []
    page = (tmp_path / "out" / "index.md").read_text()
    assert "runs/cube-stacking/" in page and "trial-005.mcap.partial" in page  # named from the folder given
    # the terminal keeps the full path, so the command a warning suggests runs as written
    assert any(str(trial.parent / "trial-006.mcap") in w for w in report.logs.warnings)
    # given relative to the working directory: named as typed, so a suggested command runs from there
    relative = replay([Path("somewhere/runs")], tmp_path / "out2")
    assert relative.logs.warnings and _absolute_paths_in(tmp_path / "out2", [tmp_path, root]) == []
    assert "- somewhere/runs/cube-stacking/" in (tmp_path / "out2" / "index.md").read_text()
