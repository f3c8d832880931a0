"""The one writer (lagrseq/outputs.py): every file a command writes is put in place whole or
refused in one line, never through a link, onto a FIFO, a folder or an input, outside the
command's output folder, or twice for two outputs; and what it writes holds no guarded key."""

from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import pytest

from lagrseq import cli, outputs
from lagrseq.errors import ConfigError, UsageError

KEY = "sk-canaryQ7x9Lm2Pz4Rt8Vw3Yb6Nc1Df5Gh0Jk"


def test_a_file_is_written_whole_and_replaced_atomically(tmp_path: Path) -> None:
    target = tmp_path / "deep" / "table.csv"
    outputs.write_text(target, "a,b\n1,2\n")
    assert target.read_text() == "a,b\n1,2\n" and stat.S_IMODE(target.stat().st_mode) == 0o644
    inode = target.stat().st_ino
    outputs.write_bytes(target, b"x\n")
    assert target.read_bytes() == b"x\n" and target.stat().st_ino != inode  # a new file, moved into place
    assert sorted(p.name for p in target.parent.iterdir()) == ["table.csv"]  # no scratch file left


@pytest.mark.parametrize("kind", ["symlink", "dangling symlink", "fifo", "directory"])
def test_a_target_that_is_no_regular_file_is_refused_without_blocking(tmp_path: Path, kind: str) -> None:
    target = tmp_path / "index.html"
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    if kind == "symlink":
        target.symlink_to(victim)
    elif kind == "dangling symlink":
        target.symlink_to(tmp_path / "nothing")
    elif kind == "fifo":
        os.mkfifo(target)
    else:
        target.mkdir()
    done: list[BaseException] = []

    def write() -> None:
        try:
            outputs.write_text(target, "<html>")
        except UsageError as exc:
            done.append(exc)

    worker = threading.Thread(target=write, daemon=True)
    worker.start()
    worker.join(10)
    assert not worker.is_alive() and len(done) == 1
    assert str(target) in str(done[0]) and "\n" not in str(done[0])
    assert victim.read_text() == "precious" and not (tmp_path / "nothing").exists()


def test_a_device_at_the_target_is_refused(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="character device"):
        outputs.write_text("/dev/null", "x")


@pytest.mark.parametrize("name", ["../escaped.png", "figures/../../escaped.png", "/tmp/lagrseq-absolute-escape.png"])
def test_a_path_outside_the_output_folder_is_refused(tmp_path: Path, name: str) -> None:
    out = tmp_path / "report"
    out.mkdir()
    with outputs.outputs(out), pytest.raises(UsageError, match="outside the output folder"):
        outputs.write_bytes(out / name, b"png")  # an absolute name replaces out
    assert not (tmp_path / "escaped.png").exists() and not Path("/tmp/lagrseq-absolute-escape.png").exists()


def test_an_input_and_anything_inside_an_input_folder_is_refused(tmp_path: Path) -> None:
    table = tmp_path / "a" / "tables" / "scoreboard.csv"
    table.parent.mkdir(parents=True)
    table.write_text("kept")
    alias = tmp_path / "alias.csv"
    os.link(table, alias)  # the same file under another name
    with outputs.outputs(inputs=[tmp_path / "a"]):
        for path in (table, table.parent / "new.csv"):
            with pytest.raises(UsageError, match="input"):
                outputs.write_text(path, "x")
    with outputs.outputs(inputs=[table]), pytest.raises(UsageError, match="is an input"):
        outputs.write_text(alias, "x")
    assert table.read_text() == "kept"


def test_two_outputs_on_one_path_are_refused(tmp_path: Path) -> None:
    with outputs.outputs():
        outputs.check(tmp_path / "x", "--csv")
        with pytest.raises(UsageError, match="--csv"):
            outputs.check(tmp_path / "sub" / ".." / "x", "--markdown")


def test_no_written_text_holds_a_guarded_key(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    body = KEY[3:]
    spaced = "\u200b".join(body[i : i + 3] for i in range(0, len(body), 3))
    text = f"{KEY} | {body.upper()} | {body[-12:]} | {spaced}\n"
    outputs.write_text(tmp_path / "a.md", text)
    outputs.write_bytes(tmp_path / "b.csv", text.encode())
    for name in ("a.md", "b.csv"):
        written = (tmp_path / name).read_text().replace("\u200b", "").lower()
        assert body[:12].lower() not in written and body[-12:].lower() not in written
        assert written.count("[redacted]") == 4


@pytest.mark.parametrize("item_id", ["../../../x", "/abs/x", ".hidden", "a\\b", "a\nb"])
def test_a_suite_item_id_that_is_no_file_name_is_refused(tmp_path: Path, item_id: str) -> None:
    from lagrseq.suite import load_suite

    escaped = item_id.replace("\\", "\\\\").replace("\n", "\\n")
    (tmp_path / "suite.toml").write_text(
        f'[suite]\nprovider = "mock"\n\n[[items]]\nid = "{escaped}"\nrender = "returns"\ntask = "cube-stacking"\n\n'
        '[[items.runs]]\nlabel = "x"\nmethod = "baseline"\n'
    )
    with pytest.raises(ConfigError, match="suite item id") as caught:
        load_suite(tmp_path / "suite.toml")
    assert "\n" not in str(caught.value)


def test_frontier_never_writes_its_table_through_a_link(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fr"
    args = ["frontier", "cube-stacking", "--provider", "mock", "--policies", "never,always", "--trials", "1",
            "--set", "run.episodes=2", "--out", str(out), "--quiet", "--no-matched-random"]
    assert cli.main(args) == 0
    (table,) = (out / "frontier").glob("*.md")
    again = tmp_path / "again"
    again.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (again / table.name).symlink_to(victim)
    capsys.readouterr()
    assert cli.main(["frontier", "--replay", str(out), "--out", str(again)]) == 2
    err = capsys.readouterr().err
    assert "symbolic link" in err and len(err.strip().splitlines()) == 1
    assert victim.read_text() == "precious"


def test_an_episode_gif_is_written_whole_and_never_through_a_link(tmp_path: Path) -> None:
    import numpy as np

    from lagrseq.robot.render import write_gif

    frames = [np.full((8, 8, 3), shade, dtype=np.uint8) for shade in (0, 128, 255)]
    gif = write_gif(frames, tmp_path / "episode-0000.gif")
    assert gif.read_bytes()[:6] == b"GIF89a" and sorted(p.name for p in tmp_path.iterdir()) == ["episode-0000.gif"]
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "episode-0001.gif").symlink_to(victim)
    with pytest.raises(UsageError, match="--render"):
        write_gif(frames, tmp_path / "episode-0001.gif")
    assert victim.read_text() == "precious"
