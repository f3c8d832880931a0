"""The real LLM answers committed under recorded_llm/: each file is what its README row says (sha256,
answers, model, temperature), imports into a store, replays as `--provider recorded:FILE.jsonl`,
and every answer goes through the task parsers without raising. No extra needed."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np
import pytest

from lagrseq import cli
from lagrseq import config as cfg
from lagrseq.errors import UsageError
from lagrseq.llm.store import RecordStore, import_jsonl_file
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


def test_a_jsonl_export_replays_under_the_endpoint_it_was_recorded_at(tmp_path: Path, server: FakeOpenAI) -> None:
    args = ["record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "0", "--store", str(tmp_path / "s"),
            "--base-url", server.url, "--api-key-env", KEY_ENV, "--samples", "2", "--quiet"]
    assert cli.main(args) == 0
    assert cli.main(["cache", "export", "--store", str(tmp_path / "s"), "--out", str(tmp_path / "a.jsonl")]) == 0
    spec = f"recorded:{tmp_path / 'a.jsonl'}"
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=5", "llm.model=gpt-4o-mini"])
    # no --base-url: the keys' endpoint (127.0.0.1:PORT) comes from the file
    result = runner.run_one(config, 0, 0, spec, tmp_path / "t.mcap", log=False)
    assert result.queries > 0
    provider = wiring.make_provider(spec, config, np.random.default_rng(0))
    directory = provider.directory  # type: ignore[attr-defined]
    provider.close()
    assert not directory.exists()  # the temporary store is removed
    with pytest.raises(UsageError, match="no such JSONL file"):
        wiring.parse_provider(f"recorded:{tmp_path / 'missing.jsonl'}")
