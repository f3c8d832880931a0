"""The MCAP sink: readable by the plain mcap library, schemas valid, crash behaviour."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import jsonschema
import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from lagrseq import config as cfg
from lagrseq.errors import LogError
from lagrseq.logs.events import (
    EpisodeEvent,
    NotAsked,
    ProbeQueryEvent,
    QueryEvent,
    Transition,
    encode,
    log_time,
    to_record,
)
from lagrseq.logs.reader import (
    fill_query_defaults,
    is_complete,
    iter_messages,
    read_info,
    read_topics,
)
from lagrseq.logs.schemas import EPISODE, QUERY, TRANSITION
from lagrseq.logs.sink import CHUNK_BYTES, McapSink, NullSink
from lagrseq.running.runner import run_one


@pytest.fixture(scope="module")
def trial_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=80"])
    return run_one(config, 0, 0, "mock", tmp_path_factory.mktemp("log") / "trial-000.mcap").path


def test_plain_mcap_reads_every_message_and_its_schema(trial_log: Path) -> None:
    counts: dict[str, int] = {}
    steps_of: dict[str, list[int]] = {}
    with trial_log.open("rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        for schema, channel, message in reader.iter_messages():
            assert schema is not None and schema.encoding == "jsonschema"
            assert channel.message_encoding == "json"
            record = json.loads(message.data)
            jsonschema.validate(record, json.loads(schema.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/transitions":  # log format 3: an episode's steps, as columns
                steps = steps_of.setdefault("/transition", [])
                steps.append(len(record["step"]))
            elif channel.topic == "/no_query":
                steps_of.setdefault("/no_query", []).append(len(record["step"]))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert counts["/transitions"] == 80 and steps_of["/transition"] == [50] * 80
    assert counts["/episode"] == 80 and counts["/query"] > 0 and counts["/no_query"] == len(steps_of["/no_query"])
    records = metadata["lagrseq.records"]
    assert records["/transition"] == "4000" and records["/episode"] == "80"
    assert records["/query"] == str(counts["/query"] + sum(steps_of["/no_query"]))
    run = metadata["lagrseq.run"]
    assert json.loads(run["config"])["method"] == "lagr-seq"
    assert (run["seed"], run["trial"], run["provider"]) == ("0", "0", "mock")
    assert metadata["lagrseq.status"]["status"] == "complete"


def test_log_times_are_logical_steps(trial_log: Path) -> None:
    """An episode's ``/transitions`` record is logged at its first step; the records the
    readers expand from it each at their own step."""
    with trial_log.open("rb") as handle:
        times = [m.log_time for _, c, m in make_reader(handle).iter_messages() if c.topic == "/transitions"]
    assert times == list(range(0, 4000, 50))
    assert [r["global_step"] for t, r in iter_messages(trial_log, ["/transition"])] == list(range(4000))


def test_summary_topics_live_in_their_own_chunks(trial_log: Path) -> None:
    with trial_log.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    channels = {c.id: c.topic for c in summary.channels.values()}
    for index in summary.chunk_indexes:
        topics = {channels[i] for i in index.message_index_offsets}
        assert topics == {"/transitions"} or "/transitions" not in topics


def test_failed_trial_still_leaves_a_valid_file(tmp_path: Path) -> None:
    path = tmp_path / "t.mcap"
    with pytest.raises(RuntimeError), McapSink(path, {"config": "{}"}) as sink:
        sink.write_record("/episode", {"x": 1}, 0)
        sink.flush()
        raise RuntimeError("boom")
    info = read_info(path)
    assert info.status["status"] == "failed" and "boom" in info.status["error"]
    assert not is_complete(path) and not (tmp_path / "t.mcap.partial").exists()


def test_partial_file_until_finished(tmp_path: Path) -> None:
    path = tmp_path / "t.mcap"
    sink = McapSink(path, {"config": "{}"})
    assert (tmp_path / "t.mcap.partial").exists() and not path.exists()
    sink.finish()
    sink.finish()  # idempotent
    assert path.exists() and is_complete(path)


def test_truncated_or_foreign_files_give_one_line_errors(trial_log: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(trial_log.read_bytes()[: trial_log.stat().st_size // 2])
    with pytest.raises(LogError, match="lagrseq recover") as info:
        list(iter_messages(cut))
    assert "\n" not in str(info.value)
    assert not is_complete(cut)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(LogError, match="not a readable MCAP log"):
        read_info(junk)


def test_unserialisable_record_is_a_log_error(tmp_path: Path) -> None:
    with McapSink(tmp_path / "t.mcap", {"config": "{}"}) as sink, pytest.raises(LogError, match="JSON"):
        sink.write_record("/transitions", {"reward": [float("nan")]}, 0)


def test_event_encoding_equals_the_json_of_its_record() -> None:
    """msgspec encodes an event as the standard library would encode its record (field order,
    separators, number formats), for the values a trial produces."""
    from lagrseq.logs.sink import _encode

    transitions = [
        Transition(1, 2, 3, 4, (4, 5, 6), 7, -0.125, False, True, True),
        Transition(0, 0, 0, 0, (), 0, 0.0, False, False, False),
        Transition(0, 1, 2, 3, [[0, 1], [1, 0]], 5, 1.0, True, False, False),
        Transition(0, 1, 2, 3, (1,), 5, 0.1 + 0.2, False, False, False),
    ]
    for event in transitions:
        assert list(to_record(event)) == list(TRANSITION["required"]), "contract order"
        assert encode(event) == _encode(to_record(event)), event
    arm = Transition(0, 1, 2, 3, (1,), 1, 0.04, False, False, True, {"row": 1, "col": 2, "outcome": "placed", "ok": True})
    assert list(to_record(arm)) == list(TRANSITION["properties"]), "arm tasks add placement at the end"
    assert encode(arm) == _encode(to_record(arm))
    skip = QueryEvent(0, 1, 2, 3, (4, 5), 0)
    sent = msgspec.structs.replace(skip, queried=True, answer="['e'] \u00e9 \"quoted\"", decision=1, evaluation=0.75, cost_usd=1.5e-06)
    for event in (skip, sent):
        assert list(to_record(event)) == list(QUERY["properties"])
        # log format 2: fields at their default are left out, and readers put them back
        assert fill_query_defaults(json.loads(encode(event))) == json.loads(_encode(to_record(event)))
    assert json.loads(encode(skip)) == {"trial": 0, "episode": 1, "step": 2, "global_step": 3, "state": [4, 5], "decision": 0}
    assert list(json.loads(encode(skip))) == QUERY["required"]
    probe = ProbeQueryEvent(**msgspec.structs.asdict(skip), prefix_length=2, fraction=0.25)
    assert list(json.loads(encode(probe)))[-2:] == ["prefix_length", "fraction"], "added after the contract"


def test_numpy_scalars_are_logged_as_numbers_and_non_finite_floats_refused(tmp_path: Path) -> None:
    import numpy as np

    event = Transition(0, 0, 0, 0, (np.int64(3),), 1, 1.0, False, False, False)
    assert json.loads(encode(event))["state"] == [3]
    with McapSink(tmp_path / "t.mcap", {"config": "{}"}) as sink:
        for bad in (
            Transition(0, 0, 0, 0, (), 0, float("nan"), False, False, False),
            QueryEvent(0, 0, 0, 0, (), 1, evaluation=float("inf")),
            EpisodeEvent(0, 0, float("-inf"), 1),
        ):
            with pytest.raises(LogError, match="not JSON-serialisable"):
                sink.write(bad)


def test_episode_event_keeps_the_return_field_name() -> None:
    event = EpisodeEvent(0, 1, 12.5, 50, 3, 1, 0.05, True, 4, 100)
    assert list(to_record(event)) == list(EPISODE["required"])
    assert to_record(event)["return"] == 12.5 and log_time(event) == 99
    from lagrseq.logs.events import ArmEpisodeEvent

    arm = ArmEpisodeEvent(0, 1, 12.5, 50, 3, 1, 0.05, True, 4, 100, 8, 1)
    assert list(to_record(arm)) == list(EPISODE["properties"]), "arm tasks add the placement counts at the end"
    assert to_record(arm)["return"] == 12.5 and log_time(arm) == 99


def test_null_sink_takes_every_event_and_writes_nothing(tmp_path: Path) -> None:
    with NullSink() as sink:
        sink.write(Transition(0, 0, 0, 0, (), 0, 0.0, False, False, False))
        sink.write(QueryEvent(0, 0, 0, 0, (), 0))
        sink.flush()
    sink.close()
    assert list(tmp_path.iterdir()) == []


def test_a_sink_refuses_what_is_not_an_event(tmp_path: Path) -> None:
    with McapSink(tmp_path / "t.mcap", {"config": "{}"}) as sink, pytest.raises(LogError, match="cannot log a dict"):
        sink.write({"trial": 0})  # type: ignore[arg-type]


def test_lean_message_index_equals_the_reference_library() -> None:
    from mcap.data_stream import RecordBuilder
    from mcap.records import MessageIndex

    from lagrseq.logs.mcap_writer import _message_index

    builder = RecordBuilder()
    MessageIndex(channel_id=3, records=[(1, 2), (5, 99), (2**40, 7)]).write(builder)
    reference = builder.end()
    assert _message_index(3, [1, 2, 5, 99, 2**40, 7]) == reference
    from array import array

    assert _message_index(3, array("Q", [1, 2, 5, 99, 2**40, 7])) == reference


def test_lean_chunk_record_equals_the_reference_library() -> None:
    from mcap.data_stream import RecordBuilder
    from mcap.records import Chunk

    from lagrseq.logs.mcap_writer import _chunk_record

    builder = RecordBuilder()
    Chunk(message_start_time=3, message_end_time=2**40, uncompressed_size=77, uncompressed_crc=12345,
          compression="zstd", data=b"\x00compressed bytes").write(builder)
    assert _chunk_record(3, 2**40, 77, 12345, b"zstd", b"\x00compressed bytes") == builder.end()


def test_lean_chunk_index_equals_the_reference_library() -> None:
    from mcap.data_stream import RecordBuilder
    from mcap.records import ChunkIndex

    from lagrseq.logs.mcap_writer import _chunk_index_record

    for compression in ("zstd", ""):
        builder = RecordBuilder()
        ChunkIndex(message_start_time=1, message_end_time=2**33, chunk_start_offset=99, chunk_length=1234,
                   message_index_offsets={1: 5000, 3: 6000}, message_index_length=77, compression=compression,
                   compressed_size=400, uncompressed_size=900).write(builder)
        packed = _chunk_index_record(1, 2**33, 99, 1234, {1: 5000, 3: 6000}, 77, compression.encode(), 400, 900)
        assert packed == builder.end()


def test_every_record_of_a_trial_log_is_the_reference_librarys_packing(tmp_path: Path) -> None:
    """A real trial's log, read record by record with ``mcap``'s stream reader and each record
    packed again by ``mcap.records``: the very bytes lagrseq wrote, from the header through the
    chunks, message indexes, metadata, statistics, summary offsets and footer to the magic."""
    from mcap.data_stream import RecordBuilder
    from mcap.stream_reader import StreamReader

    from lagrseq.logs.mcap_writer import MAGIC

    path = tmp_path / "trial.mcap"
    run_one(cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=30"]), 0, 0, "mock", path)
    data = path.read_bytes()
    builder = RecordBuilder()
    kinds = set()
    for record in StreamReader(str(path), emit_chunks=True, validate_crcs=True).records:
        record.write(builder)
        kinds.add(type(record).__name__)
    assert MAGIC + builder.end() + MAGIC == data
    assert {"Header", "Schema", "Channel", "Chunk", "MessageIndex", "Metadata", "DataEnd", "Statistics",
            "ChunkIndex", "MetadataIndex", "SummaryOffset", "Footer"} <= kinds, kinds


def _episodes(sink: McapSink, episodes: range, steps: int, stop_at: int | None = None, flush: bool = True,
              not_asked: bool = False) -> None:
    """Write cube-like episodes: ``steps`` transitions and a decision every 10 steps, then the /episode
    record (and ``flush``: a flush after it); ``stop_at``: raise KeyboardInterrupt at that step
    of the last episode, after its records so far were written. ``not_asked``: the decisions as
    :class:`NotAsked`, else as ``QueryEvent(..., 0)``."""
    for episode in episodes:
        for step in range(steps):
            t = episode * steps + step
            if step % 10 == 0:
                sink.write(NotAsked(0, episode, step, t, (step % 8,)) if not_asked else QueryEvent(0, episode, step, t, (step % 8,), 0))
            sink.write(Transition(0, episode, step, t, tuple(range(step % 8)), step % 8, 1.0, False, step == steps - 1, False))
            if stop_at is not None and episode == episodes[-1] and step == stop_at:
                raise KeyboardInterrupt
        sink.write(EpisodeEvent(0, episode, float(steps), steps, global_step=(episode + 1) * steps))
        if flush:
            sink.flush()


def test_small_chunks_are_stored_uncompressed_and_read_back(tmp_path: Path) -> None:
    path = tmp_path / "t.mcap"
    with McapSink(path, {"config": "{}"}, chunk_bytes=0) as sink:  # a chunk per episode
        _episodes(sink, range(3), steps=40)
    with path.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    kinds = [index.compression for index in summary.chunk_indexes]
    assert kinds == ["zstd", ""] * 3, "transition chunks compressed, a few decisions and an /episode not"
    assert all(index.compression == "zstd" or index.uncompressed_size < 1024 for index in summary.chunk_indexes)
    topics = read_topics(path, ["/episode", "/query", "/transition"])
    assert [len(topics[t]) for t in ("/episode", "/query", "/transition")] == [3, 12, 120]


def test_chunks_end_at_episode_ends_once_big_enough(trial_log: Path) -> None:
    """A transition chunk holds whole episodes and at least CHUNK_BYTES of records (the last
    one: what was left); the summary chunk after it holds the same episodes' records."""
    with trial_log.open("rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.id: c.topic for c in summary.channels.values()}
        indexes = sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset)
        pairs = list(zip(indexes[::2], indexes[1::2], strict=True))
        assert 1 < len(pairs) < 20, "80 episodes of about 2 KB: many episodes a chunk"
        episodes = read_topics(trial_log, ["/episode"])["/episode"]
        # an episode's /transitions record is logged at its first step, its /episode at its last
        last_step = {e["global_step"] - e["length"]: e["global_step"] - 1 for e in episodes}
        for number, (transitions, held) in enumerate(pairs):
            assert {channels[i] for i in transitions.message_index_offsets} == {"/transitions"}
            assert "/transitions" not in {channels[i] for i in held.message_index_offsets}
            assert transitions.message_end_time in last_step, "a chunk holds whole episodes"
            assert held.message_end_time == last_step[transitions.message_end_time], "and so does the one after it"
            if number < len(pairs) - 1:
                assert transitions.uncompressed_size >= CHUNK_BYTES


@pytest.mark.parametrize("flush", [True, False])
@pytest.mark.parametrize("log_format", ["2", "3"])
def test_ctrl_c_keeps_every_finished_episode_and_drops_the_unfinished_one(tmp_path: Path, log_format: str,
                                                                          flush: bool) -> None:
    from lagrseq.logs.recover import recover

    path = tmp_path / "trial-000.mcap"
    with pytest.raises(KeyboardInterrupt), McapSink(path, {"config": "{}"}, log_format=log_format) as sink:
        _episodes(sink, range(3), steps=40, stop_at=25, flush=flush)  # episodes 0 and 1 end; 2 does not
    partial = path.with_name(path.name + ".partial")
    assert not path.exists() and partial.is_file()
    result = recover(partial)
    topics = read_topics(result.path, ["/episode", "/query", "/transition"])
    assert [e["episode"] for e in topics["/episode"]] == [0, 1]
    assert [r["global_step"] for r in topics["/transition"]] == list(range(80))
    assert [r["global_step"] for r in topics["/query"]] == list(range(0, 80, 10))


def test_a_rollback_leaves_the_file_as_if_nothing_was_added_after_the_mark() -> None:
    """The writer's mark is the open chunk's size only; rolling back finds what came after it by
    its offset: the same bytes (indexes, sequence numbers, statistics) as never adding it."""
    import io

    from lagrseq.logs.mcap_writer import LeanWriter

    def written(extra: bool) -> bytes:
        out = io.BytesIO()
        writer = LeanWriter(out, profile="lagrseq")
        a, b, c = (writer.register_channel(topic, "json", 0) for topic in ("/a", "/b", "/c"))
        writer.add_message(a, 0, b"1")
        writer.flush()
        writer.add_message(a, 1, b"2")
        writer.add_message(b, 1, b"3")
        mark = writer.mark()
        if extra:
            writer.add_message(a, 2, b"4")
            writer.add_message(c, 2, b"5")  # a channel first used after the mark
            writer.add_message(b, 3, b"6")
            writer.rollback(mark)
        writer.add_message(b, 4, b"7")
        writer.finish()
        return out.getvalue()

    assert written(extra=True) == written(extra=False)


@pytest.mark.parametrize("log_format", ["3", "2"])
def test_an_episode_record_ends_its_episode_as_a_flush_does(tmp_path: Path, log_format: str) -> None:
    """The loop hands the sink every record as it comes and never flushes: an ``/episode``
    record ends its episode (columnar records, chunks), the same file as a flush after it."""
    paths = {}
    for flush in (True, False):
        paths[flush] = tmp_path / f"flush-{flush}.mcap"
        with McapSink(paths[flush], {"run": "x"}, chunk_bytes=4096, log_format=log_format) as sink:
            _episodes(sink, range(6), steps=40, flush=flush)
    assert paths[True].read_bytes() == paths[False].read_bytes()


@pytest.mark.parametrize("log_format", ["3", "2"])
def test_a_not_asked_record_writes_the_bytes_of_its_query_event(tmp_path: Path, log_format: str) -> None:
    """What the loop writes for a decision not to query (:class:`NotAsked`) gives the file that
    ``QueryEvent(trial, episode, step, global_step, state, 0)`` gives."""
    paths = {}
    for not_asked in (True, False):
        paths[not_asked] = tmp_path / f"not-asked-{not_asked}.mcap"
        with McapSink(paths[not_asked], {"run": "x"}, log_format=log_format) as sink:
            _episodes(sink, range(3), steps=40, not_asked=not_asked)
    assert paths[True].read_bytes() == paths[False].read_bytes()
    assert [q["decision"] for q in read_topics(paths[True], ["/query"])["/query"]] == [0] * 12
    assert to_record(NotAsked(0, 1, 2, 3, (4,))) == to_record(QueryEvent(0, 1, 2, 3, (4,), 0))


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=5000), running=st.integers(0, 2**32 - 1))
def test_the_log_checksum_is_zlibs_crc32(data: bytes, running: int) -> None:
    """The logger's CRC-32 (zlib-ng's where installed) is the standard library's, byte for byte,
    from any running value: a log's checksums do not depend on which one wrote it."""
    import zlib

    from lagrseq.logs.crc import crc32

    assert crc32(data, running) == zlib.crc32(data, running)
    assert crc32(bytearray(data)) == zlib.crc32(data)


@pytest.mark.skipif(sys.platform == "win32", reason="no advisory file locks (fcntl) on Windows")
def test_a_writer_that_gets_the_lock_after_the_first_finished_refuses_and_the_log_stays_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two identical runs at once: the second opens ``NAME.partial`` while the first still writes
    it, and gets the lock only once the first has finished (renamed its file to ``NAME``, then
    let go of the lock). The second is refused with one line, and the first's log is whole: it
    is never truncated under its new name."""
    from lagrseq.logs import sink as sink_module

    path = tmp_path / "trial-000.mcap"
    first = McapSink(path, {"writer": "first"})
    _episodes(first, range(3), 20)
    real_flock = sink_module.fcntl.flock

    def flock_once_the_first_finished(descriptor: int, operation: int) -> None:
        monkeypatch.setattr(sink_module.fcntl, "flock", real_flock)
        first.finish()
        real_flock(descriptor, operation)

    monkeypatch.setattr(sink_module.fcntl, "flock", flock_once_the_first_finished)
    with pytest.raises(LogError, match="another lagrseq process"):
        McapSink(path, {"writer": "second"})
    assert is_complete(path) and not path.with_name(path.name + ".partial").exists()
    assert read_info(path).run["writer"] == "first"
    assert [e["episode"] for e in read_topics(path, ["/episode"])["/episode"]] == [0, 1, 2]
    second = McapSink(path, {"writer": "second"})  # a writer that comes later writes the trial anew
    _episodes(second, range(2), 20)
    second.finish()
    assert read_info(path).run["writer"] == "second" and is_complete(path)
