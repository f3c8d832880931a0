"""Recorded-answer JSONL records as ``cache export`` writes them, the same with one field changed
or deleted, the bad field values every reader must refuse, and a store nobody can write."""

from __future__ import annotations

import contextlib
import copy
import json
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from lagrseq.llm.base import Message, Query, Usage
from lagrseq.llm.records import MAX_ANSWER_CHARS
from lagrseq.llm.store import Sample, query_key

ENDPOINT = "api.openai.com"


def query(prompt: str = "complete ['e','f']") -> Query:
    return Query("cube-stacking", "gpt-3.5-turbo", (Message("user", prompt),), 0.0, 256)


def record(index: int = 0, prompt: str = "complete ['e','f']") -> dict[str, Any]:
    """A valid JSONL record, as `cache export` writes it."""
    key, request = query_key(query(prompt), ENDPOINT)
    sample = Sample(
        id=f"s{index}", text=f"['e','f','a{index}']", origin="live", model="gpt-3.5-turbo-0125",
        usage=Usage(120, 9, 0), finish_reason="stop", latency_s=0.4, cost_usd=0.0001,
        recorded_at="2025-01-31T12:00:00Z", provenance="chatcmpl-1",
    )
    return {"format": "lagrseq.recorded/1", "key": key, "index": index, "task": "cube-stacking", "request": request, "sample": sample.to_json()}


def line(data: dict[str, Any]) -> str:
    return json.dumps(data, sort_keys=True)


def with_field(data: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    out = copy.deepcopy(data)
    *parents, last = path.split(".")
    node: Any = out
    for part in parents:
        node = node[int(part)] if part.isdigit() else node[part]
    if value is DELETE:
        del node[int(last) if last.isdigit() else last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return out


DELETE = object()
BAD_FIELD_VALUES = [
    ("request.messages", [42], "request.messages[0] is 42, expected an object with role and content"),
    ("request", {"key_version": 1, "messages": []}, "request lacks fields 'endpoint', 'model'"),
    ("sample.text", "broken \ud800 answer", "sample.text holds a lone surrogate '\\ud800'"),
    ("request.messages", [], "request.messages is an empty list, expected a list of 1 to 1000 chat messages"),
    ("request.temperature", "0.0", "request.temperature is '0.0', expected a number from 0 to 2"),
    ("request.model", None, "request.model is null, expected a model name"),
    ("sample.usage.prompt_tokens", -5, "sample.usage.prompt_tokens is -5, expected an integer from 0 to 10000000"),
    ("sample.usage.completion_tokens", 10**12, "sample.usage.completion_tokens is 1000000000000, expected an integer from 0"),
    ("sample.cost_usd", "0.01", "sample.cost_usd is '0.01', expected US dollars"),
    ("sample.latency_s", float("nan"), "sample.latency_s is nan, expected a finite number"),
    ("sample.id", "", "sample.id is an empty string, expected an id"),
    ("request.temperature", float("inf"), "request.temperature is inf, expected a number from 0 to 2"),
    ("request.messages.0.content", 7, "request.messages[0].content is 7, expected a string"),
    ("sample.text", "x" * (MAX_ANSWER_CHARS + 1), f"sample.text is a string of {MAX_ANSWER_CHARS + 1} characters, expected an answer of at most {MAX_ANSWER_CHARS}"),
    ("request.key_version", DELETE, "request lacks field 'key_version'"),
    ("sample.recorded_as", "pickle", "sample.recorded_as is 'pickle', expected text, array or list"),
    ("sample.surprise", 1, "sample has unknown field 'surprise'"),
    ("request.seed", 2**70, "request.seed is 1180591620717411303424, expected a 64-bit integer"),
]


@contextlib.contextmanager
def made_read_only(store: Path) -> Iterator[Path]:
    """``store`` (a directory) and everything in it unwritable, not even by root: ``chattr +i``
    where the file system allows it, plain permissions for other users; the test is skipped where
    neither holds. Writable again afterwards."""
    targets = [store, *store.rglob("*")]
    if os.geteuid() == 0:
        try:
            subprocess.run(["chattr", "+i", *map(str, targets)], check=True, capture_output=True)
        except (OSError, subprocess.CalledProcessError):
            pytest.skip("root ignores permissions and chattr +i is not available here")
        undo = ["chattr", "-i", *map(str, targets)]
    else:
        for path in reversed(targets):
            path.chmod(0o555 if path.is_dir() else 0o444)
        undo = []
    try:
        with pytest.raises(OSError):
            (store / "probe").write_text("x")
        yield store
    finally:
        if undo:
            subprocess.run(undo, check=False, capture_output=True)
        for path in targets:
            if path.exists():
                path.chmod(0o755 if path.is_dir() else 0o644)
