"""Padded and flooded logs are judged by what they hold, not walked record by record.

Walked record by record, a valid MCAP start followed by megabytes of zeros would be millions of
9-byte records of opcode 0 (about 2 s a MB in Python). The reader stops at the first zero opcode and
measures the run of zeros in C; these tests check what every reader says about such files
(the time for 300 MB is printed by ``benchmarks/bench_scan.py``, not asserted here).
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from mcap.records import Chunk

from lagrseq import config as cfg
from lagrseq.cli import main
from lagrseq.errors import LogError, UsageError
from lagrseq.logs import mcap_reader
from lagrseq.logs.mcap_reader import Damage, McapFile
from lagrseq.logs.reader import full_path, read_info, read_topics
from lagrseq.logs.recover import recover
from lagrseq.progress import Reporter
from lagrseq.running.recording import record_patterns
from tests.support.golden_mcap import DATA, GOLDEN

CONFIG = cfg.load("cube-stacking", "lagr-seq", "upstream")
PADDING = 20_000_000
_HEADER_END = 8 + 9 + struct.unpack_from("<Q", DATA, 9)[0]
"""Where the golden log's header record ends (the magic, then the header)."""


def _padded(path: Path, start: bytes, size: int = PADDING) -> Path:
    """``start`` followed by zeros up to ``size`` bytes in all (a sparse file: no disk used)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as handle:
        handle.write(start)
        handle.truncate(size)
    return path


def test_a_log_start_followed_by_zeros_is_one_line_from_every_reader(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _padded(tmp_path / "runs" / "trial-000.mcap", DATA[:_HEADER_END])
    zeros = f"{PADDING - _HEADER_END} zero bytes from here to the end of the file"

    with pytest.raises(LogError) as cut:
        recover(log, tmp_path / "out.mcap")
    assert zeros in str(cut.value) and f"no episode was flushed before byte {_HEADER_END}" in str(cut.value)
    assert not (tmp_path / "out.mcap").exists()

    with pytest.raises(LogError) as read:
        read_info(log)
    assert "damaged MCAP log" in str(read.value) and zeros in str(read.value) and "\n" not in str(read.value)

    with pytest.raises(UsageError) as asked:  # record --from-runs: no states, the skipped log named
        record_patterns(CONFIG, [log.parent], reporter=Reporter.silent())
    assert "1 log skipped" in str(asked.value) and zeros in str(asked.value)

    code = main(["replay", str(log.parent), "--out", str(tmp_path / "reports")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and zeros in err[0], err


def test_a_partial_log_padded_with_zeros_keeps_its_flushed_episodes(tmp_path: Path) -> None:
    partial = _padded(tmp_path / "trial-000.mcap.partial", DATA[:13000])
    result = recover(partial)
    kept = read_topics(result.path, ["/episode"])["/episode"]
    assert 0 < len(kept) < 4 and result.episodes == len(kept)
    assert kept == read_topics(tmp_path / "trial-000.mcap", ["/episode"])["/episode"]
    assert result.dropped_bytes >= PADDING - 13000
    assert f"{result.episodes} episodes, {result.messages} messages kept" in result.summary()


def test_zeros_then_data_again_say_where_the_data_is(tmp_path: Path) -> None:
    log = tmp_path / "trial-000.mcap.partial"
    log.write_bytes(DATA[:_HEADER_END] + b"\0" * 1000 + DATA[_HEADER_END:13000])
    with McapFile(log) as opened, pytest.raises(Damage) as found:
        list(opened.scan())
    assert found.value.offset == _HEADER_END
    assert "1000 zero bytes, then other bytes again at 1000 bytes further" in found.value.what


def test_a_run_of_zeros_is_measured_no_further_than_the_cap(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mcap_reader, "MAX_ZERO_SCAN", 4096)
    log = _padded(tmp_path / "trial-000.mcap.partial", DATA[:_HEADER_END], 100_000)
    with McapFile(log) as opened, pytest.raises(Damage) as found:
        list(opened.scan())
    assert "at least 4096 zero bytes (measured no further)" in found.value.what


def test_a_flood_of_records_no_lagrseq_log_holds_is_refused_after_the_cap(tmp_path: Path) -> None:
    private = struct.pack("<BQ", 0x80, 0)  # a private record (opcode 0x80) with an empty body
    log = tmp_path / "trial-000.mcap.partial"
    log.write_bytes(DATA[:_HEADER_END] + private * (mcap_reader.MAX_UNKNOWN_RECORDS + 10))
    with McapFile(log) as opened, pytest.raises(Damage) as found:
        list(opened.scan())
    assert f"more than {mcap_reader.MAX_UNKNOWN_RECORDS} records of kinds no lagrseq log holds" in found.value.what
    with pytest.raises(LogError) as refused:
        recover(log)
    assert "more than 1024 records" in str(refused.value) and str(full_path(log)) in str(refused.value)


@pytest.mark.parametrize(
    ("inside", "said"),
    [
        (b"\0" * 90, "90 zero bytes from here to the end of the chunk's data"),
        (struct.pack("<BQ", 0x0C, 0), "a metadata record at 0 of 9; a chunk holds schemas, channels and messages only"),
    ],
    ids=["zeros", "metadata"],
)
def test_a_chunk_holding_what_no_chunk_holds_is_damage(tmp_path: Path, inside: bytes, said: str) -> None:
    chunk = Chunk(compression="", data=inside, message_end_time=0, message_start_time=0, uncompressed_crc=0, uncompressed_size=len(inside))
    log = tmp_path / "any.mcap"
    log.write_bytes(DATA)
    with McapFile(log) as opened:
        for read in (opened.chunk_records, lambda c, o: opened.chunk_messages(c, o, {1})):
            with pytest.raises(Damage) as found:
                read(chunk, 123)
            assert found.value.offset == 123 and said in found.value.what


_FLUSHED = 12635  # the golden log's data up to a chunk and its two message indexes (episodes flushed)
_INDEX = struct.pack("<BQHI", 0x07, 6, 1, 0)  # a valid message index record: channel 1, no entries (15 bytes)
_STATISTICS = struct.pack("<BQ", 0x0B, 46) + bytes(46)  # a valid statistics record, all counts 0
_METADATA = struct.pack("<BQII", 0x0C, 8, 0, 0)  # a valid metadata record: no name, no entries
_EMPTY_CHUNK = struct.pack("<BQQQQIIQ", 0x06, 40, 0, 0, 0, 0, 0, 0)  # a valid chunk holding nothing


@pytest.mark.parametrize(
    ("flood", "first_refused", "said"),
    [
        # two message indexes follow the chunk already: the 63rd added is the 65th after it
        (_INDEX * 10_000, _FLUSHED + 62 * len(_INDEX), "more than 64 message index records after one chunk"),
        (_METADATA + _INDEX * 10_000, _FLUSHED + len(_METADATA), "a message index record after a metadata record, not after its chunk"),
        (_STATISTICS * 10_000, _FLUSHED + len(_STATISTICS), "statistics record number 2, more than the file can hold (1: one per file)"),
        # the golden start holds one metadata record
        (_METADATA * 10_000, _FLUSHED + 1023 * len(_METADATA), "metadata record number 1025, more than the file can hold (1024"),
    ],
    ids=["message-indexes-after-a-chunk", "message-indexes-after-no-chunk", "statistics", "metadata"],
)
def test_a_flood_of_small_valid_records_is_refused_at_the_first_one_too_many(
    tmp_path: Path, flood: bytes, first_refused: int, said: str
) -> None:
    """Records a lagrseq log never holds in such numbers or places stop the walk at once (10,000
    are written; the walk stops within the first 64, or 1,024 metadata records): ``recover`` keeps the episodes flushed
    before them and says how many, in one line."""
    log = tmp_path / "trial-000.mcap.partial"
    log.write_bytes(DATA[:_FLUSHED] + flood)
    walked = 0
    with McapFile(log) as opened, pytest.raises(Damage) as found:
        for offset, _end, _record in opened.scan():
            walked += 1
            assert offset < first_refused
    assert found.value.offset == first_refused and said in found.value.what, found.value.what
    assert walked < 1100
    result = recover(log)
    assert result.episodes == len(read_topics(result.path, ["/episode"])["/episode"]) > 0
    assert f"{result.episodes} episodes, {result.messages} messages kept" in result.summary()


def test_a_scan_stops_after_its_record_cap(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Any walk outside chunks stops after MAX_SCAN_RECORDS records (here lowered to 40; the
    golden start holds 23 up to its last flush, then 1,000 empty chunks, each with a message
    index, follow: the kinds a log holds in numbers)."""
    monkeypatch.setattr(mcap_reader, "MAX_SCAN_RECORDS", 40)
    log = tmp_path / "trial-000.mcap.partial"
    log.write_bytes(DATA[:_FLUSHED] + (_EMPTY_CHUNK + _INDEX) * 1000)
    offsets = []
    with McapFile(log) as opened, pytest.raises(Damage) as found:
        offsets.extend(offset for offset, _end, _record in opened.scan())
    before = sum(1 for offset in offsets if offset < _FLUSHED)
    assert before == 23 and len(offsets) == 40
    assert "more than 40 records outside chunks" in found.value.what
    assert found.value.offset == _FLUSHED + (40 - before) // 2 * len(_EMPTY_CHUNK + _INDEX) + len(_EMPTY_CHUNK)
    assert recover(log).episodes > 0


def test_the_golden_log_has_what_the_bounds_allow() -> None:
    """The bounds hold for a real log: at most 2 message indexes after a chunk, 1 statistics
    record, as many chunk indexes as chunks."""
    with McapFile(GOLDEN) as opened:
        kinds = [type(record).__name__ for _, _, record in opened.scan()]
    assert kinds.count("Statistics") == 1 and kinds.count("ChunkIndex") == kinds.count("Chunk") == 8
