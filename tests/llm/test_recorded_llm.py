"""The real LLM answers committed under recorded_llm/: each file is what its README row says (sha256,
answers, model, temperature), imports into a store, replays as `--provider recorded:FILE.jsonl`,
and every answer goes through the task parsers without raising. No extra needed."""

from __future__ import annotations

import hashlib
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest

from lagrseq import cli
from lagrseq import config as cfg
from lagrseq.errors import RecordMiss, StoreError, UsageError
from lagrseq.llm import store as store_module
from lagrseq.llm.store import JsonlStore, RecordStore, import_jsonl_file
from lagrseq.running import recording, runner, wiring
from tests.llm.conftest import KEY_ENV, FakeOpenAI

ROOT = Path(__file__).resolve().parents[2]
RECORDED = ROOT / "recorded_llm"
ROW = re.compile(r"^\| `(?P<file>[^`]+\.jsonl)` \| (?P<model>[^|]+) \| (?P<task>[^|]+) \| (?P<temperature>[^|]+) \| (?P<samples>[^|]+) \| (?P<answers>\d+) \| `(?P<sha>[0-9a-f]{64})` \|")


def rows() -> list[dict[str, str]]:
    text = (RECORDED / "README.md").read_text(encoding="utf-8")
    return [{k: v.strip() for k, v in m.groupdict().items()} for m in map(ROW.match, text.splitlines()) if m]


def test_every_committed_file_has_a_readme_row_and_imports_with_the_stated_sha256(tmp_path: Path) -> None:
    files = sorted(p.name for p in RECORDED.glob("*.jsonl"))
    listed = rows()
    assert sorted(r["file"] for r in listed) == files
    for row in listed:
        path = RECORDED / row["file"]
        assert hashlib.sha256(path.read_bytes()).hexdigest() == row["sha"], row["file"]
        report = import_jsonl_file(path, tmp_path / row["file"])
        assert report.lines == int(row["answers"]) and report.added == report.lines
        with RecordStore(tmp_path / row["file"], create=False) as store:
            entries = list(store.entries())
        assert {e.request["model"] for e in entries} == {row["model"]}
        assert {float(e.request["temperature"]) for e in entries} == {float(row["temperature"])}
        assert {e.task for e in entries} == {row["task"]}


def test_every_recorded_answer_goes_through_the_parser(tmp_path: Path) -> None:
    for row in rows():
        config = recording.record_config(row["task"], "upstream", None, [])
        census = recording.answer_census(RECORDED / row["file"], config)  # raises nothing
        assert sum(r.total for r in census) == int(row["answers"])


def test_a_jsonl_export_replays_under_the_endpoint_it_was_recorded_at(tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch) -> None:
    args = ["record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "0", "--store", str(tmp_path / "s"),
            "--base-url", server.url, "--api-key-env", KEY_ENV, "--samples", "2", "--quiet"]
    assert cli.main(args) == 0
    assert cli.main(["cache", "export", "--store", str(tmp_path / "s"), "--out", str(tmp_path / "a.jsonl")]) == 0
    spec = f"recorded:{tmp_path / 'a.jsonl'}"
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=5", "llm.model=gpt-4o-mini"])
    # no --base-url: the keys' endpoint (127.0.0.1:PORT) comes from the file
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    result = runner.run_one(config, 0, 0, spec, tmp_path / "t.mcap", log=False)
    assert result.queries > 0
    provider = wiring.make_provider(spec, config, np.random.default_rng(0))
    provider.close()
    assert provider.store.directory == tmp_path / "a.jsonl"  # type: ignore[attr-defined]
    assert not list((tmp_path / "tmp").iterdir())  # read in memory: no temporary store on disk
    with pytest.raises(UsageError, match="no such JSONL file"):
        wiring.parse_provider(f"recorded:{tmp_path / 'missing.jsonl'}")


# ----------------------------------------------------------------------------- replaying a JSONL file
def test_a_jsonl_file_replays_the_entries_its_import_into_a_store_holds(tmp_path: Path) -> None:
    """JsonlStore (what recorded:FILE.jsonl reads, in memory) gives every committed file's entries
    exactly as `lagrseq cache import` files them: keys in order, requests, tasks, samples."""
    for path in sorted(RECORDED.glob("*.jsonl")):
        import_jsonl_file(path, tmp_path / path.name)
        with RecordStore(tmp_path / path.name, create=False) as imported:
            expected = list(imported.entries())
        assert list(JsonlStore(path).entries()) == expected, path.name


def test_a_jsonl_file_merges_repeated_samples_as_an_import_does(tmp_path: Path) -> None:
    """A sample id a key already holds is skipped (the file twice over gives the file once); the
    entries equal the import of the doubled file."""
    source = (RECORDED / "smollm2-135m-cube-t0.jsonl").read_text(encoding="utf-8")
    doubled = tmp_path / "doubled.jsonl"
    doubled.write_text(source + source, encoding="utf-8")
    import_jsonl_file(doubled, tmp_path / "store")
    with RecordStore(tmp_path / "store", create=False) as imported:
        expected = list(imported.entries())
    assert list(JsonlStore(doubled).entries()) == expected == list(JsonlStore(RECORDED / "smollm2-135m-cube-t0.jsonl").entries())


def test_a_changed_jsonl_file_is_read_again_and_an_unchanged_one_is_shared(tmp_path: Path) -> None:
    lines = (RECORDED / "qwen2.5-coder-1.5b-cube-t0.jsonl").read_text(encoding="utf-8").splitlines(keepends=True)
    path = tmp_path / "a.jsonl"
    path.write_text("".join(lines[:10]), encoding="utf-8")
    first, again = JsonlStore(path), JsonlStore(path)
    assert first.entry(first.keys()[0]) is again.entry(first.keys()[0])  # read once, shared
    path.write_text("".join(lines[:30]), encoding="utf-8")  # another size: read again
    grown = JsonlStore(path)
    assert sum(len(e.samples) for e in grown.entries()) == 30 > sum(len(e.samples) for e in first.entries()) == 10


def test_a_jsonl_file_that_is_bad_or_too_large_is_one_store_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_text((RECORDED / "smollm2-135m-cube-t0.jsonl").read_text(encoding="utf-8").splitlines()[0] + "\n{not json\n", encoding="utf-8")
    with pytest.raises(StoreError, match="line 2"):
        JsonlStore(bad)
    with pytest.raises(StoreError, match="is a directory"):
        JsonlStore(tmp_path)
    monkeypatch.setattr(store_module, "JSONL_IN_MEMORY_MAX_BYTES", 1000)
    with pytest.raises(StoreError, match=r"lagrseq cache import FILE STORE.*recorded:STORE"):
        JsonlStore(RECORDED / "smollm2-135m-cube-t0.jsonl")


def test_a_miss_in_a_jsonl_file_names_the_file_and_the_nearest_keys(tmp_path: Path) -> None:
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=2", "llm.model=gpt-4o-mini"])
    spec = f"recorded:{RECORDED / 'smollm2-135m-cube-t0.jsonl'}"
    with pytest.raises(RecordMiss) as caught:
        runner.run_one(config, 0, 0, spec, tmp_path / "t.mcap", provider_options=wiring.provider_options(spec, {"on_miss": "error"}))
    message = str(caught.value)
    assert "smollm2-135m-cube-t0.jsonl" in message and "model 'SmolLM2-135M-Instruct' instead of 'gpt-4o-mini'" in message, message


def test_a_process_keeps_a_bounded_number_of_jsonl_files(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(store_module, "_jsonl_opened", {})
    monkeypatch.setattr(store_module, "JSONL_OPENED_MAX", 2)
    files = sorted(RECORDED.glob("*cube-t*.jsonl"))[:3]
    for path in files:
        JsonlStore(path)
    assert [kept[0] for kept in store_module._jsonl_opened] == [str(path.resolve()) for path in files[1:]]
    monkeypatch.setattr(store_module, "JSONL_OPENED_MAX_BYTES", 1)  # over the bytes: only the latest stays
    JsonlStore(files[0])
    assert [kept[0] for kept in store_module._jsonl_opened] == [str(files[0].resolve())]
