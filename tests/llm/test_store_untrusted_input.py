"""Hostile input to the recorded store: malformed JSONL is refused before anything is written,
damaged store rows give one line naming the key, and a read-only store is read without writing."""

from __future__ import annotations

import io
import pickle
import re
import shutil
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import diskcache
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from jsonschema import Draft202012Validator

from lagrseq import cli
from lagrseq.errors import RecordMiss, StoreError
from lagrseq.llm.mock import MockProvider
from lagrseq.llm.recorded import RecordedProvider, RecordingProvider
from lagrseq.llm.records import MAX_LINE_BYTES, RECORD_SCHEMA, fits
from lagrseq.llm.store import (
    JSONOnlyDisk,
    RecordStore,
    Sample,
    export_jsonl,
    import_jsonl,
    import_jsonl_file,
    key_of_request,
)
from tests.llm.conftest import authors_cache
from tests.support.records import (
    BAD_FIELD_VALUES,
    DELETE,
    ENDPOINT,
    line,
    made_read_only,
    query,
    record,
    with_field,
)


def snapshot(directory: Path) -> dict[str, tuple[bytes, int]]:
    """Bytes and modification time of every file of a store (SQLite's shared-memory index, which
    every reader updates, aside)."""
    return {
        str(p.relative_to(directory)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(directory.rglob("*"))
        if p.is_file() and not p.name.endswith("-shm")
    }


def exported(directory: Path) -> str:
    with RecordStore(directory, create=False) as store:
        text = io.StringIO()
        export_jsonl(store, text)
    return text.getvalue()


@pytest.fixture(scope="module")
def base_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store holding two answers, made once; tests copy it."""
    directory = tmp_path_factory.mktemp("base") / "store"
    import_jsonl(io.StringIO(line(record(0)) + "\n" + line(record(1, "complete ['e']")) + "\n"), directory)
    return directory


def fresh_copy(base_store: Path, target: Path) -> Path:
    shutil.copytree(base_store, target)
    return target


# ------------------------------------------------------------------------------ JSONL import


@pytest.mark.parametrize(("path", "value", "message"), BAD_FIELD_VALUES, ids=[p for p, _, _ in BAD_FIELD_VALUES])
def test_every_bad_field_value_is_refused_with_its_line_and_the_store_is_unchanged(
    base_store: Path, tmp_path: Path, path: str, value: Any, message: str
) -> None:
    store = fresh_copy(base_store, tmp_path / "store")
    listing = exported(store)
    before = snapshot(store)
    text = "\n".join([line(record(5)), line(with_field(record(6), path, value)), line(record(7))]) + "\n"
    with pytest.raises(StoreError) as caught:
        import_jsonl(io.StringIO(text), store, "bad.jsonl")
    error = str(caught.value)
    assert error.startswith("bad.jsonl: 1 bad line of 3, nothing imported: line 2: ")
    assert message in error, error
    assert "\n" not in error and len(error) < 1000
    assert snapshot(store) == before and exported(store) == listing  # lines 1 and 3 were not written either


def test_bad_lines_are_listed_with_numbers_and_at_most_five_are_shown(tmp_path: Path) -> None:
    lines = [line(record(i)) for i in range(20)]
    for i in (1, 4, 6, 9, 12, 15, 18):
        lines[i] = line(with_field(record(i), "sample.latency_s", -1))
    with pytest.raises(StoreError) as caught:
        import_jsonl(io.StringIO("\n".join(lines)), tmp_path / "new", "x.jsonl")
    error = str(caught.value)
    assert error.startswith("x.jsonl: 7 bad lines of 20, nothing imported: line 2: sample.latency_s is -1")
    assert [f"line {n}:" in error for n in (2, 5, 7, 10, 13, 16, 19)] == [True] * 5 + [False] * 2
    assert error.endswith("(first 5 shown)")
    assert not (tmp_path / "new").exists()  # a rejected import into a new store creates nothing


# Values that are wrong for every field of a record.
BAD_ANYWHERE = st.one_of(
    st.sampled_from([float("nan"), float("inf"), float("-inf"), True, False]),
    st.integers(min_value=2**64, max_value=10**40) | st.integers(min_value=-(10**40), max_value=-(2**64)),
    st.builds(lambda a, b: a + "\ud800" + b, st.text(max_size=5), st.text(max_size=5)),
    st.dictionaries(st.sampled_from(["zz", "__class__", "x y"]), st.integers(), min_size=1, max_size=2),
    st.integers(min_value=1, max_value=3000).map(lambda depth: f"NESTED:{depth}"),
)
FIELDS = [
    "format", "key", "index", "task", "request", "sample", "request.key_version", "request.endpoint",
    "request.model", "request.messages", "request.messages.0", "request.messages.0.role",
    "request.messages.0.content", "request.temperature", "request.top_p", "request.max_tokens",
    "request.stop", "request.seed", "sample.id", "sample.text", "sample.origin", "sample.recorded_as",
    "sample.model", "sample.usage", "sample.usage.prompt_tokens", "sample.usage.completion_tokens",
    "sample.usage.cached_tokens", "sample.finish_reason", "sample.system_fingerprint", "sample.latency_s",
    "sample.cost_usd", "sample.recorded_at", "sample.provenance",
]
REQUIRED = ["request", "sample", "request.key_version", "request.endpoint", "request.model", "request.messages",
            "request.messages.0.role", "request.messages.0.content", "request.temperature", "request.top_p",
            "request.max_tokens", "request.stop", "request.seed", "sample.id", "sample.text", "sample.origin",
            "sample.usage.prompt_tokens"]


def _mutated_line(path: str, value: Any) -> str:
    if isinstance(value, str) and value.startswith("NESTED:"):
        depth = int(value.split(":")[1])
        return line(with_field(record(3), path, "@@")).replace('"@@"', "[" * depth + "]" * depth)
    return line(with_field(record(3), path, value))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    mutation=st.one_of(
        st.tuples(st.sampled_from(FIELDS), BAD_ANYWHERE),
        st.tuples(st.sampled_from(REQUIRED), st.just(DELETE)),
    ),
    position=st.integers(min_value=0, max_value=3),
    as_bytes=st.booleans(),
)
def test_any_malformed_record_is_refused_with_its_line_number_and_nothing_is_written(
    base_store: Path, tmp_path: Path, mutation: tuple[str, Any], position: int, as_bytes: bool
) -> None:
    store = tmp_path / "store"
    if not store.exists():
        fresh_copy(base_store, store)
    listing = exported(store)
    before = snapshot(store)
    lines = [line(record(10 + i)) for i in range(4)]
    lines[position] = _mutated_line(*mutation)
    text = "\n".join(lines) + "\n"
    source: io.IOBase = io.BytesIO(text.encode("utf-8", "surrogatepass")) if as_bytes else io.StringIO(text)
    with pytest.raises(StoreError) as caught:
        import_jsonl(source, store, "m.jsonl")  # type: ignore[arg-type]
    error = str(caught.value)
    assert error.startswith(f"m.jsonl: 1 bad line of 4, nothing imported: line {position + 1}: "), error
    assert "\n" not in error and len(error) < 1500
    assert snapshot(store) == before and exported(store) == listing


def test_valid_records_import_with_numbers_normalised_into_one_key(tmp_path: Path) -> None:
    hand_written = with_field(record(1), "request.temperature", 0)  # 0 and 0.0 make one key
    hand_written = with_field(hand_written, "request.top_p", 1)
    minimal = {"format": "lagrseq.recorded/1", "request": record(2)["request"], "sample": {"id": "m", "text": "", "origin": "authors-cache"}}
    text = "\n".join(line(r) for r in (record(0), hand_written, minimal)) + "\n\n"
    report = import_jsonl(io.BytesIO(("\ufeff" + text).encode()), tmp_path / "s")
    assert (report.lines, report.keys, report.added) == (3, 1, 3)
    with RecordStore(tmp_path / "s", create=False) as store:
        assert store.keys() == [record(0)["key"]]


@pytest.mark.parametrize(
    ("pickle_file", "task"),
    [("cube_stacking_cache0.0.pkl", "cube-stacking"), ("object_arrangement_gpt4.pkl", "object-arrangement")],
)
def test_exports_of_the_authors_caches_import_again(tmp_path: Path, capsys: pytest.CaptureFixture[str], pickle_file: str, task: str) -> None:
    path = authors_cache(pickle_file)
    args = ["cache", "import", str(path), "--task", task, "--model", "gpt-4", "--temperature", "0", "--store", str(tmp_path / "a")]
    assert cli.main(args) == 0
    text = exported(tmp_path / "a")
    (tmp_path / "a.jsonl").write_text(text, encoding="utf-8")
    report = import_jsonl_file(tmp_path / "a.jsonl", tmp_path / "b")
    assert report.added == len(text.splitlines()) > 0
    assert exported(tmp_path / "b") == text


def test_a_file_that_is_not_utf8_jsonl_is_refused_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "latin1.jsonl"
    bad.write_bytes((line(record(0)) + "\n").encode() + b'{"format": "caf\xe9"}\n')
    with pytest.raises(StoreError, match=r"1 bad line of 2, nothing imported: line 2: not UTF-8 \(byte 0xe9 at byte 16\).*--format pkl"):
        import_jsonl_file(bad, tmp_path / "s")
    with bad.open(encoding="utf-8") as handle, pytest.raises(StoreError, match="not UTF-8 text .*--format pkl"):
        import_jsonl(handle, tmp_path / "s", "latin1.jsonl")  # a text handle, as the CLI opens it today
    assert not (tmp_path / "s").exists()


def test_a_pickle_given_as_jsonl_suggests_format_pkl(tmp_path: Path) -> None:
    path = tmp_path / "cache.jsonl"
    path.write_bytes(pickle.dumps([[1, 2], "['e']"], protocol=4))
    with pytest.raises(StoreError, match=r"cache.jsonl is a pickle .*not JSONL; if it is an authors' cache pickle, import it with --format pkl"):
        import_jsonl_file(path, tmp_path / "s")
    with pytest.raises(StoreError, match="is a directory"):
        import_jsonl_file(tmp_path, tmp_path / "s")
    with pytest.raises(StoreError, match="cannot read .*missing.jsonl"):
        import_jsonl_file(tmp_path / "missing.jsonl", tmp_path / "s")


def test_deep_nesting_and_huge_numbers_are_line_errors(tmp_path: Path) -> None:
    text = "[" * 100_000 + "]" * 100_000 + "\n" + '{"format": "lagrseq.recorded/1", "index": ' + "9" * 5000 + "}\n"
    with pytest.raises(StoreError) as caught:
        import_jsonl(io.StringIO(text), tmp_path / "s", "deep.jsonl")
    assert "line 1: not a record (JSON nested too deeply)" in str(caught.value)
    assert "line 2: not JSON (Exceeds the limit" in str(caught.value)


class EndlessLine(io.RawIOBase):
    """A stream whose second line never ends (64 MiB without a newline), counting the largest
    read asked for."""

    def __init__(self) -> None:
        self.first = (line(record(0)) + "\n").encode()
        self.sent = 0
        self.largest = 0

    def readable(self) -> bool:
        return True

    def readline(self, size: int | None = -1) -> bytes:  # type: ignore[override]
        assert size is not None and size > 0, "a line must never be read whole"
        self.largest = max(self.largest, size)
        if self.first:
            out, self.first = self.first, b""
            return out
        if self.sent >= 64 << 20:
            return b""
        self.sent += size
        return b"x" * size


def test_a_line_over_the_size_cap_is_refused_without_reading_it_whole(tmp_path: Path) -> None:
    stream = EndlessLine()
    with pytest.raises(StoreError, match=f"line 2: longer than {MAX_LINE_BYTES} bytes"):
        import_jsonl(stream, tmp_path / "s", "endless.jsonl")  # type: ignore[arg-type]
    assert stream.sent >= 64 << 20 and stream.largest <= MAX_LINE_BYTES + 1


def test_a_large_file_of_valid_lines_imports_in_batches(tmp_path: Path) -> None:
    records = [record(i, f"prompt {i % 100}") for i in range(1500)]
    path = tmp_path / "big.jsonl"
    path.write_text("".join(line(r) + "\n" for r in records), encoding="utf-8")
    report = import_jsonl_file(path, tmp_path / "s")
    assert (report.lines, report.keys, report.added) == (1500, 100, 1500)
    again = import_jsonl_file(path, tmp_path / "s")
    assert (again.added, again.already_present) == (0, 1500)


# ------------------------------------------------------------------------------ damaged rows
def _plant(directory: Path, key: str, value: Any) -> None:
    """Write a row as an older lagrseq or a hand edit could (JSON, bypassing every check)."""
    with diskcache.Cache(str(directory), disk=JSONOnlyDisk, eviction_policy="none") as cache:
        cache.set(key, value)


def _good_value() -> dict[str, Any]:
    r = record(0)
    return {"request": r["request"], "task": "cube-stacking", "samples": [r["sample"]]}


DAMAGE = [
    ("messages [42]", lambda v: with_field(v, "request.messages", [42]), "request.messages[0] is 42"),
    ("lone surrogate", lambda v: with_field(v, "samples.0.text", "\udcff"), "samples[0].text holds a lone surrogate"),
    ("NaN latency", lambda v: with_field(v, "samples.0.latency_s", float("nan")), "samples[0].latency_s is nan"),
    ("not an object", lambda v: [1, 2], "the entry is a list of 2 items, expected an object"),
    ("request changed", lambda v: with_field(v, "request.temperature", 1.0), "the key is not the hash of its request"),
    ("no samples", lambda v: with_field(v, "samples", DELETE), "lacks field 'samples'"),
]


@pytest.mark.parametrize(("name", "damage", "message"), DAMAGE, ids=[d[0] for d in DAMAGE])
def test_a_damaged_store_row_is_one_line_naming_the_key_in_list_export_and_recorded_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, damage: Any, message: str
) -> None:
    store = tmp_path / "store"
    import_jsonl(io.StringIO(line(record(0, "another prompt")) + "\n"), store)
    key = record(0)["key"]
    _plant(store, key, damage(_good_value()))
    expected = f"key {key}: .*{re.escape(message)}.*rebuild it with `lagrseq cache import`"
    with RecordedProvider(RecordStore(store, create=False), ENDPOINT, 0) as provider, pytest.raises(StoreError, match=expected):
        provider.complete(query())
    with RecordedProvider(RecordStore(store, create=False), ENDPOINT, 0, MockProvider(lambda p, t, rng: "x", np.random.default_rng(0))) as provider, pytest.raises(StoreError, match=expected):
        provider.complete(query())
    with RecordStore(store, create=False) as opened, pytest.raises(StoreError, match=expected):
        export_jsonl(opened, io.StringIO())
    with RecordStore(store) as opened, pytest.raises(StoreError, match=expected):
        opened.add(key, record(0)["request"], None, [Sample("new", "x", "live")])  # never extended
    capsys.readouterr()
    for command in (["cache", "list", "--store", str(store)], ["cache", "export", "--store", str(store), "--out", "-"]):
        assert cli.main(command) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and len(captured.err.strip().splitlines()) == 1 and key in captured.err


def test_a_store_row_pointing_outside_the_store_is_refused(tmp_path: Path) -> None:
    store = tmp_path / "store"
    import_jsonl(io.StringIO(line(record(0)) + "\n"), store)
    with sqlite3.connect(store / "cache.db") as db:
        db.execute("UPDATE Cache SET mode = 2, filename = '../../etc/passwd', value = NULL WHERE raw = 1 AND size = 0 AND key != ?", (b"",))
    with pytest.raises(StoreError, match="points a value at '../../etc/passwd', outside the store directory"), RecordStore(store, create=False) as opened:
        list(opened.entries())


# ------------------------------------------------------------------------------ read-only stores


@pytest.fixture
def read_only(tmp_path: Path) -> Iterator[Path]:
    """A store in a directory nobody can write, not even root: ``chattr +i`` where the file
    system allows it, plain permissions for other users; skipped where neither holds."""
    store = tmp_path / "ro"
    import_jsonl(io.StringIO(line(record(0)) + "\n" + line(record(1, "other")) + "\n"), store)
    with made_read_only(store):
        yield store


def test_a_read_only_store_serves_list_export_and_recorded_runs(read_only: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(read_only)
    with RecordedProvider(RecordStore(read_only, create=False), ENDPOINT, 0) as provider:
        assert provider.complete(query()).text == "['e','f','a0']"
        with pytest.raises(RecordMiss, match="nearest recorded keys"):
            provider.complete(query("never recorded"))
    assert cli.main(["cache", "list", "--store", str(read_only)]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 2
    assert cli.main(["cache", "export", "--store", str(read_only), "--out", str(tmp_path / "out.jsonl")]) == 0
    assert len((tmp_path / "out.jsonl").read_text().splitlines()) == 2
    with pytest.raises(StoreError, match="cannot be written .*it is read-only; .*make it writable, or use another store"):
        import_jsonl(io.StringIO(line(record(5)) + "\n"), read_only)
    with pytest.raises(StoreError, match="cannot be written .*it is read-only"):
        RecordingProvider(RecordStore(read_only), MockProvider(lambda p, t, rng: "x", np.random.default_rng(0)), ENDPOINT)
    assert snapshot(read_only) == before


def test_reading_a_store_opens_sqlite_read_only_and_never_the_writing_cache(
    base_store: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the read-only test checks where it cannot run (root without chattr): the read paths
    never open diskcache (which writes on opening) and change no byte of the database."""
    store = fresh_copy(base_store, tmp_path / "store")

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("a read path opened the writing diskcache")

    monkeypatch.setattr(diskcache, "Cache", refuse)
    before = snapshot(store)
    with RecordedProvider(RecordStore(store, create=False), ENDPOINT, 0) as provider:
        assert provider.store._reader is not None and "mode=ro" in provider.store._reader.uri(False)
        assert provider.complete(query()).record_key == record(0)["key"]
        export_jsonl(provider.store, io.StringIO())
        assert len(provider.store) == 2
    after = snapshot(store)
    assert after["cache.db"] == before["cache.db"]
    assert set(after) - set(before) <= {"cache.db-wal"} and not after.get("cache.db-wal", (b"",))[0]


def test_a_store_being_created_by_another_process_is_read_without_a_false_alarm(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A reader opening a store while another process creates it (the tables exist, the header
    and the first answers land between the reader's two reads) must not call it a foreign cache.
    The header is the first row a store gets, so the reader counts first and reads it after."""
    store = tmp_path / "s"
    diskcache.Cache(str(store), disk=JSONOnlyDisk).close()  # the creator's tables, no row yet
    from lagrseq.llm import store as store_module

    count = store_module.ReadOnlyDatabase.count
    created: list[bool] = []

    def count_then_let_the_creator_write(self: Any) -> int:
        if not created:  # the other process writes its header and one answer just now
            created.append(True)
            with RecordStore(store) as writer:
                writer.add(record(0)["key"], record(0)["request"], "cube-stacking", [Sample.from_json(record(0)["sample"])])
        return count(self)

    monkeypatch.setattr(store_module.ReadOnlyDatabase, "count", count_then_let_the_creator_write)
    with RecordStore(store, create=False) as reader:
        assert created and len(reader) == 1


def test_store_paths_that_are_files_or_missing_are_one_line(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    for create in (True, False):
        with pytest.raises(StoreError, match="is a file; expected a directory"):
            RecordStore(tmp_path / "file", create=create)
    with pytest.raises(StoreError, match="no recorded store at .*lagrseq record"):
        RecordStore(tmp_path / "missing", create=False)
    with pytest.raises(StoreError, match="could not open it for writing"):
        RecordStore(tmp_path / "file" / "below")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "cache.db").write_bytes(b"not a database at all" * 100)
    with pytest.raises(StoreError, match="store .*junk: could not open it"):
        RecordStore(tmp_path / "junk", create=False)
    (tmp_path / "other").mkdir()
    with sqlite3.connect(tmp_path / "other" / "cache.db") as db:
        db.execute("CREATE TABLE people (name TEXT)")
    for create in (True, False):
        with pytest.raises(StoreError, match="holds an SQLite database that is not a lagrseq store"):
            RecordStore(tmp_path / "other", create=create)
    assert key_of_request(record(0)["request"]) == record(0)["key"]


# ------------------------------------------------------------------------------ the fast check agrees with jsonschema
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(2**70), max_value=2**70) | st.floats() | st.text(max_size=8)
    | st.sampled_from(["", "user", "text", "live", "a" * 65, "2025-01-31T12:00:00Z", "0" * 64, "lagrseq.recorded/1"]),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.sampled_from(["role", "content", "id", "x"]), inner, max_size=3),
    max_leaves=8,
)


RECORD_VALIDATOR = Draft202012Validator(RECORD_SCHEMA)
VALID_RECORD = record(0)


@settings(max_examples=150, deadline=None)
@given(path=st.sampled_from(FIELDS), value=JSON_VALUES | st.just(DELETE))
def test_the_fast_check_gives_jsonschemas_verdict(path: str, value: Any) -> None:
    mutated = with_field(VALID_RECORD, path, value)
    assert fits(mutated, RECORD_SCHEMA) == RECORD_VALIDATOR.is_valid(mutated)
