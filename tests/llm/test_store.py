"""The recorded store: keys, JSON-only diskcache, concurrency, sample choice, misses, JSONL."""

from __future__ import annotations

import io
import json
import multiprocessing
import os
import zlib
from collections import Counter
from pathlib import Path

import diskcache
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lagrseq.errors import RecordMiss, StoreError
from lagrseq.llm.base import Message, Query, Usage, user_query
from lagrseq.llm.recorded import RecordedProvider
from lagrseq.llm.store import (
    RecordStore,
    Sample,
    endpoint_of,
    export_jsonl,
    import_jsonl,
    import_jsonl_file,
    key_of_request,
    pick_index,
    prompt_similarity,
    query_key,
)
from lagrseq.progress import Reporter

ENDPOINT = "api.openai.com"


def query(prompt: str = "complete ['e','f']", **changes: object) -> Query:
    base = Query("cube-stacking", "gpt-3.5-turbo", (Message("user", prompt),), 0.0, 256)
    return Query(**{**base.__dict__, **changes})  # type: ignore[arg-type]


def samples(prefix: str, count: int, start: int = 0) -> list[Sample]:
    return [Sample(id=f"{prefix}-{i}", text=f"answer {i}", origin="live", usage=Usage(10, 2)) for i in range(start, start + count)]


# ------------------------------------------------------------------------------ keys
def test_the_key_writes_api_defaults_in_and_normalises_numbers() -> None:
    key, request = query_key(query(), ENDPOINT)
    assert request == {
        "key_version": 1,
        "endpoint": "api.openai.com",
        "model": "gpt-3.5-turbo",
        "messages": [{"role": "user", "content": "complete ['e','f']"}],
        "temperature": 0.0,
        "top_p": 1.0,
        "max_tokens": 256,
        "stop": None,
        "seed": None,
    }
    assert key == key_of_request(request) and len(key) == 64
    assert query_key(query(temperature=0), ENDPOINT)[0] == key  # 0 and 0.0 are one key
    assert query_key(query(stop=()), ENDPOINT)[0] == key  # no stop sequences is the API default
    assert query_key(query(task="another task"), ENDPOINT)[0] == key  # the server never sees the task


@pytest.mark.parametrize(
    "change",
    [
        {"model": "gpt-4"},
        {"temperature": 0.5},
        {"top_p": 0.9},
        {"max_tokens": 100},
        {"stop": ("\n",)},
        {"seed": 3},
        {"messages": (Message("system", "be brief"), Message("user", "complete ['e','f']"))},
        {"messages": (Message("user", "complete ['e','f','g']"),)},
    ],
)
def test_every_field_that_changes_an_answer_changes_the_key(change: dict[str, object]) -> None:
    assert query_key(query(**change), ENDPOINT)[0] != query_key(query(), ENDPOINT)[0]


def test_the_endpoint_is_the_host_with_a_non_default_port() -> None:
    assert endpoint_of("https://api.openai.com/v1") == "api.openai.com"
    assert endpoint_of("https://API.OpenAI.com:443/v1/") == "api.openai.com"
    assert endpoint_of("http://localhost:11434/v1") == "localhost:11434"
    assert endpoint_of("http://127.0.0.1:80/v1") == "127.0.0.1"
    assert query_key(query(), "localhost:8000")[0] != query_key(query(), ENDPOINT)[0]
    with pytest.raises(StoreError, match="has no host"):
        endpoint_of("http:///v1")


# ------------------------------------------------------------------------------ the store
def test_samples_are_appended_once_by_id_and_survive_reopening(tmp_path: Path) -> None:
    key, request = query_key(query(), ENDPOINT)
    with RecordStore(tmp_path / "store") as store:
        assert store.add(key, request, "cube-stacking", samples("a", 3)) == 3
        assert store.add(key, request, "cube-stacking", samples("a", 4)) == 4  # a-0..a-2 already there
        assert store.keys() == [key] and len(store) == 1
    with RecordStore(tmp_path / "store", create=False) as store:
        entry = store.entry(key)
    assert entry is not None and entry.task == "cube-stacking" and entry.request == request
    assert [s.id for s in entry.samples] == ["a-0", "a-1", "a-2", "a-3"]
    assert entry.samples[0].usage == Usage(10, 2)


def test_a_key_that_is_not_the_hash_of_its_request_is_refused(tmp_path: Path) -> None:
    _, request = query_key(query(), ENDPOINT)
    with RecordStore(tmp_path / "store") as store, pytest.raises(StoreError, match="not the hash"):
        store.add("0" * 64, request, None, samples("a", 1))


def test_opening_a_missing_store_read_only_says_how_to_make_one(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="lagrseq record"):
        RecordStore(tmp_path / "nothing", create=False)
    (tmp_path / "file").write_text("x")
    with pytest.raises(StoreError, match="is a file"):
        RecordStore(tmp_path / "file")


def test_the_store_is_configured_json_only_without_eviction(tmp_path: Path) -> None:
    with RecordStore(tmp_path / "store") as store:
        cache = store._cache
        assert isinstance(cache.disk, diskcache.JSONDisk)
        assert cache.eviction_policy == "none"


class _RunsCode:
    """Pickles into a call of os.system (what a planted cache entry could do)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[str]]:
        return (os.system, (f"touch {self.marker}",))


def test_a_pickled_value_planted_in_the_store_is_refused_and_never_runs(tmp_path: Path) -> None:
    key, request = query_key(query(), ENDPOINT)
    with RecordStore(tmp_path / "store") as store:
        store.add(key, request, None, samples("a", 1))
    marker = tmp_path / "ran"
    planted = "f" * 64
    our_key = zlib.compress(json.dumps(planted).encode(), 1)  # the key as lagrseq writes it
    with diskcache.Cache(str(tmp_path / "store")) as foreign:  # the default, pickling disk
        foreign.set(our_key, _RunsCode(marker))
    with RecordStore(tmp_path / "store", create=False) as store:
        assert store.entry(key) is not None  # JSON rows still read
        with pytest.raises(StoreError, match="stored as pickle; lagrseq stores are JSON only"):
            store.entry(planted)
    assert not marker.exists()


def test_a_key_lagrseq_did_not_write_is_refused(tmp_path: Path) -> None:
    with RecordStore(tmp_path / "store"):
        pass
    with diskcache.Cache(str(tmp_path / "store")) as foreign:
        foreign.set("plain", "x")
    with RecordStore(tmp_path / "store", create=False) as store, pytest.raises(StoreError, match="did not write"):
        store.keys()


def test_a_pickled_key_planted_in_the_store_is_refused(tmp_path: Path) -> None:
    with RecordStore(tmp_path / "store"):
        pass
    with diskcache.Cache(str(tmp_path / "store")) as foreign:
        foreign.set(("a", "tuple", "key"), "x")  # tuple keys are pickled by the default disk
    with RecordStore(tmp_path / "store", create=False) as store, pytest.raises(StoreError, match="pickled key"):
        store.keys()


def test_a_foreign_diskcache_is_not_adopted(tmp_path: Path) -> None:
    with diskcache.Cache(str(tmp_path / "other")) as foreign:
        foreign.set("k", "v")
    with pytest.raises(StoreError, match="not a lagrseq store"):
        RecordStore(tmp_path / "other")


def _append_many(directory: str, worker: int, count: int) -> None:
    key, request = query_key(query(), ENDPOINT)
    with RecordStore(directory) as store:
        for i in range(count):  # one transaction per sample: the most contention
            store.add(key, request, "cube-stacking", [Sample(id=f"w{worker}-{i}", text=f"{worker}/{i}", origin="live")])


def test_several_processes_appending_to_one_key_lose_nothing(tmp_path: Path) -> None:
    directory = str(tmp_path / "store")
    RecordStore(directory).close()
    context = multiprocessing.get_context("spawn")  # never fork a threaded test process
    workers = [context.Process(target=_append_many, args=(directory, w, 25)) for w in range(4)]
    for process in workers:
        process.start()
    for process in workers:
        process.join(60)
        assert process.exitcode == 0
    with RecordStore(directory, create=False) as store:
        entry = store.entry(query_key(query(), ENDPOINT)[0])
    assert entry is not None and len(entry.samples) == 100
    assert {s.id for s in entry.samples} == {f"w{w}-{i}" for w in range(4) for i in range(25)}
    for w in range(4):  # each worker's samples keep their order
        mine = [s.id for s in entry.samples if s.id.startswith(f"w{w}-")]
        assert mine == [f"w{w}-{i}" for i in range(25)]


# ------------------------------------------------------------------------------ sample choice
def test_sample_choice_is_a_function_of_seed_key_and_occurrence() -> None:
    key = query_key(query(), ENDPOINT)[0]
    picks = [pick_index(0, key, k, 10) for k in range(200)]
    assert picks == [pick_index(0, key, k, 10) for k in range(200)]
    assert picks != [pick_index(1, key, k, 10) for k in range(200)]
    other = query_key(query("complete ['e']"), ENDPOINT)[0]
    assert picks != [pick_index(0, other, k, 10) for k in range(200)]
    counts = Counter(picks)
    assert set(counts) == set(range(10)) and max(counts.values()) < 40  # roughly uniform


def test_a_recorded_provider_serves_the_same_samples_whatever_else_is_asked(tmp_path: Path) -> None:
    first, second = query(), query("complete ['e']")
    with RecordStore(tmp_path / "store") as store:
        for q in (first, second):
            key, request = query_key(q, ENDPOINT)
            store.add(key, request, "cube-stacking", samples(key[:6], 10))

    def served(order: list[Query], seed: int) -> list[int | None]:
        provider = RecordedProvider(RecordStore(tmp_path / "store", create=False), ENDPOINT, seed)
        with provider:
            return [provider.complete(q).sample_index for q in order if q is first]

    alone = served([first] * 6, 5)
    interleaved = served([first, second, second, first, first, second, first, first, first], 5)
    assert alone == interleaved  # depends on (seed, key, occurrence) only
    assert alone != served([first] * 6, 6)


def test_a_recorded_answer_costs_nothing_and_says_where_it_came_from(tmp_path: Path) -> None:
    key, request = query_key(query(), ENDPOINT)
    with RecordStore(tmp_path / "store") as store:
        store.add(key, request, "cube-stacking", [Sample("x", "['e','f','g']", "live", model="gpt-3.5-turbo-0125", usage=Usage(300, 20), cost_usd=0.01)])
    with RecordedProvider(RecordStore(tmp_path / "store", create=False), ENDPOINT, 0) as provider:
        answer = provider.complete(query())
    assert answer.source == "recorded" and answer.cost_usd == 0.0 and answer.usage == Usage(300, 20)
    assert answer.record_key == key and answer.sample_index == 0 and answer.model == "gpt-3.5-turbo-0125"


# ------------------------------------------------------------------------------ misses
def test_a_strict_miss_names_task_model_temperature_and_the_nearest_keys(tmp_path: Path) -> None:
    recorded = [query("A human is stacking ['e','f']"), query("A human is stacking ['e','f','g']")]
    with RecordStore(tmp_path / "store") as store:
        for q in recorded:
            key, request = query_key(q, ENDPOINT)
            store.add(key, request, "cube-stacking", samples(key[:4], 2))
    asked = query("A human is stacking ['e','f']", model="gpt-4", temperature=0.5)
    with RecordedProvider(RecordStore(tmp_path / "store", create=False), ENDPOINT, 0) as provider, pytest.raises(RecordMiss) as caught:
        provider.complete(asked)
    message = str(caught.value)
    same_prompt = query_key(recorded[0], ENDPOINT)[0]
    assert "task cube-stacking" in message and "model gpt-4" in message and "temperature 0.5" in message
    assert f"key {query_key(asked, ENDPOINT)[0][:12]}" in message
    assert "nearest recorded keys: " + same_prompt[:12] in message  # same prompt, other settings first
    assert "model 'gpt-3.5-turbo' instead of 'gpt-4'" in message and "temperature 0.0 instead of 0.5" in message
    assert "--on-miss" in message and "\n" not in message


def test_a_miss_on_the_open_models_image_store_names_the_prompt_one_cell_away(tmp_path: Path) -> None:
    """The real SmolLM2 image answers (418 prompts of about 1,400 characters, nearly all zeros):
    the prompt asked with one cell changed is named first (difflib took 131 s for this message)."""
    import_jsonl_file(Path(__file__).parents[2] / "recorded_llm" / "smollm2-135m-image-t0.jsonl", tmp_path / "store")
    with RecordStore(tmp_path / "store", create=False) as store:
        entries = list(store.entries())
        target = entries[len(entries) // 2]
        prompt = target.prompt
        cell = prompt.rindex("0 0")  # a cell of the partial image, near the end
        changed = prompt[:cell] + "1" + prompt[cell + 1 :]
        request = {**target.request, "messages": [*target.request["messages"][:-1], {"role": "user", "content": changed}]}
        near = store.nearest(request, "image-completion")
    assert near[0][0].key == target.key
    assert "alike; recorded text from the first difference: '0" in near[0][1]
    assert len(entries) > 400 and len(prompt) > 1000


@given(st.text(alphabet="01 []ab", max_size=60), st.text(alphabet="01 []ab", max_size=60))
def test_prompt_similarity_is_a_symmetric_fraction_that_is_one_only_for_equal_prompts(a: str, b: str) -> None:
    alike = prompt_similarity(a, b)
    assert 0.0 <= alike <= 1.0 and alike == prompt_similarity(b, a)
    assert (alike == 1.0) == (a == b)


def test_a_miss_in_an_empty_store(tmp_path: Path) -> None:
    with RecordedProvider(RecordStore(tmp_path / "store"), ENDPOINT, 0) as provider, pytest.raises(RecordMiss, match="the store is empty"):
        provider.complete(query())


# ------------------------------------------------------------------------------ JSONL
def _filled(directory: Path) -> RecordStore:
    store = RecordStore(directory)
    for i, q in enumerate([query(), query("complete ['e']", temperature=1.0), query("ünïcode ✓")]):
        key, request = query_key(q, ENDPOINT)
        store.add(key, request, "cube-stacking", samples(f"s{i}", 3))
    key, request = query_key(query(), ENDPOINT)
    store.add(key, request, None, [Sample("arr", "[[0, 1], [1, 0]]", "authors-cache", recorded_as="array", provenance="x.pkl pair 3")])
    return store


def test_jsonl_round_trips_byte_for_byte(tmp_path: Path) -> None:
    with _filled(tmp_path / "a") as store:
        first = io.StringIO()
        report = export_jsonl(store, first)
    assert report.lines == 10 and report.keys == 3
    lines = first.getvalue().splitlines()
    assert all(json.loads(line)["format"] == "lagrseq.recorded/1" for line in lines)
    assert "ünïcode ✓" in first.getvalue()  # human-readable, not escaped
    with RecordStore(tmp_path / "b") as copy:
        imported = import_jsonl(io.StringIO(first.getvalue()), copy)
        assert (imported.added, imported.already_present) == (10, 0)
        again = import_jsonl(io.StringIO(first.getvalue()), copy)
        assert (again.added, again.already_present) == (0, 10)  # idempotent
        second = io.StringIO()
        export_jsonl(copy, second)
    assert second.getvalue() == first.getvalue()


def test_a_hand_edited_request_is_filed_under_its_new_key(tmp_path: Path) -> None:
    with _filled(tmp_path / "a") as store:
        text = io.StringIO()
        export_jsonl(store, text)
    record = json.loads(text.getvalue().splitlines()[0])
    record["request"]["temperature"] = 0.7
    warnings: list[str] = []
    with RecordStore(tmp_path / "b") as copy:
        import_jsonl(io.StringIO(json.dumps(record) + "\n"), copy, "edited.jsonl", Reporter(warn=warnings.append))
        assert copy.keys() == [key_of_request(record["request"])]
    assert warnings and "edited.jsonl line 1" in warnings[0]


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("{not json", "line 2: not JSON"),
        ('{"format": "other"}', "line 2: expected a 'lagrseq.recorded/1' record"),
        ('{"format": "lagrseq.recorded/1", "request": {"messages": [], "key_version": 9}, "sample": {}}', "line 2: request lacks fields 'endpoint'.*request.key_version is 9, expected 1"),
        ('{"format": "lagrseq.recorded/1", "request": {"messages": [], "key_version": 1}, "sample": {"id": "x"}}', "sample lacks fields 'text', 'origin'"),
    ],
)
def test_a_bad_jsonl_line_is_named(tmp_path: Path, line: str, message: str) -> None:
    with RecordStore(tmp_path / "s") as store, pytest.raises(StoreError, match=message):
        import_jsonl(io.StringIO("\n" + line + "\n"), store, "bad.jsonl")


def test_user_query_keys_match_a_hand_built_query() -> None:
    built = user_query("cube-stacking", "complete ['e','f']", "gpt-3.5-turbo", 0.0, 256)
    assert query_key(built, ENDPOINT) == query_key(query(), ENDPOINT)
