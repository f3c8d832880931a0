"""Outputs never go through a link nor over a user's file. A symlink planted as
a log's ``.partial`` or final name, as ``cache export --out`` or ``screen --answers``, is refused
in one line with the file it points at untouched; ``cache export --out`` inside the store it
exports is refused; an existing ``--answers`` file is refused before anything is asked, never
truncated. Real runs, real stores, real HTTP on 127.0.0.1."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq import cli
from lagrseq.errors import LogError
from lagrseq.logs.events import QueryEvent
from lagrseq.logs.sink import McapSink
from tests.llm.conftest import KEY_ENV, FakeOpenAI

ROOT = Path(__file__).resolve().parents[2]
RECORDED = ROOT / "recorded_llm" / "qwen2.5-coder-1.5b-cube-t0.jsonl"
VICTIM = "someone's file: never written by lagrseq\n"
RUN = ["run", "cube-stacking", "--trials", "1", "--set", "run.episodes=2", "--quiet"]


def lagrseq(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "lagrseq", *argv], capture_output=True, text=True, cwd=ROOT, timeout=300, check=False)


def one_line(done: subprocess.CompletedProcess[str], *words: str) -> str:
    """The single error line of a refused command, checked for ``words``."""
    lines = [line for line in done.stderr.splitlines() if "error" in line]
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert all(word in lines[0] for word in words), lines[0]
    return lines[0]


@pytest.fixture
def trial_log(tmp_path: Path) -> Path:
    """Where ``lagrseq run RUN --out tmp/runs`` writes its one log (found by a first run elsewhere)."""
    first = lagrseq(*RUN, "--out", str(tmp_path / "probe"))
    assert first.returncode == 0, first.stderr
    [log] = list((tmp_path / "probe").rglob("trial-*.mcap"))
    return tmp_path / "runs" / log.relative_to(tmp_path / "probe")


@pytest.mark.parametrize("planted", [".partial", ""])
def test_a_run_never_writes_its_log_through_a_planted_symlink(tmp_path: Path, trial_log: Path, planted: str) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM)
    link = trial_log.with_name(trial_log.name + planted)
    link.parent.mkdir(parents=True)
    link.symlink_to(os.path.relpath(victim, link.parent))
    done = lagrseq(*RUN, "--out", str(tmp_path / "runs"))
    one_line(done, "symbolic link", link.name)
    assert victim.read_text() == VICTIM
    assert link.is_symlink()  # left as it was found; nothing renamed onto or over it
    assert not trial_log.exists() or trial_log == link


def test_the_sink_refuses_a_link_a_hard_link_and_a_link_planted_while_it_writes(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM)
    path = tmp_path / "trial-000.mcap"
    partial = tmp_path / "trial-000.mcap.partial"
    os.link(victim, partial)  # a hard link to someone's file: truncating it would empty theirs
    with pytest.raises(LogError, match="other hard links"):
        McapSink(path, {})
    partial.unlink()
    with McapSink(path, {}) as sink:  # a link planted at the final name while the trial runs
        sink.write(QueryEvent(0, 0, 0, 0, [1], 0))
        path.symlink_to(victim)
        with pytest.raises(LogError, match="symbolic link"):
            sink.finish()
    assert victim.read_text() == VICTIM and path.is_symlink() and partial.is_file()
    path.unlink()
    partial.unlink()
    with McapSink(path, {}) as sink:  # and nothing in the way: the log is written as before
        sink.write(QueryEvent(0, 0, 0, 0, [1], 0))
    assert path.is_file() and not path.is_symlink() and not partial.exists()


# ----------------------------------------------------------------------------- cache export --out
@pytest.fixture
def store(tmp_path: Path) -> Path:
    store = tmp_path / "store"
    assert cli.main(["cache", "import", str(RECORDED), "--store", str(store)]) == 0
    return store


@pytest.mark.parametrize("inside", ["cache.db", "export.jsonl", "sub/export.jsonl", "."])
def test_an_export_into_the_store_it_exports_is_refused(store: Path, inside: str) -> None:
    before = {p.name: p.read_bytes() for p in store.iterdir() if p.is_file()}
    done = lagrseq("cache", "export", "--store", str(store), "--out", str(store / inside))
    one_line(done, "inside the store")
    assert {p.name: p.read_bytes() for p in store.iterdir() if p.is_file()} == before
    assert lagrseq("cache", "list", "--store", str(store)).returncode == 0


def test_an_export_into_the_store_through_a_linked_folder_is_refused(store: Path, tmp_path: Path) -> None:
    (tmp_path / "alias").symlink_to(store)
    done = lagrseq("cache", "export", "--store", str(store), "--out", str(tmp_path / "alias" / "cache.db"))
    one_line(done, "inside the store")
    assert lagrseq("cache", "list", "--store", str(store)).returncode == 0


def test_an_export_never_writes_through_a_symlink_and_replaces_a_regular_file(store: Path, tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM)
    out = tmp_path / "export.jsonl"
    out.symlink_to(victim)
    one_line(lagrseq("cache", "export", "--store", str(store), "--out", str(out)), "symbolic link")
    assert victim.read_text() == VICTIM and out.is_symlink()
    out.unlink()
    out.write_text("an older export\n")
    assert lagrseq("cache", "export", "--store", str(store), "--out", str(out)).returncode == 0
    assert out.read_text().count("\n") > 1 and '"key"' in out.read_text()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]


def test_a_store_is_never_written_through_a_planted_database_link(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM)
    store = tmp_path / "store"
    store.mkdir()
    (store / "cache.db").symlink_to(victim)
    done = lagrseq("cache", "import", str(RECORDED), "--store", str(store))
    one_line(done, "symbolic link", "cache.db")
    assert victim.read_text() == VICTIM


# ----------------------------------------------------------------------------- screen --answers
SCREEN = ["screen", "cube-stacking", "--provider", "live:gpt-4o-mini", "--prompts", "4", "--api-key-env", KEY_ENV, "--quiet"]


def test_screen_refuses_an_existing_answers_file_before_asking(server: FakeOpenAI, tmp_path: Path) -> None:
    answers = tmp_path / "answers.jsonl"
    answers.write_text("".join(f'{{"line": {i}}}\n' for i in range(16)))
    before = answers.read_bytes()
    status = cli.main([*SCREEN, "--base-url", server.url, "--answers", str(answers), "--out", str(tmp_path / "out")])
    assert status == 2
    assert answers.read_bytes() == before  # 16 lines stay 16
    assert server.requests == []  # refused before anything was asked (or paid for)


def test_screen_refuses_answers_through_a_symlink_and_writes_a_new_file(
    server: FakeOpenAI, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM)
    link = tmp_path / "answers.jsonl"
    link.symlink_to(victim)
    assert cli.main([*SCREEN, "--base-url", server.url, "--answers", str(link), "--out", str(tmp_path / "out")]) == 2
    assert "symbolic link" in capfd.readouterr().err
    assert victim.read_text() == VICTIM and server.requests == []
    fresh = tmp_path / "new" / "answers.jsonl"
    assert cli.main([*SCREEN, "--base-url", server.url, "--answers", str(fresh), "--out", str(tmp_path / "out")]) == 0
    assert fresh.is_file() and fresh.read_text().count("\n") >= 4 and server.requests
    assert not [p for p in fresh.parent.iterdir() if p.name.endswith(".partial")]
