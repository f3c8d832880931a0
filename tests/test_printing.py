"""Outside text (file names, model paths, GGUF metadata, host names) is printed on one line with
control and format characters escaped, and a terminal encoding that cannot write a character
escapes it instead of raising UnicodeEncodeError.
Real files with hostile names, the real program in fresh processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq.text import printable
from tests.support.gguf import build, model_pairs

ROOT = Path(__file__).resolve().parents[1]
NOT_UTF8 = os.fsdecode(b"caf\xe9-\xff.gguf")
"""A file name that is not UTF-8 (Latin-1 bytes), as Python sees it: lone surrogates."""
NEWLINE = "evil\nforged: line.gguf"
ANSI = "\x1b[2J\x1b[31mred.gguf"
BIDI = "model-\u202eexe.gguf"


def lagrseq(*argv: str, **env: str) -> subprocess.CompletedProcess[bytes]:
    """The real program; its output as bytes (what the terminal would get)."""
    environ = {**os.environ, **env}
    return subprocess.run([sys.executable, "-m", "lagrseq", *argv], capture_output=True, env=environ, cwd=ROOT, timeout=120, check=False)


def test_printable_keeps_text_and_escapes_what_acts_on_a_terminal() -> None:
    for ordinary in ("runs/cube/trial-000.mcap", "naïve ☃ 模型 🤖.gguf", "C:\\models\\m.gguf", "with space.gguf", ""):
        assert printable(ordinary) == ordinary
    assert printable(NEWLINE) == "evil\\nforged: line.gguf"
    assert printable(ANSI) == "\\x1b[2J\\x1b[31mred.gguf"
    assert printable(BIDI) == "model-\\u202eexe.gguf"
    assert printable(NOT_UTF8) == "caf\\xe9-\\xff.gguf"
    assert printable("a\\b\n") == "a\\\\b\\n"  # a backslash doubled where the text is changed: the escapes read back
    assert printable("\u2028\u2029\x00\x7f\ue000") == "\\u2028\\u2029\\x00\\x7f\\ue000"


@pytest.fixture
def hostile_models(tmp_path: Path) -> Path:
    folder = tmp_path / "models"
    folder.mkdir()
    for name in (NOT_UTF8, NEWLINE, ANSI, BIDI):
        (folder / name).write_bytes(build(model_pairs()))  # os.fsencode gives back the name's bytes
    return folder


@pytest.mark.parametrize("encoding", ["ascii", "utf-8", "latin-1"])
def test_models_prints_hostile_file_names_escaped_in_any_terminal_encoding(hostile_models: Path, encoding: str) -> None:
    done = lagrseq("models", "--no-hash", str(hostile_models), PYTHONIOENCODING=encoding)
    assert done.returncode == 0, done.stderr
    assert b"Traceback" not in done.stderr and b"UnicodeEncodeError" not in done.stderr
    out = done.stdout
    assert b"\x1b" not in out and b"\xe2\x80\xae" not in out and b"\xff" not in out  # no raw escape, bidi override or bad byte
    lines = out.decode("ascii" if encoding == "ascii" else encoding).splitlines()
    headings = [line for line in lines if line.startswith(str(hostile_models))]
    assert len(headings) == 4, lines  # one line per model: no forged extra line
    assert not any(line.startswith("forged") for line in lines)
    assert any("evil\\nforged: line.gguf" in line for line in headings)
    assert any("caf\\xe9-\\xff.gguf" in line for line in headings)


def test_models_json_stays_valid_json_for_a_name_that_is_not_utf8(hostile_models: Path) -> None:
    done = lagrseq("models", "--no-hash", "--json", str(hostile_models), PYTHONIOENCODING="ascii")
    assert done.returncode == 0, done.stderr
    rows = [json.loads(line) for line in done.stdout.decode("ascii").splitlines()]
    assert sorted(Path(row["path"]).name for row in rows) == sorted((NOT_UTF8, NEWLINE, ANSI, BIDI))


def test_an_error_about_a_hostile_path_is_one_escaped_line(tmp_path: Path) -> None:
    bad = tmp_path / f"{ANSI}\n{NOT_UTF8}.txt"
    bad.write_bytes(b"not a model")
    done = lagrseq("models", str(bad), PYTHONIOENCODING="ascii")
    assert done.returncode == 2 and done.stderr.count(b"\n") == 1, done.stderr
    assert b"\x1b" not in done.stderr and b"Traceback" not in done.stderr
    assert b"\\x1b[2J" in done.stderr and b"\\xe9" in done.stderr


def test_robot_serve_with_a_newline_in_host_is_one_line() -> None:
    pytest.importorskip("grpc")
    done = lagrseq("robot", "serve", "--sim", "--host", "127.0.0.1\nX", "--port", "0")
    errors = [line for line in done.stderr.decode().splitlines() if not line.startswith("pybullet build time")]
    assert done.returncode == 2 and len(errors) == 1, done.stderr
    assert "127.0.0.1\\nX" in errors[0]
