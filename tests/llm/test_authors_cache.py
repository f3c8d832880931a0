"""The authors'-cache importer: restricted unpickling, rebuilt prompts, skipped entries."""

from __future__ import annotations

import builtins
import io
import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest

from lagrseq.config import LLMConfig
from lagrseq.errors import StoreError
from lagrseq.llm.authors_cache import RestrictedUnpickler, import_authors_cache, read_pairs
from lagrseq.llm.store import RecordStore, query_key
from lagrseq.loop.lagr import query_for
from lagrseq.progress import Reporter
from lagrseq.tasks import cube
from tests.llm.conftest import authors_cache

ENDPOINT = "api.openai.com"


class _Calls:
    """Pickles into a call of ``function(*args)``."""

    def __init__(self, function: object, *args: object) -> None:
        self.function = function
        self.args = args

    def __reduce__(self) -> tuple[object, tuple[object, ...]]:
        return (self.function, self.args)


@pytest.mark.parametrize(
    "payload",
    [
        lambda marker: _Calls(os.system, f"touch {marker}"),
        lambda marker: _Calls(builtins.exec, f"open({str(marker)!r}, 'w').close()"),
        lambda marker: _Calls(np.save, str(marker), np.zeros(1)),  # numpy, but not array reconstruction
    ],
)
def test_a_pickle_with_any_other_global_is_refused_and_nothing_runs(tmp_path: Path, payload: object) -> None:
    marker = tmp_path / "ran"
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps([[4], payload(marker)]))  # type: ignore[operator]
    with RecordStore(tmp_path / "store") as store, pytest.raises(StoreError, match="refusing to load .*Nothing was executed"):
        import_authors_cache(path, store, lambda key: "x", task="t", model="m", temperature=0.0, endpoint=ENDPOINT, max_tokens=256)
    assert not marker.exists() and not (tmp_path / "ran.npy").exists()
    with RecordStore(tmp_path / "store") as store:
        assert store.keys() == []


def test_numpy_arrays_and_plain_data_load() -> None:
    data = [np.arange(6).reshape(2, 3), {"a": [1, "b", 2.5]}, np.zeros((2, 2), dtype=np.float64)]
    blob = pickle.dumps(data, protocol=4)  # the protocol of the authors' files (NumPy reconstructs)
    loaded = RestrictedUnpickler(io.BytesIO(blob)).load()
    assert np.array_equal(loaded[0], data[0]) and loaded[1] == data[1] and loaded[2].dtype == np.float64


def test_a_file_that_is_not_a_flat_pair_list(tmp_path: Path) -> None:
    (tmp_path / "odd.pkl").write_bytes(pickle.dumps([[4], "a", [5]]))
    with pytest.raises(StoreError, match="flat list alternating key, answer; found a list of 3"):
        read_pairs(tmp_path / "odd.pkl")
    (tmp_path / "junk.pkl").write_bytes(b"not a pickle")
    with pytest.raises(StoreError, match="not a readable pickle"):
        read_pairs(tmp_path / "junk.pkl")


def cube_prompt_for(stack_size: int, model: str = "gpt-3.5-turbo") -> object:
    task = cube.CubeStacking(stack_size)
    llm = LLMConfig(model=model, temperature=0.0, max_tokens=256)
    return lambda key: query_for(task, llm, task.coerce_pattern(key)).prompt


def test_the_8_cube_cache_imports_as_81_samples_keyed_like_a_run(tmp_path: Path) -> None:
    path = authors_cache("cube_stacking_cache0.0.pkl")
    warnings: list[str] = []
    with RecordStore(tmp_path / "store") as store:
        report = import_authors_cache(
            path, store, cube_prompt_for(8), task="cube-stacking", model="gpt-3.5-turbo",
            temperature=0.0, endpoint=ENDPOINT, max_tokens=256, reporter=Reporter(warn=warnings.append),
        )
        assert (report.pairs, report.imported, report.skipped, report.keys) == (81, 81, 0, 8)
        task = cube.CubeStacking(8)
        llm = LLMConfig(model="gpt-3.5-turbo", temperature=0.0, max_tokens=256)
        for prefix in task.prefixes():  # a run's query for every prefix finds its answers
            entry = store.entry(query_key(query_for(task, llm, prefix), ENDPOINT)[0])
            assert entry is not None and entry.task == "cube-stacking"
            assert len(entry.samples) == (11 if len(prefix) == 1 else 10)
            assert all(s.origin == "authors-cache" and s.model == "gpt-3.5-turbo" for s in entry.samples)
        first = store.entry(query_key(query_for(task, llm, (4,)), ENDPOINT)[0])
        assert first is not None
        assert [s.recorded_as for s in first.samples].count("list") == 1  # the seed pair ['e']
        assert task.parse(first.samples[0].text).solution == (4,)
        assert "cube_stacking_cache0.0.pkl pair 0" in (first.samples[0].provenance or "")
        again = import_authors_cache(
            path, store, cube_prompt_for(8), task="cube-stacking", model="gpt-3.5-turbo",
            temperature=0.0, endpoint=ENDPOINT, max_tokens=256,
        )
        assert (again.imported, again.already_present) == (0, 81)
    assert warnings == []


def test_keys_that_do_not_fit_the_task_are_skipped_with_a_warning(tmp_path: Path) -> None:
    path = authors_cache("cube_stacking_cache0.pkl")  # 11 cubes (ids up to 10) and the 8-cube seed pair
    warnings: list[str] = []
    with RecordStore(tmp_path / "store") as store:
        report = import_authors_cache(
            path, store, cube_prompt_for(8), task="cube-stacking", model="gpt-3.5-turbo",
            temperature=0.0, endpoint=ENDPOINT, max_tokens=256, reporter=Reporter(warn=warnings.append),
        )
    assert report.skipped == len(warnings) > 0 and report.imported == report.pairs - report.skipped
    assert all("does not fit task cube-stacking" in w for w in warnings)
    assert any("cube id 10 is not one of the 8 cubes" in w for w in warnings)


def test_grid_answers_are_written_as_text_and_marked_as_arrays(tmp_path: Path) -> None:
    path = authors_cache("object_arrangement_gpt4.pkl")

    def prompt_for(key: object) -> str:
        if not isinstance(key, np.ndarray) or key.shape != (5, 5):
            raise ValueError(f"expected a 5x5 grid, found {getattr(key, 'shape', key)}")
        return "arrange:\n" + str(key.astype(int))

    warnings: list[str] = []
    with RecordStore(tmp_path / "store") as store:
        report = import_authors_cache(
            path, store, prompt_for, task="object-arrangement", model="gpt-4",
            temperature=0.0, endpoint=ENDPOINT, max_tokens=256, reporter=Reporter(warn=warnings.append),
        )
        assert report.pairs == 143 and report.skipped == 1 and "pair 0" in warnings[0] and "(10, 10)" in warnings[0]
        entries = list(store.entries())
    pairs = read_pairs(path)
    assert report.imported == 142 and sum(len(e.samples) for e in entries) == 142
    by_prompt = {e.prompt: e for e in entries}
    for key, answer in pairs[1:]:
        sample = by_prompt[prompt_for(key)].samples[0]
        assert sample.recorded_as == "array"
        assert np.array_equal(np.array(json.loads(sample.text)), answer)


def test_answers_a_store_may_not_hold_are_skipped_with_a_warning(tmp_path: Path) -> None:
    from lagrseq.llm.records import MAX_ANSWER_CHARS

    path = tmp_path / "hostile.pkl"
    path.write_bytes(pickle.dumps([[4], "['e','f']", [5], "x" * (MAX_ANSWER_CHARS + 1), [6], "bad \ud800 text"]))
    warnings: list[str] = []
    with RecordStore(tmp_path / "store") as store:
        report = import_authors_cache(
            path, store, lambda key: f"prompt {key}", task="cube-stacking", model="gpt-3.5-turbo",
            temperature=0.0, endpoint=ENDPOINT, max_tokens=256, reporter=Reporter(warn=warnings.append),
        )
        assert (report.imported, report.skipped) == (1, 2)
        assert sum(len(e.samples) for e in store.entries()) == 1
    assert f"pair 1: answer.text is a string of {MAX_ANSWER_CHARS + 1} characters" in warnings[0]
    assert "pair 2: answer.text holds a lone surrogate" in warnings[1]
