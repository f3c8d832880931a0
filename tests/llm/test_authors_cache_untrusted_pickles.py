"""The authors'-cache importer reads untrusted pickles (every parser): an answer
too large to store is refused before it is written out (old: a 20-million-value array took 74 s
and 320 MB to turn into text that the store then refused), answers of types no store can hold are
skipped, not a traceback (old: a complex array of the key's shape), warnings stay one short line
each (old: a key of a million ids made a 3 MB warning) and their number is bounded."""

from __future__ import annotations

import gc
import pickle
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from lagrseq.config import LLMConfig
from lagrseq.errors import StoreError
from lagrseq.llm.authors_cache import MAX_WARNINGS, ImportReport, import_authors_cache
from lagrseq.llm.records import MAX_ANSWER_CHARS
from lagrseq.llm.store import RecordStore
from lagrseq.loop.lagr import query_for
from lagrseq.progress import Reporter
from lagrseq.tasks import cube
from lagrseq.tasks.arrangement import object_arrangement

CUBE = cube.CubeStacking(8)
GRID = object_arrangement()
WARNING_WIDTH = 300


def prompt_for(task: Any) -> Any:
    return lambda key: query_for(task, LLMConfig(), task.coerce_pattern(key)).prompt


def run_import(tmp_path: Path, pairs: list[Any], task: Any = CUBE) -> tuple[ImportReport, list[str], float]:
    """Import ``pairs`` (pickled as the authors did) into a fresh store: the report, the warnings
    and the CPU seconds the import took."""
    path = tmp_path / "cache.pkl"
    path.write_bytes(pickle.dumps(pairs, protocol=4))
    warnings: list[str] = []
    gc.collect()
    with RecordStore(tmp_path / f"store-{len(list(tmp_path.iterdir()))}") as store:
        started = time.process_time()
        report = import_authors_cache(
            path, store, prompt_for(task), task=task.name, model="gpt-4", temperature=0.0,
            endpoint="api.openai.com", max_tokens=256, reporter=Reporter(warn=warnings.append),
        )
        took = time.process_time() - started
    for line in warnings:
        assert "\n" not in line and len(line) <= WARNING_WIDTH, line[:400]
    return report, warnings, took


@pytest.mark.parametrize(
    "answer",
    [np.zeros(2_000_000, dtype=np.int8), np.zeros((8, 250_000)), ["a"] * 1_000_000, "e" * (MAX_ANSWER_CHARS + 1)],
    ids=["2M-value array", "2M-value matrix", "1M-item list", "text over the cap"],
)
def test_an_answer_too_large_to_store_is_refused_before_it_is_written_out(tmp_path: Path, answer: Any) -> None:
    report, warnings, took = run_import(tmp_path, [[4], answer, [4, 5], "['e','f','g']"])
    assert report.imported == 1 and report.skipped == 1
    assert len(warnings) == 1 and "(MAX_ANSWER_CHARS)" in warnings[0] and str(MAX_ANSWER_CHARS) in warnings[0]
    assert took < 1.0, f"{took:.2f} s"


@pytest.mark.parametrize(
    "answer",
    [
        np.zeros((5, 5), dtype=complex),
        np.array([[{1}, b"x", "s", None, 1.5]] * 5, dtype=object),
        np.zeros((5, 5), dtype=[("a", "i4"), ("b", "f8")]),
        np.array([["a"] * 5] * 5),
        b"raw bytes" * 1000,
        {i: i for i in range(100_000)},
        {1, 2, 3},
        [[0, 1]] * 5,
    ],
    ids=["complex", "objects", "structured", "strings", "bytes", "dict", "set", "nested list"],
)
def test_answers_of_other_types_are_skipped_with_one_short_warning(tmp_path: Path, answer: Any) -> None:
    target = GRID.target
    report, warnings, _ = run_import(tmp_path, [np.zeros((5, 5)), answer, np.zeros((5, 5)), target.astype(float)], GRID)
    assert report.imported == 1 and report.skipped == 1 and len(warnings) == 1


@pytest.mark.parametrize(
    "key",
    [[0] * 1_000_000, ["x" * 100_000], [list(range(100_000))], [1.5] * 3, "abc" * 100_000, {"k": 1}],
    ids=["a million ids", "a long string id", "a long list id", "floats", "a string", "a dict"],
)
def test_a_key_that_does_not_fit_makes_one_short_warning(tmp_path: Path, key: Any) -> None:
    report, warnings, took = run_import(tmp_path, [key, "['e']", [4], "['e','f']"])
    assert report.imported == 1 and report.skipped == 1 and len(warnings) == 1 and "does not fit task" in warnings[0]
    assert took < 1.0


def test_many_bad_pairs_make_a_bounded_number_of_warnings(tmp_path: Path) -> None:
    bad = [[9, 9], "x"] * (MAX_WARNINGS + 500)  # the pickle memoises the repeated objects: a small file
    report, warnings, _ = run_import(tmp_path, [*bad, [4], "['e','f']"])
    assert report.skipped == MAX_WARNINGS + 500 and report.imported == 1
    assert len(warnings) == MAX_WARNINGS + 1 and "skipped 500 more pairs" in warnings[-1]


values = st.recursive(
    st.one_of(
        st.integers(-(2**70), 2**70), st.floats(allow_nan=True), st.text(max_size=50), st.binary(max_size=20), st.none(),
        st.booleans(),
        st.sampled_from([np.zeros((5, 5)), np.ones((5, 5), dtype=np.int64), np.zeros((5, 5), dtype=complex), np.zeros(3),
                         np.array([["1"] * 5] * 5), np.full((5, 5), np.nan), np.zeros((0, 5))]),
    ),
    lambda inner: st.one_of(st.lists(inner, max_size=6), st.tuples(inner, inner), st.dictionaries(st.text(max_size=3), inner, max_size=3)),
    max_leaves=20,
)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(pairs=st.lists(st.tuples(values, values), max_size=6))
@example(pairs=[(np.full((5, 5), np.nan), 0)])  # 25 NaNs are 25 distinct set members: a 566-character line once
def test_any_pickled_data_imports_or_is_refused_in_one_line(tmp_path: Path, pairs: list[tuple[Any, Any]]) -> None:
    flat = [item for pair in pairs for item in pair]
    for task in (CUBE, GRID):
        try:
            report, warnings, _ = run_import(tmp_path, flat, task)
        except StoreError as exc:
            assert "\n" not in str(exc) and len(str(exc)) <= 400
            continue
        assert report.pairs == len(pairs) and report.skipped + report.imported + report.already_present >= report.pairs
        assert len(warnings) <= MAX_WARNINGS + 1


def test_a_key_of_many_nans_is_one_short_warning(tmp_path: Path) -> None:
    _, warnings, _ = run_import(tmp_path, [np.full((5, 5), np.nan), 0, np.full((5, 5), 7.0), 0], GRID)
    assert len(warnings) == 2 and all(len(line) <= WARNING_WIDTH for line in warnings)
    assert "found nan" in warnings[0] and "found 7" in warnings[1]
