"""Input paths are checked before they are opened (lagrseq/paths.py): a FIFO, a socket or a
device named like a log, a JSONL export, a TOML file or a model is one line and exit status 2,
never a hang; symlink loops and a ``~`` that cannot be expanded are one line too; a directory
walk enters every real directory once. The command-line cases run ``lagrseq`` as a child process
under a timeout, as a user would."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq.errors import LogError, UsageError
from lagrseq.logs.reader import find_logs
from lagrseq.paths import expand_user, input_path, open_input, walk_files

ROOT = Path(__file__).resolve().parents[1]
FAKE = ROOT / "tests" / "llm" / "fake_llama"
NO_USER = "~no-such-user-of-lagrseq"


def lagrseq(*args: str, env: dict[str, str] | None = None, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT,
        env={**os.environ, **(env or {})},
    )


def one_line(done: subprocess.CompletedProcess[str], *expected: str) -> None:
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    for text in expected:
        assert text in done.stderr, done.stderr


@pytest.fixture
def specials(tmp_path: Path) -> Path:
    """A folder of things that are not regular files, named like inputs."""
    os.mkfifo(tmp_path / "trial-000.mcap")
    os.mkfifo(tmp_path / "answers.jsonl")
    os.mkfifo(tmp_path / "config.toml")
    os.mkfifo(tmp_path / "model.gguf")
    (tmp_path / "loop.mcap").symlink_to("loop.mcap")
    return tmp_path


def test_replay_of_a_folder_holding_a_fifo_log_is_one_line(specials: Path) -> None:
    (specials / "loop.mcap").unlink()
    one_line(lagrseq("replay", str(specials), "--out", str(specials / "out")), "trial-000.mcap is a FIFO (named pipe); expected a regular file")
    one_line(lagrseq("replay", str(specials / "trial-000.mcap"), "--out", str(specials / "out")), "is a FIFO")
    one_line(lagrseq("recover", str(specials / "trial-000.mcap")), "is a FIFO")


def test_replay_of_a_symlink_loop_is_one_line(specials: Path) -> None:
    (specials / "trial-000.mcap").unlink()
    one_line(lagrseq("replay", str(specials), "--out", str(specials / "out")), "loop.mcap: a symlink loop")


def test_cache_parse_and_config_of_special_files(specials: Path) -> None:
    one_line(lagrseq("cache", "parse", "--task", "cube-stacking", str(specials / "answers.jsonl")), "answers.jsonl is a FIFO")
    one_line(lagrseq("cache", "parse", "--task", "cube-stacking", str(specials / "trial-000.mcap")), "is a FIFO (named pipe); expected a directory")
    one_line(lagrseq("config", "cube-stacking", "--config", str(specials / "config.toml")), "config.toml is a FIFO")
    one_line(lagrseq("config", "cube-stacking", "--config", f"{NO_USER}/x.toml"), "'~' cannot be expanded")


def test_models_fifos_and_unexpandable_home(specials: Path) -> None:
    env = {"PYTHONPATH": os.pathsep.join([str(FAKE), str(ROOT)])}  # the stand-in llama.cpp server
    one_line(lagrseq("serve-llm", str(specials / "model.gguf"), env=env), "model.gguf is a FIFO")
    one_line(lagrseq("serve-llm", f"{NO_USER}/model.gguf", env=env), "'~' cannot be expanded", "give the full path")
    out = str(specials / "runs")
    one_line(lagrseq("run", "cube-stacking", "--provider", f"local:{NO_USER}/m.gguf", "--out", out, env=env), "'~' cannot be expanded")
    one_line(lagrseq("run", "cube-stacking", "--provider", f"recorded:{specials / 'answers.jsonl'}", "--out", out), "is a FIFO")


def test_open_input_never_blocks_and_checks_what_it_opened(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "pipe")
    with pytest.raises(LogError, match="pipe is a FIFO"):
        open_input(tmp_path / "pipe", "log", LogError)
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(tmp_path / "sock"))
        with pytest.raises(UsageError, match="is a socket"):
            input_path(tmp_path / "sock")
    with pytest.raises(UsageError, match="is a character device"):
        input_path("/dev/zero")
    with pytest.raises(UsageError, match="is a directory; expected a regular file"):
        input_path(tmp_path)
    with pytest.raises(UsageError, match="no such file"):
        input_path(tmp_path / "missing")
    with pytest.raises(UsageError, match="NUL byte"):
        input_path("a\0b")
    assert input_path(tmp_path, expect="directory") == tmp_path
    (tmp_path / "file").write_bytes(b"data")
    with open_input(tmp_path / "file") as handle:
        assert handle.read() == b"data"
    with pytest.raises(UsageError, match="'~' cannot be expanded"):
        expand_user(f"{NO_USER}/file")


def test_a_walk_enters_every_directory_once(tmp_path: Path) -> None:
    (tmp_path / "a" / "b").mkdir(parents=True)
    (tmp_path / "a" / "b" / "up").symlink_to(tmp_path)  # a loop of directories
    (tmp_path / "a" / "b" / "same").symlink_to(tmp_path / "a")
    (tmp_path / "a" / "b" / "run.mcap").write_bytes(b"")
    (tmp_path / "top.mcap").write_bytes(b"")
    found = walk_files(tmp_path, lambda name: name.endswith(".mcap"))
    assert sorted(p.name for p in found) == ["run.mcap", "top.mcap"]
    assert [p.name for p in find_logs([tmp_path])] == ["run.mcap", "top.mcap"]
