"""A lean MCAP writer for the logging hot path.

``mcap.writer.Writer`` builds a ``Message`` object and several small records per message, which
costs about 5 microseconds each in pure Python: more than a whole cube-stacking environment step.
This writer packs message records straight into a chunk buffer with one ``struct.pack`` call,
the header, schemas and channels with the ``mcap.records`` classes of the reference library (once
per process: they repeat from trial to trial), and everything else (chunks, message indexes,
metadata, the summary section and footer) with one ``struct.pack`` per record, byte for byte as
the reference library's writers do (a test reads a trial's log back and packs it again). Files
follow the same layout as ``mcap.writer.Writer`` output: indexed, zstd-compressed chunks, a
summary with schemas, channels, statistics, chunk and metadata indexes, summary offsets and CRCs.
"""

from __future__ import annotations

import functools
import struct
import sys
import threading
from array import array
from collections import defaultdict
from collections.abc import Sequence
from typing import IO, Any, NamedTuple

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Header, Schema
from mcap.well_known import MessageEncoding, SchemaEncoding

from lagrseq.logs.crc import crc32

MAGIC = b"\x89MCAP0\r\n"
_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log, publish time
_MESSAGE_FIXED = 2 + 4 + 8 + 8
_RESERVED = bytes(_MESSAGE.size)
"""Room for a message record's header, filled in once its data is encoded behind it."""
_OPCODE_MESSAGE = int(Opcode.MESSAGE)

__all__ = ["LeanWriter", "Mark", "MessageEncoding", "SchemaEncoding"]


def _offsets() -> array[int]:
    return array("Q")


_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, record length, start, end, size, crc, len("zstd")


def _chunk_head(start: int, end: int, raw_size: int, crc: int, compression: bytes, data_size: int) -> bytes:
    """A Chunk record up to its data (the same bytes as ``mcap.records.Chunk.write``), packed at
    once: the reference builder seeks and packs field by field, which costs more than a small
    chunk's compression. The data follows as it is (no copy of it is made)."""
    length = 8 + 8 + 8 + 4 + 4 + len(compression) + 8 + data_size
    head = _CHUNK_HEAD.pack(Opcode.CHUNK, length, start, end, raw_size, crc, len(compression))
    return head + compression + struct.pack("<Q", data_size)


def _chunk_record(start: int, end: int, raw_size: int, crc: int, compression: bytes, data: bytes) -> bytes:
    """A whole Chunk record (the same bytes as ``mcap.records.Chunk.write``)."""
    return _chunk_head(start, end, raw_size, crc, compression, len(data)) + data


def _chunk_index_record(
    start: int,
    end: int,
    chunk_offset: int,
    chunk_length: int,
    index_offsets: dict[int, int],
    index_length: int,
    compression: bytes,
    compressed_size: int,
    raw_size: int,
) -> bytes:
    """A ChunkIndex record (the same bytes as ``mcap.records.ChunkIndex.write``), packed at once."""
    offsets = b"".join(struct.pack("<HQ", channel, offset) for channel, offset in index_offsets.items())
    body = (
        struct.pack("<QQQQI", start, end, chunk_offset, chunk_length, len(offsets))
        + offsets
        + struct.pack("<QI", index_length, len(compression))
        + compression
        + struct.pack("<QQ", compressed_size, raw_size)
    )
    return struct.pack("<BQ", Opcode.CHUNK_INDEX, len(body)) + body


COMPRESSION_LEVEL = -1
"""zstd's fastest regular setting but one. Measured on a cube LaGR-SEQ trial's 199 chunks (8 KB
each, ``benchmarks/bench_cube.py``): level 1 took 13 ms a trial, -1 took 8 ms for 16% more bytes
(lz4: 4 ms for 84% more; zlib 1: 34 ms). Readers need nothing new: any level is zstd."""

_COMPRESSORS = threading.local()


def _compressor() -> zstandard.ZstdCompressor:
    """This thread's zstd compressor, made once: making one costs about 0.1 ms (its working
    memory), as much as compressing a trial's chunks; each ``compress`` is a frame of its own,
    so reusing it changes no byte. One per thread: a compressor is not safe to share between
    threads that compress at once (trials on a threaded executor)."""
    compressor = getattr(_COMPRESSORS, "zstd", None)
    if compressor is None:
        compressor = _COMPRESSORS.zstd = zstandard.ZstdCompressor(level=COMPRESSION_LEVEL)
    return compressor


_SMALL_CHUNK = 1024
"""Chunks smaller than this many bytes (an episode's summary messages) are stored uncompressed:
zstd saves a few bytes there and costs more than writing them."""


def _message_index(channel_id: int, flat: Sequence[int]) -> bytes:
    """A MessageIndex record (the same bytes as ``mcap.records.MessageIndex.write``) from the
    flat sequence log time, offset, log time, offset, ...; packed at once, not field by field."""
    if isinstance(flat, array) and sys.byteorder == "little":
        body = struct.pack("<HI", channel_id, 8 * len(flat)) + flat.tobytes()
    else:
        body = struct.pack(f"<HI{len(flat)}Q", channel_id, 8 * len(flat), *flat)
    return struct.pack("<BQ", Opcode.MESSAGE_INDEX, len(body)) + body


class Mark(NamedTuple):
    """Where a writer's open and held chunks stood (:meth:`LeanWriter.mark`): their sizes in
    bytes. What was added after it is found by its offset when it is rolled back, so a mark
    costs nothing to keep (the sink keeps one at every episode's end)."""

    size: int
    held: int = 0


class _OpenChunk:
    """A chunk being filled: its message records and, per channel, the flat sequence log time,
    offset, log time, offset, ... of its messages (their message index)."""

    __slots__ = ("data", "index")

    def __init__(self) -> None:
        self.data = bytearray()
        self.index: dict[int, array[int]] = defaultdict(_offsets)

    def rollback(self, size: int, counts: dict[int, int]) -> None:
        """Drop every message from offset ``size`` on, and its count in ``counts``."""
        del self.data[size:]
        for channel_id in list(self.index):
            entries = self.index[channel_id]
            kept = len(entries)
            while kept and entries[kept - 1] >= size:  # (log time, offset) pairs, in order
                kept -= 2
            counts[channel_id] -= (len(entries) - kept) // 2
            if not counts[channel_id]:  # first used after the mark: as if never used
                del counts[channel_id]
            if kept:
                del entries[kept:]
            else:
                del self.index[channel_id]


def _packed(record: Any) -> bytes:
    """A record as bytes, packed by ``mcap.records``."""
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


@functools.lru_cache(maxsize=64)
def _preamble_record(kind: type, **fields: Any) -> bytes:
    """A header, schema or channel record (``kind(**fields)``, a channel without metadata) as
    bytes, kept: every trial's file starts with the same few, and packing them field by field
    costs more than compressing a small chunk."""
    return _packed(kind(**fields, metadata={}) if kind is Channel else kind(**fields))


def _string(value: str) -> bytes:
    """An MCAP string: its UTF-8 length (uint32) and bytes."""
    data = value.encode()
    return struct.pack("<I", len(data)) + data


def _summary_record(opcode: int, body: bytes) -> bytes:
    """A record of the file's end (metadata, their index, statistics, summary offsets, footer)
    packed at once: the same bytes as ``mcap.records``' writers, which pack field by field
    through a seekable buffer and cost about as much as the rest of a small trial's closing."""
    return struct.pack("<BQ", opcode, len(body)) + body


def _metadata_record(name: str, data: dict[str, str]) -> bytes:
    """A Metadata record (``mcap.records.Metadata.write``'s bytes): name, then the map's byte
    length and its key, value strings in order."""
    pairs = b"".join(_string(key) + _string(value) for key, value in data.items())
    return _summary_record(Opcode.METADATA, _string(name) + struct.pack("<I", len(pairs)) + pairs)


class LeanWriter:
    """Write an indexed, chunked MCAP file. Messages go to one of two chunks being filled, the
    open one or the held one; ``flush()`` writes both, the open one first."""

    def __init__(self, stream: IO[bytes], library: str = "lagrseq", profile: str = "") -> None:
        self._stream = stream
        self._schemas: dict[int, bytes] = {}
        self._channels: dict[int, bytes] = {}
        """The packed schema and channel records by id (the summary repeats them)."""
        self._open = _OpenChunk()
        """The chunk being filled (a trial's transitions and pictures)."""
        self._held = _OpenChunk()
        """A second chunk being filled, written after the open one (a trial's queries and
        episode summaries, so that a reader of those alone never decompresses transitions)."""
        self._chunk_indexes: list[bytes] = []
        """ChunkIndex records, packed as each chunk is written."""
        self._metadata_indexes: list[bytes] = []
        """MetadataIndex records, packed as each metadata record is written."""
        self._counts: dict[int, int] = defaultdict(int)
        """Messages added so far per channel (each message's sequence number is its count), in
        the order the file first holds each channel: the held chunk is filled only as the open
        one is written, so the statistics record's counts keep the reference writer's order."""
        self._message_count = 0
        self._start_time = self._end_time = 0
        self._chunks = 0
        self._offset = 0
        self._write(MAGIC + _preamble_record(Header, profile=profile, library=library))

    # ------------------------------------------------------------------ low level
    def _write(self, data: bytes | bytearray) -> None:
        self._stream.write(data)
        self._offset += len(data)

    # ------------------------------------------------------------------ registration
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = len(self._schemas) + 1
        record = self._schemas[schema_id] = _preamble_record(Schema, id=schema_id, name=name, encoding=encoding, data=data)
        self._write(record)
        return schema_id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        channel_id = len(self._channels) + 1
        record = self._channels[channel_id] = _preamble_record(
            Channel, id=channel_id, topic=topic, message_encoding=message_encoding, schema_id=schema_id
        )
        self._write(record)
        return channel_id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        record = _metadata_record(name, data)
        self._metadata_indexes.append(
            _summary_record(Opcode.METADATA_INDEX, struct.pack("<QQ", self._offset, len(record)) + _string(name))
        )
        self._write(record)

    # ------------------------------------------------------------------ messages
    def add_message(
        self, channel_id: int, log_time: int, data: bytes, sequence: int | None = None, held: bool = False
    ) -> None:
        """Add one message to the open chunk (``held``: to the held chunk, which
        :meth:`flush` writes after it); ``sequence`` defaults to the channel's count of messages
        so far (what every lagrseq topic uses)."""
        chunk = self._held if held else self._open
        data_so_far = chunk.data
        counts = self._counts
        count = counts[channel_id]
        counts[channel_id] = count + 1
        chunk.index[channel_id].extend((log_time, len(data_so_far)))
        data_so_far += _MESSAGE.pack(
            Opcode.MESSAGE, _MESSAGE_FIXED + len(data), channel_id, count if sequence is None else sequence, log_time, log_time
        )
        data_so_far += data

    def append_encoded(self, channel_id: int, log_time: int, item: Any, encode_into: Any, held: bool = False) -> None:
        """Add one message whose data ``encode_into(item, buffer, -1)`` appends to ``buffer``
        (``msgspec.json.Encoder.encode_into``) to the open chunk (``held``: to the held one):
        the same bytes as :meth:`add_message` with the encoded data, but encoded straight into
        the chunk (no bytes object, no second copy). An item that cannot be encoded leaves the
        chunk as it was. The chunk's first and last log times and message count are worked out
        when it is written (from its message index), not kept up per message."""
        chunk = self._held if held else self._open
        data = chunk.data
        start = len(data)
        data += _RESERVED
        try:
            encode_into(item, data, -1)
        except BaseException:
            del data[start:]
            raise
        counts = self._counts
        count = counts[channel_id]
        _MESSAGE.pack_into(data, start, _OPCODE_MESSAGE, len(data) - start - 9, channel_id, count, log_time, log_time)
        counts[channel_id] = count + 1
        chunk.index[channel_id].extend((log_time, start))

    @property
    def chunk_size(self) -> int:
        """Bytes of message records in the open chunk (not the held one)."""
        return len(self._open.data)

    def mark(self) -> Mark:
        """Where the open and held chunks stand now, for :meth:`rollback`."""
        return Mark(len(self._open.data), len(self._held.data))

    def rollback(self, mark: Mark) -> None:
        """Drop every message added to the open and held chunks since ``mark`` was taken (no
        chunk may have been written in between): the chunks' bytes, their index entries (those
        at or past the mark's offsets) and their count."""
        self._open.rollback(mark.size, self._counts)
        self._held.rollback(mark.held, self._counts)

    @property
    def messages(self) -> int:
        """Messages added so far."""
        return sum(self._counts.values())

    def channel_counts(self) -> dict[int, int]:
        """Messages added so far per channel id."""
        return dict(self._counts)

    def flush(self, push: bool = True) -> None:
        """Write the open chunk, then the held chunk (each if it holds messages) and, with
        ``push``, hand the bytes to the operating system."""
        if self._open.data:
            self._finish_chunk(self._open)
            self._open = _OpenChunk()
        if self._held.data:
            self._finish_chunk(self._held)
            self._held = _OpenChunk()
        if push:
            self._stream.flush()

    def _finish_chunk(self, chunk: _OpenChunk) -> None:
        index = chunk.index
        chunk_start = min(min(entries[::2]) for entries in index.values())
        chunk_end = max(max(entries[::2]) for entries in index.values())
        chunk_messages = sum(len(entries) for entries in index.values()) // 2
        raw = chunk.data  # read in place: a copy of a large chunk costs fresh memory pages
        compression = b"" if len(raw) < _SMALL_CHUNK else b"zstd"
        compressed = _compressor().compress(raw) if compression else raw  # the running thread's
        head = _chunk_head(chunk_start, chunk_end, len(raw), crc32(raw), compression, len(compressed))
        chunk_offset, chunk_length = self._offset, len(head) + len(compressed)
        self._write(head + compressed)  # one write: a copy of the compressed data only
        offsets: dict[int, int] = {}
        pieces: list[bytes] = []
        position = self._offset
        for channel_id, records in index.items():
            offsets[channel_id] = position
            piece = _message_index(channel_id, records)
            pieces.append(piece)
            position += len(piece)
        index_data = b"".join(pieces)
        self._write(index_data)
        self._chunk_indexes.append(
            _chunk_index_record(
                chunk_start,
                chunk_end,
                chunk_offset,
                chunk_length,
                offsets,
                len(index_data),
                compression,
                len(compressed),
                len(raw),
            )
        )
        if self._message_count == 0:
            self._start_time = chunk_start
        else:
            self._start_time = min(self._start_time, chunk_start)
        self._end_time = max(self._end_time, chunk_end)
        self._message_count += chunk_messages
        self._chunks += 1

    # ------------------------------------------------------------------ end of file
    def finish(self) -> None:
        """Write the data end, the summary section, the footer and the closing magic."""
        self.flush(push=False)
        self._write(_summary_record(Opcode.DATA_END, struct.pack("<I", 0)))  # no data section CRC
        summary_start = self._offset
        counts = self._counts
        statistics = _summary_record(
            Opcode.STATISTICS,
            struct.pack(
                "<QHIIIIQQI", self._message_count, len(self._schemas), len(self._channels), 0,
                len(self._metadata_indexes), self._chunks, self._start_time, self._end_time, 10 * len(counts),
            )
            + b"".join(struct.pack("<HQ", channel, count) for channel, count in counts.items()),
        )
        groups = [
            (Opcode.SCHEMA, list(self._schemas.values())),
            (Opcode.CHANNEL, list(self._channels.values())),
            (Opcode.STATISTICS, [statistics]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.METADATA_INDEX, self._metadata_indexes),
        ]
        pieces: list[bytes] = []
        offsets: list[bytes] = []
        position = summary_start
        for opcode, records in groups:
            if records:
                group = b"".join(records)
                offsets.append(_summary_record(Opcode.SUMMARY_OFFSET, struct.pack("<BQQ", opcode, position, len(group))))
                pieces.append(group)
                position += len(group)
        summary_offset_start = position
        summary = b"".join(pieces + offsets)
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start)
        crc = crc32(footer_head, crc32(summary))
        self._write(summary + footer_head + struct.pack("<I", crc) + MAGIC)
        self._stream.flush()
