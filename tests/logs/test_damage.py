"""Damaged MCAP logs: a flipped bit in any length or offset is one LogError line, never a
MemoryError, another exception or a hang, and reading never allocates much more than the file."""

from __future__ import annotations

import shutil
import struct
import time
import tracemalloc
import zlib
from collections.abc import Callable
from pathlib import Path

import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.opcode import Opcode
from mcap.records import Chunk

from lagrseq.errors import LogError
from lagrseq.logs.mcap_reader import Damage, McapFile
from lagrseq.logs.reader import iter_messages, read_info, read_log, read_topics
from lagrseq.logs.recover import diagnose, recover
from tests.support.golden_mcap import CHUNK_DATA_LENGTHS, DATA, GOLDEN, MEMORY_BOUND, length_fields

TIME_BOUND = 10.0
"""A hang guard, not a speed target: a damaged log is refused in well under a second on a quiet
machine (tests never time what a benchmark measures)."""


def _readers(path: Path) -> list[Callable[[], object]]:
    return [
        lambda: read_info(path),
        lambda: read_log(path, ["/episode", "/query"]),
        lambda: list(iter_messages(path)),
        lambda: diagnose(path),
    ]


def _only_log_errors(path: Path, readers: list[Callable[[], object]] | None = None) -> None:
    for read in readers or _readers(path):
        start = time.perf_counter()
        try:
            read()
        except LogError as exc:
            assert "\n" not in str(exc)
        assert time.perf_counter() - start < TIME_BOUND


def test_the_golden_file_has_the_fields_these_tests_flip() -> None:
    fields = length_fields(DATA)
    assert len(fields) > 150
    assert all(offset > 0 and offset + width <= len(DATA) for offset, width in fields)


def test_a_flipped_bit_in_any_length_field_is_a_log_error(tmp_path: Path) -> None:
    path = tmp_path / "damaged.mcap"
    failures = 0
    for offset, width in length_fields(DATA):
        for bit in (8 * width - 1,):  # an exabyte (or 2 GiB for a 4-byte field)
            data = bytearray(DATA)
            data[offset + bit // 8] ^= 1 << (bit % 8)
            path.write_bytes(data)
            try:
                read_log(path, ["/episode", "/query", "/transition"])
            except LogError:
                failures += 1
            _only_log_errors(path, _readers(path)[::3])  # read_info and diagnose
    # the rest are records the indexed reader never reads (data-section schemas, message indexes)
    assert failures > 150, "most flips are caught (CRC, index and layout checks)"


def test_reading_a_damaged_length_allocates_about_the_file_size(tmp_path: Path) -> None:
    """Lengths made half a gigabyte larger (an allocation that size would succeed, so only the
    peak shows it): the peak of Python allocations stays near the file size."""
    path = tmp_path / "damaged.mcap"
    tracemalloc.start()
    try:
        for offset, _width in length_fields(DATA):
            for bit in (29,):
                data = bytearray(DATA)
                data[offset + bit // 8] ^= 1 << (bit % 8)
                path.write_bytes(data)
                _only_log_errors(path, [lambda: read_log(path, ["/episode", "/query", "/transition"])])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_BOUND


def test_the_exact_chunk_length_flip_that_ran_out_of_memory(tmp_path: Path) -> None:
    """Bit 62 of a chunk's data length: ``mcap`` asked for 4 EiB (MemoryError)."""
    length_fields(DATA)
    assert len(CHUNK_DATA_LENGTHS) == 8
    path = tmp_path / "flipped.mcap"
    for field in CHUNK_DATA_LENGTHS:
        data = bytearray(DATA)
        data[field + 7] ^= 0x40
        path.write_bytes(data)
        with pytest.raises(LogError, match=r"damaged MCAP log .*cannot repair it \(corrupt at"):
            list(iter_messages(path))


def test_chunk_records_with_damaged_inner_lengths_are_damage() -> None:
    """Inside a chunk whose CRC is right (so only the record lengths are wrong)."""
    with McapFile(GOLDEN) as log:
        summary = log.summary()
        assert summary is not None
        index = summary.chunk_indexes[1]
        chunk = log.chunk(index)
        raw = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        assert len(log.chunk_records(chunk, index.chunk_start_offset)) > 3
        pos, heads, damaged = 0, [], 0
        while pos < len(raw):
            heads.append(pos)
            pos += 9 + struct.unpack_from("<Q", raw, pos + 1)[0]
        for head in heads:
            for bit in (0, 5, 20, 40, 63):
                data = bytearray(raw)
                data[head + 1 + bit // 8] ^= 1 << (bit % 8)
                fake = Chunk(
                    compression="",
                    data=bytes(data),
                    message_start_time=0,
                    message_end_time=0,
                    uncompressed_crc=zlib.crc32(data),
                    uncompressed_size=len(data),
                )
                try:
                    log.chunk_records(fake, index.chunk_start_offset)
                except Damage as exc:
                    assert exc.offset == index.chunk_start_offset and "chunk" in str(exc)
                    damaged += 1
        assert damaged >= 4 * len(heads), "every flip but the lowest bit runs past the chunk"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    flips=st.lists(
        st.tuples(st.integers(0, len(DATA) - 1), st.integers(0, 7)), min_size=1, max_size=4
    )
)
def test_random_bit_flips_anywhere_are_log_errors(tmp_path: Path, flips: list[tuple[int, int]]) -> None:
    data = bytearray(DATA)
    for offset, bit in flips:
        data[offset] ^= 1 << bit
    path = tmp_path / "random.mcap"
    path.write_bytes(data)
    _only_log_errors(path)


@pytest.mark.parametrize(
    "damage",
    ["one byte short", "garbage appended", "zeros appended", "summary index flipped", "no footer"],
)
def test_damage_after_the_data_section_is_rebuilt_whole(tmp_path: Path, damage: str) -> None:
    data = bytearray(DATA)
    if damage == "one byte short":
        data = data[:-1]
    elif damage == "garbage appended":
        data += b"\x07garbage that replay rejects" * 3
    elif damage == "zeros appended":
        data += bytes(4096)
    elif damage == "summary index flipped":
        chunk_index = next(o for o, w in length_fields(DATA) if DATA[o - 1] == Opcode.CHUNK_INDEX)
        data[chunk_index + 9 + 16] ^= 0x10  # its chunk start offset
    else:
        data = data[: len(data) - 37]
    path = tmp_path / "trial-000.mcap"
    path.write_bytes(bytes(data))
    with pytest.raises(LogError) as info:
        read_log(path, ["/episode"])
    assert f"lagrseq recover {path}" in str(info.value)  # runnable: no quoting needed here
    assert diagnose(path).recoverable
    result = recover(path)
    assert result.complete and result.path == path
    assert result.backup is not None and result.backup.read_bytes() == bytes(data)
    info_after = read_info(path)
    assert info_after.complete, "the trial's own status survives a rebuilt summary"
    topics = ["/episode", "/query", "/transition"]
    assert read_topics(path, topics) == read_topics(GOLDEN, topics)
    assert list(iter_messages(path)) == list(iter_messages(GOLDEN))


def test_a_path_with_spaces_is_quoted_in_the_command(tmp_path: Path) -> None:
    folder = tmp_path / "my runs; x"
    folder.mkdir()
    path = folder / "trial 0.mcap"
    path.write_bytes(DATA[:-1])
    with pytest.raises(LogError) as info:
        read_info(path)
    assert f"`lagrseq recover '{path}'`" in str(info.value)


def test_a_damaged_copy_elsewhere_is_named_by_its_full_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "sub").mkdir()
    shutil.copy(GOLDEN, tmp_path / "sub" / "a.mcap")
    monkeypatch.chdir(tmp_path)
    with open("sub/a.mcap", "r+b") as handle:
        handle.truncate(len(DATA) - 3)
    with pytest.raises(LogError) as info:
        read_info("sub/a.mcap")
    assert str(info.value).startswith(f"{tmp_path / 'sub' / 'a.mcap'}: damaged MCAP log")
