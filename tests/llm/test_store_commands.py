"""The store commands and recorded runs refuse bad input in one line: a bad JSONL line by its
number, a write to a read-only store (which still serves every reader), a folder or a missing
file to import, and ``record`` with a missing key, a bad URL, model or store before its progress
bar."""

from __future__ import annotations

import importlib.util
import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.cli import cli, refused
from tests.support.records import BAD_FIELD_VALUES, line, made_read_only, record, with_field

ROOT = Path(__file__).resolve().parents[2]
SMALL = ["--set", "run.episodes=2", "--quiet"]
RECORDED = ROOT / "recorded_llm" / "smollm2-135m-cube-t0.jsonl"


# ----------------------------------------------------------------------------- JSONL readers
@pytest.mark.parametrize(("path", "value", "message"), BAD_FIELD_VALUES[:14], ids=[p for p, _, _ in BAD_FIELD_VALUES[:14]])
def test_cache_parse_and_recorded_jsonl_runs_refuse_a_bad_line_by_number(tmp_path: Path, path: str, value: Any, message: str) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_bytes((line(record(0)) + "\n" + line(with_field(record(1), path, value)) + "\n").encode("utf-8", "surrogatepass"))
    for argv in (
        ["cache", "parse", str(bad), "--task", "cube-stacking"],
        ["run", "cube-stacking", "--provider", f"recorded:{bad}", "--on-miss", "mock", "--trials", "1", "--out", str(tmp_path / "o"), *SMALL],
        ["frontier", "cube-stacking", "--provider", f"recorded:{bad}", "--on-miss", "mock", "--policies", "always", "--trials", "1", "--jobs", "1", "--out", str(tmp_path / "o"), *SMALL],
    ):
        error = refused(*argv)
        assert f"line 2: {message}" in error, error
    assert not list(tmp_path.rglob("*.mcap*"))


# ----------------------------------------------------------------------------- read-only store
@pytest.fixture
def read_only_store(tmp_path: Path) -> Iterator[Path]:
    """A store whose directory and files nobody may write (root: chattr +i, as root ignores modes)."""
    store = tmp_path / "store"
    assert cli("cache", "import", str(RECORDED), "--store", str(store))[0] == 0
    with made_read_only(store):
        yield store


def test_a_read_only_store_serves_parse_frontier_and_runs_and_refuses_writes_in_one_line(
    read_only_store: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = {p.name: p.read_bytes() for p in read_only_store.iterdir()}
    status, out, err = cli("cache", "parse", str(read_only_store), "--task", "cube-stacking")
    assert status == 0 and "accuracy" in out.lower(), err
    recorded = ["--provider", f"recorded:{read_only_store}", "--base-url", "local", "--on-miss", "mock", "--trials", "1", *SMALL]
    status, _, err = cli("frontier", "cube-stacking", "--policies", "always,seq", "--jobs", "1", "--out", str(tmp_path / "fr"), *recorded)
    assert status == 0, err
    assert cli("run", "cube-stacking", "--out", str(tmp_path / "runs"), *recorded)[0] == 0
    status, _, _ = cli("cache", "list", "--store", str(read_only_store))
    assert status == 0
    assert "read-only" in refused("cache", "import", str(RECORDED), "--store", str(read_only_store))
    live_misses = [{"mock": "live", "local": "http://127.0.0.1:9/v1"}.get(a, a) for a in recorded]  # nothing is sent: it fails first
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-not-a-key")
    assert "read-only" in refused("run", "cube-stacking", "--out", str(tmp_path / "live"), *live_misses)
    # an export into the store it exports is refused before anything is written
    assert "inside the store" in refused("cache", "export", "--store", str(read_only_store), "--out", str(read_only_store / "x.jsonl"))
    assert {p.name: p.read_bytes() for p in read_only_store.iterdir()} == before


# ----------------------------------------------------------------------------- record, and the store commands on folders and missing files
def test_record_checks_key_url_model_and_store_before_its_progress_bar(tmp_path: Path, read_only_store: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("keep me")
    head = ["record", "cube-stacking", "--mode", "new"]  # no --quiet: a bar drawn first would be a second line
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    assert "OPENAI_API_KEY is not set" in refused(*head, "--store", str(tmp_path / "s"))
    # a missing model file, or (core environments) the missing extra: either way one line, before the bar
    local = refused(*head, "--store", str(tmp_path / "s"), "--provider", f"local:{tmp_path / 'none.gguf'}")
    extra = importlib.util.find_spec("llama_cpp") is not None
    assert ("local model" if extra else "the local-llm extra is not installed") in local
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-not-a-key")
    assert "http:// or https://" in refused(*head, "--store", str(tmp_path / "s"), "--base-url", "ftp://127.0.0.1")
    assert "is not a URL" in refused(*head, "--store", str(tmp_path / "s"), "--base-url", "http://[::1")
    assert str(a_file / "x") in refused(*head, "--store", str(a_file / "x"))
    assert "/proc/lagrseq-x" in refused(*head, "--store", "/proc/lagrseq-x")
    assert "read-only" in refused(*head, "--store", str(read_only_store))
    assert a_file.read_text() == "keep me"


def test_cache_import_refuses_a_directory_and_a_missing_file_in_one_line(tmp_path: Path) -> None:
    for source in (tmp_path, tmp_path / "missing.jsonl"):
        assert str(source) in refused("cache", "import", str(source), "--store", str(tmp_path / "s"))
    assert not (tmp_path / "s").exists()


def test_jsonl_export_of_a_read_store_keeps_json_lines(tmp_path: Path) -> None:
    """Sanity: the recorded file used above imports and exports as it should (no refusal above
    passes because nothing works)."""
    store = tmp_path / "s"
    assert cli("cache", "import", str(RECORDED), "--store", str(store))[0] == 0
    assert cli("cache", "export", "--store", str(store), "--out", str(tmp_path / "x.jsonl"))[0] == 0
    rows = [json.loads(x) for x in (tmp_path / "x.jsonl").read_text().splitlines()]
    assert len(rows) == len(RECORDED.read_text().splitlines())
    shutil.rmtree(store)
