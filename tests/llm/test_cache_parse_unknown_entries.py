"""``lagrseq cache parse`` on hostile stores: an entry whose prompt is not a cube prompt (a JSONL
import, another tool's store) gets its key in the table instead of a traceback, and answers at the
size cap made of the parsers' worst inputs are classified in bounded time."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from lagrseq import cli
from lagrseq.llm.base import user_query
from lagrseq.llm.records import MAX_ANSWER_CHARS
from lagrseq.llm.store import RecordStore, Sample, query_key
from lagrseq.tasks import cube

HOSTILE = ["[" * MAX_ANSWER_CHARS, "1" * (MAX_ANSWER_CHARS - 1) + "x", "[]" * (MAX_ANSWER_CHARS // 2),
           ("['e'," * MAX_ANSWER_CHARS)[:MAX_ANSWER_CHARS], "١" * MAX_ANSWER_CHARS, "['e','f','g']"]


def test_cache_parse_reads_odd_prompts_and_hostile_answers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = tmp_path / "store"
    odd = user_query("cube-stacking", "not a cube prompt (from bottom to top): [" + "x" * 50, "gpt-4", 0.0, 64)
    good = user_query("cube-stacking", cube.CubeStacking(8).prompt((4,)), "gpt-4", 0.0, 64)
    with RecordStore(store) as opened:
        for query in (odd, good):
            key, request = query_key(query, "api.openai.com")
            opened.add(key, request, "cube-stacking", [Sample(id=f"s{i}", text=t, origin="live") for i, t in enumerate(HOSTILE)])
    started = time.process_time()
    assert cli.main(["cache", "parse", "--task", "cube-stacking", str(store)]) == 0
    assert time.process_time() - started < 5.0
    captured = capsys.readouterr()
    odd_key = query_key(odd, "api.openai.com")[0]
    lines = captured.out.splitlines()
    assert any(line.startswith(f"| 0 | {odd_key[:12]} | {len(HOSTILE)} |") for line in lines), captured.out
    assert any(line.startswith(f"| 0 | 1 | {len(HOSTILE)} |") for line in lines), captured.out
    assert "Traceback" not in captured.err
