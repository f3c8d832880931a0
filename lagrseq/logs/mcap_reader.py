"""Checked MCAP reading: every length and offset is validated before anything is allocated.

The ``mcap`` library trusts the lengths a file states: one flipped bit in a chunk's length or
uncompressed size makes it ask for exabytes (``MemoryError``), an offset past the end of the file
makes it read garbage. A log is a file from outside, so this module reads it defensively:

- a record's length must fit in what is left of the file (or of its section) before its body is
  read, so no read is ever longer than the file;
- fields inside a record are read from that record's bytes only, and a field that runs past its
  record is damage (never a short read taken at face value);
- a chunk's uncompressed size is capped (:data:`MAX_CHUNK_BYTES`), and the chunk is decompressed
  in pieces of at most :data:`_PIECE` bytes, stopping as soon as more comes out than the chunk
  says it holds, so memory follows what the data really holds, not what a field claims;
- the summary is checked against its CRC and every index in it against the file's layout;
- a walk through records stops at the first byte that cannot start one: opcode 0x00 is no MCAP
  record (zeros are what a crash or a preallocating copy leaves), a chunk holds only schemas,
  channels and messages, and at most :data:`MAX_UNKNOWN_RECORDS` records of kinds this reader does
  not know are skipped. Small valid records are bounded too: message indexes only after their
  chunk and at most :data:`MAX_MESSAGE_INDEXES_PER_CHUNK` of them, one statistics record, no more
  chunk (metadata, attachment) indexes than chunks (metadata, attachments), at most
  :data:`MAX_DEFINITIONS` metadata, schema, channel or attachment records of each kind, and at
  most :data:`MAX_SCAN_RECORDS` records outside chunks in all. A run of zeros is measured with ``bytes`` operations in C (at memory or
  disk speed, never record by record, and at most :data:`MAX_ZERO_SCAN` bytes of it), so a log
  padded with hundreds of megabytes of zeros is judged in well under a second
  (``benchmarks/bench_scan.py``).

What is wrong is raised as :class:`Damage` (an offset and what was found there); the public
readers in :mod:`lagrseq.logs.reader` turn it into a one-line :class:`~lagrseq.errors.LogError`.
Records are decoded with the ``mcap.records`` classes of the reference library.
"""

from __future__ import annotations

import io
import struct
import threading
from collections.abc import Container, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from lagrseq.errors import LogError  # noqa: E402
from lagrseq.logs.crc import crc32  # noqa: E402
from lagrseq.logs.mcap_writer import MAGIC  # noqa: E402 - one definition of the file magic
from lagrseq.paths import open_input  # noqa: E402

MAX_CHUNK_BYTES = 1 << 30
"""The largest uncompressed chunk read (1 GiB). A lagrseq chunk holds one episode's transitions
(or its queries and summary): a few megabytes at most; a bigger size is a damaged field."""
_PIECE = 1 << 20
WHOLE_FILE_BYTES = 64 << 20
"""A file up to this size is read into memory with one read on first use, and every later read
is a slice of it (a log is read in hundreds of small reads: a chunk's head and body, every chunk
index's check; one system call each cost more than all of them from memory). A bigger file is
read piece by piece as asked. Either way, reading a log costs at most its own size in memory."""
MAX_UNKNOWN_RECORDS = 1024
"""Records of a kind this reader does not know (private opcodes 0x80-0xff, kinds of later MCAP
versions) skipped in one walk; lagrseq writes none, so more is damage, not data (a flood of
9-byte unknown records would otherwise be walked one Python step each)."""
MAX_MESSAGE_INDEXES_PER_CHUNK = 64
"""Message index records after one chunk: the writer puts one per channel with messages in the
chunk right after it, and a lagrseq log has about ten channels. More, or one that follows no
chunk, is damage (a flood of 15-byte index records would otherwise be walked one Python step each)."""
MAX_DEFINITIONS = 1024
"""Metadata, schema, channel and attachment records, of each kind, outside chunks: a lagrseq log
writes three metadata records, about ten schemas and channels (twice: in the data section and
again in the summary) and no attachment. More is a flood (recover would keep every one)."""
MAX_SCAN_RECORDS = 1 << 20
"""Records walked outside chunks in one scan (1,048,576: about 4 s of Python steps). A lagrseq log
holds about seven per episode (its chunks, their message and chunk indexes), so this is over
100,000 episodes; more is a flood of small valid records, judged as damage where the walk
stands (what came before it is kept)."""
MAX_ZERO_SCAN = 1 << 30
"""The most bytes of a run of zeros measured to say how far it goes (1 GiB, about half a second);
a longer run is reported as "at least" that much."""
_ZERO_PIECE = 8 << 20
_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")
_FOOTER_LENGTH = 20
_FOOTER_RECORD = 9 + _FOOTER_LENGTH
_HEADER_MIN = 9 + 8  # a Header record with two empty strings
_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, length, start, end, uncompressed size, crc, len(compression)
_MAX_COMPRESSION_NAME = 64

_RECORDS: dict[int, Any] = {
    Opcode.ATTACHMENT: Attachment,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex,
    Opcode.CHANNEL: Channel,
    Opcode.CHUNK: Chunk,
    Opcode.CHUNK_INDEX: ChunkIndex,
    Opcode.DATA_END: DataEnd,
    Opcode.FOOTER: Footer,
    Opcode.HEADER: Header,
    Opcode.MESSAGE_INDEX: MessageIndex,
    Opcode.METADATA: Metadata,
    Opcode.METADATA_INDEX: MetadataIndex,
    Opcode.SCHEMA: Schema,
    Opcode.STATISTICS: Statistics,
    Opcode.SUMMARY_OFFSET: SummaryOffset,
}


def opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower().replace("_", " ")
    except ValueError:
        return f"unknown record (opcode {opcode:#04x})"


class Damage(Exception):
    """The file is not what an MCAP log must be at byte ``offset``."""

    def __init__(self, offset: int, what: str) -> None:
        super().__init__(f"{what} at byte {offset}")
        self.offset = offset
        self.what = what


def _zero_run(data: memoryview) -> int:
    """How many zero bytes ``data`` starts with (at most :data:`MAX_ZERO_SCAN`), in pieces of
    :data:`_ZERO_PIECE` bytes so that no more than one piece is copied at a time."""
    run = 0
    while run < min(len(data), MAX_ZERO_SCAN):
        piece = bytes(data[run : run + _ZERO_PIECE])
        zeros = len(piece) - len(piece.lstrip(b"\0"))
        run += zeros
        if zeros < len(piece):
            break
    return min(run, MAX_ZERO_SCAN)


def _zeros_found(run: int, left: int, end: str) -> str:
    """The damage text for ``run`` zero bytes where a record should start (``left`` bytes to
    ``end``)."""
    if run >= left:
        where = f"{run} zero bytes from here to {end}"
    elif run >= MAX_ZERO_SCAN:
        where = f"at least {run} zero bytes (measured no further)"
    else:
        where = f"{run} zero bytes, then other bytes again at {run} bytes further"
    return f"no record where one should start: {where} (zeros are no MCAP record: padding, or space a crash never wrote)"


def _not_in_chunk(opcode: int, data: bytes, pos: int, offset: int) -> Damage:
    """The damage for a record a chunk cannot hold (found at ``pos`` of the chunk at ``offset``)."""
    if opcode == 0:
        text = _zeros_found(_zero_run(memoryview(data)[pos:]), len(data) - pos, "the end of the chunk's data")
        return Damage(offset, f"chunk (at {pos} of {len(data)}): {text}")
    return Damage(offset, f"chunk: a {opcode_name(opcode)} record at {pos} of {len(data)}; a chunk holds schemas, channels and messages only")


class _Fields(ReadDataStream):
    """Reads the fields of one record from its bytes; a field running past them is damage."""

    def __init__(self, body: bytes, offset: int, kind: str) -> None:
        super().__init__(io.BytesIO(body))
        self._size = len(body)
        self._offset = offset
        self._kind = kind

    def read(self, length: int) -> bytes:
        if length < 0 or length > self._size - self._count:
            raise Damage(
                self._offset,
                f"{self._kind} record: a field of {length} bytes runs past the record "
                f"({self._size - self._count} bytes left)",
            )
        data = self._stream.read(length)
        self._count += len(data)
        return data


_INDEX_HEAD = struct.Struct("<QQQQI")
_INDEX_ENTRY = struct.Struct("<HQ")
_U32 = struct.Struct("<I")
_U16 = struct.Struct("<H")
_U64_PAIR = struct.Struct("<QQ")


def _chunk_index(body: bytes) -> ChunkIndex | None:
    """A well-formed ChunkIndex body decoded with a few ``struct`` calls (the reference reader
    takes one call per field; a log has two chunk indexes per episode, and replay reads every
    log's summary). ``None`` when anything does not fit: :func:`parse` then reads it field by
    field and says what is wrong."""
    size = len(body)
    if size < _INDEX_HEAD.size:
        return None
    start, end, chunk_start, chunk_length, offsets_length = _INDEX_HEAD.unpack_from(body, 0)
    pos = _INDEX_HEAD.size
    if offsets_length % _INDEX_ENTRY.size or pos + offsets_length + 12 > size:
        return None
    offsets = dict(_INDEX_ENTRY.iter_unpack(body[pos : pos + offsets_length]))
    pos += offsets_length
    (index_length,) = struct.unpack_from("<Q", body, pos)
    (name_length,) = _U32.unpack_from(body, pos + 8)
    pos += 12
    if pos + name_length + 16 > size:
        return None
    try:
        compression = body[pos : pos + name_length].decode()
    except UnicodeDecodeError:
        return None
    compressed_size, uncompressed_size = _U64_PAIR.unpack_from(body, pos + name_length)
    return ChunkIndex(
        message_index_offsets=offsets,
        chunk_start_offset=chunk_start,
        chunk_length=chunk_length,
        compression=compression,
        compressed_size=compressed_size,
        message_end_time=end,
        message_index_length=index_length,
        message_start_time=start,
        uncompressed_size=uncompressed_size,
    )


_CHUNK_BODY = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, len(compression)


def _chunk(body: bytes) -> Chunk | None:
    """A well-formed Chunk body decoded with two ``struct`` calls (the reference reader takes one
    call per field, and replay reads a chunk or two per episode); ``None`` when anything does not
    fit exactly: :func:`parse` then reads it field by field and says what is wrong."""
    size = len(body)
    if size < _CHUNK_BODY.size:
        return None
    start, end, uncompressed_size, crc, name_length = _CHUNK_BODY.unpack_from(body, 0)
    pos = _CHUNK_BODY.size + name_length
    if pos + 8 > size:
        return None
    try:
        compression = body[_CHUNK_BODY.size : pos].decode()
    except UnicodeDecodeError:
        return None
    (data_length,) = struct.unpack_from("<Q", body, pos)
    if data_length != size - pos - 8:
        return None
    return Chunk(
        compression=compression,
        data=body[pos + 8 :],
        message_end_time=end,
        message_start_time=start,
        uncompressed_crc=crc,
        uncompressed_size=uncompressed_size,
    )


def parse(opcode: int, body: bytes, offset: int) -> McapRecord | None:
    """Decode one record body (``None`` for an opcode this reader does not know)."""
    if opcode == Opcode.CHUNK_INDEX:
        fast = _chunk_index(body)
        if fast is not None:
            return fast
    elif opcode == Opcode.CHUNK:
        chunk = _chunk(body)
        if chunk is not None:
            return chunk
    kind = opcode_name(opcode)
    stream = _Fields(body, offset, kind)
    try:
        if opcode == Opcode.MESSAGE:
            return Message.read(stream, len(body))
        cls = _RECORDS.get(opcode)
        return None if cls is None else cls.read(stream)
    except (struct.error, UnicodeDecodeError, ValueError, OverflowError) as exc:
        raise Damage(offset, f"{kind} record unreadable ({type(exc).__name__}: {exc})") from None


@dataclass
class Summary:
    """The summary section of a checked file."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    statistics: Statistics | None = None
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    attachment_indexes: list[AttachmentIndex] = field(default_factory=list)


_LOCAL = threading.local()


def _zstd() -> Any:
    """This thread's zstd decompressor, made once: making one costs more than decompressing a
    typical chunk of a log (about 20 against 6 microseconds); one object may decompress many
    inputs, one at a time."""
    try:
        return _LOCAL.zstd
    except AttributeError:
        import zstandard

        _LOCAL.zstd = zstandard.ZstdDecompressor()
        return _LOCAL.zstd


def _decompress(compression: str, data: bytes, size: int, offset: int) -> bytes:
    """``data`` decompressed, which must give exactly ``size`` bytes; never more is produced."""
    if size > MAX_CHUNK_BYTES:
        raise Damage(
            offset,
            f"chunk says it holds {size} bytes uncompressed, more than the "
            f"{MAX_CHUNK_BYTES} any lagrseq chunk can hold",
        )
    if compression == "":
        out = data
    elif compression == "zstd":
        import zstandard

        pieces: list[bytes] = []
        total = 0
        try:
            reader = _zstd().stream_reader(data, read_across_frames=True)
            while total <= size:
                piece = reader.read(min(_PIECE, size + 1 - total))
                if not piece:
                    break
                pieces.append(piece)
                total += len(piece)
        except zstandard.ZstdError as exc:
            raise Damage(offset, f"chunk data is not valid zstd ({exc})") from None
        out = b"".join(pieces)
    elif compression == "lz4":
        try:
            import lz4.frame
        except ImportError:  # pragma: no cover - lagrseq writes zstd
            raise Damage(offset, "chunk is lz4-compressed and the lz4 package is missing") from None
        decompressor = lz4.frame.LZ4FrameDecompressor()
        pieces = []
        total = 0
        try:
            rest = data
            while total <= size:
                piece = decompressor.decompress(rest, max_length=min(_PIECE, size + 1 - total))
                rest = b""
                if not piece:
                    break
                pieces.append(piece)
                total += len(piece)
        except RuntimeError as exc:
            raise Damage(offset, f"chunk data is not valid lz4 ({exc})") from None
        out = b"".join(pieces)
    else:
        raise Damage(offset, f"chunk compression {compression[:40]!r} is not one MCAP knows")
    if len(out) != size:
        more = "more than" if len(out) > size else f"{len(out)} bytes, not"
        raise Damage(offset, f"chunk decompresses to {more} the {size} bytes it says it holds")
    return out


class _Counts:
    """The bounds of :meth:`McapFile.scan` on records outside chunks, checked before a record is
    parsed: a flood of small valid records (message indexes, chunk indexes, statistics, summary
    offsets: 15 to 60 bytes each, about 3.5 microseconds of Python each) is refused at the first
    record no lagrseq log holds in such numbers or in such a place, and any walk stops after
    :data:`MAX_SCAN_RECORDS` records."""

    def __init__(self) -> None:
        self.records = 0
        self.by_opcode: dict[int, int] = {}
        self.previous = 0
        self.run = 0  # message indexes since the last chunk

    def check(self, opcode: int, offset: int) -> None:
        self.records += 1
        if self.records > MAX_SCAN_RECORDS:
            raise Damage(
                offset,
                f"more than {MAX_SCAN_RECORDS} records outside chunks (a lagrseq log holds about 7 an episode); "
                "a flood of small records: not a lagrseq log, or damaged",
            )
        seen = self.by_opcode.get(opcode, 0) + 1
        self.by_opcode[opcode] = seen
        if opcode == Opcode.MESSAGE_INDEX:
            self.run = 1 if self.previous == Opcode.CHUNK else self.run + 1 if self.previous == Opcode.MESSAGE_INDEX else 0
            if self.run == 0:
                raise Damage(offset, f"a message index record after a {opcode_name(self.previous)} record, not after its chunk; damaged")
            if self.run > MAX_MESSAGE_INDEXES_PER_CHUNK:
                raise Damage(
                    offset,
                    f"more than {MAX_MESSAGE_INDEXES_PER_CHUNK} message index records after one chunk "
                    "(one per channel; a lagrseq log has about ten); a flood of small records: damaged",
                )
        else:
            limit = self._limit(opcode)
            if limit is not None and seen > limit:
                raise Damage(
                    offset,
                    f"{opcode_name(opcode)} record number {seen}, more than the file can hold ({limit}: "
                    f"{self._why(opcode)}); a flood of small records: damaged",
                )
        self.previous = opcode

    def _limit(self, opcode: int) -> int | None:
        if opcode == Opcode.STATISTICS:
            return 1
        if opcode == Opcode.CHUNK_INDEX:
            return self.by_opcode.get(Opcode.CHUNK, 0)
        if opcode == Opcode.METADATA_INDEX:
            return self.by_opcode.get(Opcode.METADATA, 0)
        if opcode == Opcode.ATTACHMENT_INDEX:
            return self.by_opcode.get(Opcode.ATTACHMENT, 0)
        if opcode == Opcode.SUMMARY_OFFSET:
            return 256
        if opcode in (Opcode.METADATA, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.ATTACHMENT):
            return MAX_DEFINITIONS
        return None

    @staticmethod
    def _why(opcode: int) -> str:
        why: dict[int, str] = {
            Opcode.STATISTICS: "one per file",
            Opcode.CHUNK_INDEX: "one per chunk before it",
            Opcode.METADATA_INDEX: "one per metadata record before it",
            Opcode.ATTACHMENT_INDEX: "one per attachment before it",
            Opcode.SUMMARY_OFFSET: "one per record kind",
        }
        return why.get(opcode, "a lagrseq log writes a handful")


class McapFile:
    """An MCAP file opened for checked reading (a context manager)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._handle = open_input(self.path, "log", LogError)
        try:
            self.size = int(self._handle.seek(0, io.SEEK_END))
        except OSError:
            self._handle.close()
            raise
        self._footer: tuple[Footer, int] | None = None
        self._summary: Summary | None = None
        self._data: bytes | None = None
        self._whole = self.size <= WHOLE_FILE_BYTES
        self._heads: dict[int, tuple[ChunkIndex, int, int]] = {}
        """Chunk offset -> (its checked index, its CRC, where its data starts)."""

    def __enter__(self) -> McapFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._handle.close()

    # ------------------------------------------------------------------ raw reads
    def read(self, offset: int, length: int, what: str = "data") -> bytes:
        """``length`` bytes at ``offset``; both are checked against the file size first."""
        if offset < 0 or length < 0 or offset + length > self.size:
            raise Damage(
                offset,
                f"{what} of {length} bytes runs past the end of the file ({self.size} bytes)",
            )
        if self._whole:
            if self._data is None:
                self._handle.seek(0)
                whole = self._handle.read(self.size)
                self._whole = len(whole) == self.size  # it shrank: read as asked, and say so below
                if self._whole:
                    self._data = whole
            if self._data is not None:
                return self._data[offset : offset + length]
        self._handle.seek(offset)
        data = self._handle.read(length)
        if len(data) != length:
            raise Damage(offset, f"the file shrank while it was read ({what})")
        return data

    def record_at(self, offset: int, limit: int | None = None) -> tuple[int, bytes, int]:
        """``(opcode, body, end)`` of the record at ``offset``, which must end by ``limit``
        (default: the end of the file)."""
        limit = self.size if limit is None else min(limit, self.size)
        if offset + 9 > limit:
            raise Damage(offset, f"a record header runs past byte {limit}")
        opcode, length = _HEAD.unpack(self.read(offset, 9, "record header"))
        if length > limit - offset - 9:
            where = "the end of the file" if limit == self.size else f"its section (byte {limit})"
            raise Damage(
                offset,
                f"{opcode_name(opcode)} record of {length} bytes runs past {where}",
            )
        return opcode, self.read(offset + 9, length, opcode_name(opcode)), offset + 9 + length

    def parse_at(self, offset: int, opcode: int, limit: int | None = None) -> tuple[Any, int]:
        """The record at ``offset``, which must have ``opcode``; returns it and its end."""
        found, body, end = self.record_at(offset, limit)
        if found != opcode:
            raise Damage(
                offset, f"expected a {opcode_name(opcode)} record, found {opcode_name(found)}"
            )
        return parse(found, body, offset), end

    # ------------------------------------------------------------------ structure
    def header(self) -> Header:
        if self.read(0, len(MAGIC), "magic") != MAGIC:
            raise Damage(0, "no MCAP magic at the start")
        header, _ = self.parse_at(len(MAGIC), Opcode.HEADER)
        return header  # type: ignore[no-any-return]

    def footer(self) -> tuple[Footer, int]:
        """The footer and its offset; the file must end with the footer and the magic."""
        if self._footer is not None:
            return self._footer
        minimum = 2 * len(MAGIC) + _HEADER_MIN + _FOOTER_RECORD
        if self.size < minimum:
            raise Damage(0, f"{self.size} bytes is too short for a finished MCAP file")
        if self.read(0, len(MAGIC), "magic") != MAGIC:
            raise Damage(0, "no MCAP magic at the start")
        end = self.size - len(MAGIC)
        if self.read(end, len(MAGIC), "magic") != MAGIC:
            raise Damage(end, "no MCAP magic at the end (cut short, or bytes appended)")
        start = end - _FOOTER_RECORD
        footer, _ = self.parse_at(start, Opcode.FOOTER, limit=end)
        if footer.summary_start and not len(MAGIC) + _HEADER_MIN <= footer.summary_start <= start:
            raise Damage(start, f"footer: summary start {footer.summary_start} is outside the file")
        if footer.summary_offset_start and not (
            footer.summary_start <= footer.summary_offset_start <= start
        ):
            raise Damage(
                start, f"footer: summary offsets start {footer.summary_offset_start} is outside the summary"
            )
        self._footer = (footer, start)
        return self._footer

    def summary(self) -> Summary | None:
        """The summary section (``None`` when the file has none), checked: CRC, and every
        index pointing where a record of its kind can be."""
        if self._summary is not None:
            return self._summary
        footer, footer_start = self.footer()
        if footer.summary_start == 0:
            return None
        start = footer.summary_start
        section = self.read(start, footer_start - start, "summary section")
        if footer.summary_crc:
            crc = crc32(self.read(footer_start, 1 + 8 + 16, "footer"), crc32(section))
            if crc != footer.summary_crc:
                raise Damage(start, f"summary CRC mismatch (stored {footer.summary_crc}, computed {crc})")
        summary = Summary()
        for offset, opcode, record in self._records_in(section, start):
            if isinstance(record, ChunkIndex):  # most of a summary: two per episode
                self._check_chunk_index(record, offset, start)
                summary.chunk_indexes.append(record)
            elif isinstance(record, Schema):
                summary.schemas[record.id] = record
            elif isinstance(record, Channel):
                summary.channels[record.id] = record
            elif isinstance(record, Statistics):
                summary.statistics = record
            elif isinstance(record, MetadataIndex):
                self._check_span(record.offset, record.length, start, offset, "metadata index")
                summary.metadata_indexes.append(record)
            elif isinstance(record, AttachmentIndex):
                self._check_span(record.offset, record.length, start, offset, "attachment index")
                summary.attachment_indexes.append(record)
            elif opcode in (Opcode.HEADER, Opcode.FOOTER, Opcode.CHUNK, Opcode.MESSAGE):
                raise Damage(offset, f"a {opcode_name(opcode)} record inside the summary")
        for cid, channel in summary.channels.items():
            if channel.schema_id and channel.schema_id not in summary.schemas:
                raise Damage(start, f"channel {cid} names schema {channel.schema_id}, which is not in the summary")
        for index in summary.chunk_indexes:
            unknown = index.message_index_offsets.keys() - summary.channels.keys()
            if unknown:
                raise Damage(
                    index.chunk_start_offset, f"chunk index names unknown channels {sorted(unknown)}"
                )
            self._check_chunk_head(index)
        self._summary = summary
        return summary

    def _records_in(self, data: bytes, base: int) -> Iterator[tuple[int, int, McapRecord | None]]:
        """``(offset, opcode, record)`` for the records packed in ``data`` (found at ``base``)."""
        pos = 0
        while pos < len(data):
            if pos + 9 > len(data):
                raise Damage(base + pos, f"a record header runs past its section ({len(data) - pos} bytes left)")
            opcode, length = _HEAD.unpack_from(data, pos)
            if opcode == 0:
                raise Damage(base + pos, _zeros_found(_zero_run(memoryview(data)[pos:]), len(data) - pos, "its section"))
            if length > len(data) - pos - 9:
                raise Damage(base + pos, f"{opcode_name(opcode)} record of {length} bytes runs past its section")
            yield base + pos, opcode, parse(opcode, data[pos + 9 : pos + 9 + length], base + pos)
            pos += 9 + length

    def _check_span(self, offset: int, length: int, end: int, where: int, what: str) -> None:
        if not (len(MAGIC) <= offset and length >= 9 and offset + length <= end):
            raise Damage(
                where,
                f"{what} points at bytes {offset}..{offset + length}, outside the data section (0..{end})",
            )

    def _check_chunk_index(self, index: ChunkIndex, where: int, end: int) -> None:
        self._check_span(index.chunk_start_offset, index.chunk_length, end, where, "chunk index")
        after = index.chunk_start_offset + index.chunk_length
        for channel, offset in index.message_index_offsets.items():
            if not after <= offset < after + index.message_index_length or offset >= end:
                raise Damage(where, f"chunk index: message index of channel {channel} at {offset} is outside the chunk's indexes")
        if index.compressed_size > index.chunk_length:
            raise Damage(where, f"chunk index: compressed size {index.compressed_size} is larger than the chunk ({index.chunk_length} bytes)")
        if index.uncompressed_size > MAX_CHUNK_BYTES:
            raise Damage(where, f"chunk index: uncompressed size {index.uncompressed_size} is over the {MAX_CHUNK_BYTES}-byte cap")

    def _check_chunk_head(self, index: ChunkIndex) -> None:
        """The fixed fields of the chunk ``index`` points at agree with the index (a few dozen
        bytes read, nothing decompressed): a damaged length or size in any chunk is found by
        every reader, also in chunks a reader never opens (replay skips the transitions)."""
        at = index.chunk_start_offset
        if index.chunk_length < _CHUNK_HEAD.size + 8:
            raise Damage(at, f"chunk index: a chunk of {index.chunk_length} bytes is shorter than a chunk's fixed fields")
        opcode, length, start, end, size, _crc, name_length = _CHUNK_HEAD.unpack(self.read(at, _CHUNK_HEAD.size, "chunk header"))
        if opcode != Opcode.CHUNK:
            raise Damage(at, f"expected a chunk record, found {opcode_name(opcode)}")
        if length != index.chunk_length - 9:
            raise Damage(at, f"chunk record says it is {length + 9} bytes, its index says {index.chunk_length}")
        if name_length > _MAX_COMPRESSION_NAME or _CHUNK_HEAD.size + name_length + 8 > index.chunk_length:
            raise Damage(at, f"chunk record: a compression name of {name_length} bytes runs past its fixed fields")
        tail = self.read(at + _CHUNK_HEAD.size, name_length + 8, "chunk header")
        data_length = struct.unpack_from("<Q", tail, name_length)[0]
        if data_length != index.chunk_length - _CHUNK_HEAD.size - name_length - 8:
            raise Damage(at, f"chunk record: its data of {data_length} bytes does not fill the {index.chunk_length}-byte chunk")
        if (size, start, end) != (index.uncompressed_size, index.message_start_time, index.message_end_time):
            raise Damage(at, "chunk record: its size or times differ from its index's")
        if data_length != index.compressed_size or tail[:name_length] != index.compression.encode():
            raise Damage(at, "chunk record: its compressed size or compression differs from its index's")
        self._heads[at] = (index, _crc, at + _CHUNK_HEAD.size + name_length + 8)

    # ------------------------------------------------------------------ content
    def metadata(self) -> list[Metadata]:
        """The metadata records, through the summary's index (a linear scan when the file has
        no summary)."""
        summary = self.summary()
        if summary is None:
            return [r for _, _, r in self.scan() if isinstance(r, Metadata)]
        found = []
        for index in summary.metadata_indexes:
            record, end = self.parse_at(index.offset, Opcode.METADATA)
            if end - index.offset != index.length:
                raise Damage(index.offset, f"metadata record is {end - index.offset} bytes, its index says {index.length}")
            found.append(record)
        return found

    def chunk(self, index: ChunkIndex) -> Chunk:
        """The chunk an index points at (its length must be the index's)."""
        head = self._heads.get(index.chunk_start_offset)
        if head is not None and head[0] is index and self._data is not None:
            # every field of this chunk's record was checked against ``index`` (_check_chunk_head)
            # in the bytes read into memory: the record is the index's fields, its CRC and its data
            _, crc, begin = head
            return Chunk(
                compression=index.compression,
                data=self._data[begin : index.chunk_start_offset + index.chunk_length],
                message_end_time=index.message_end_time,
                message_start_time=index.message_start_time,
                uncompressed_crc=crc,
                uncompressed_size=index.uncompressed_size,
            )
        chunk, end = self.parse_at(index.chunk_start_offset, Opcode.CHUNK)
        if end - index.chunk_start_offset != index.chunk_length:
            raise Damage(
                index.chunk_start_offset,
                f"chunk record is {end - index.chunk_start_offset} bytes, its index says {index.chunk_length}",
            )
        return chunk  # type: ignore[no-any-return]

    @staticmethod
    def chunk_data(chunk: Chunk, offset: int) -> bytes:
        """The records of ``chunk`` (found at ``offset``) decompressed, CRC checked."""
        data = _decompress(chunk.compression, chunk.data, chunk.uncompressed_size, offset)
        if chunk.uncompressed_crc and crc32(data) != chunk.uncompressed_crc:
            raise Damage(offset, f"chunk CRC mismatch (stored {chunk.uncompressed_crc}, computed {crc32(data)})")
        return data

    def chunk_messages(self, chunk: Chunk, offset: int, channels: Container[int]) -> list[tuple[int, bytes]]:
        """``(channel id, data)`` of the messages of ``channels`` in ``chunk``, in order: the
        same checks as :meth:`chunk_records` (which it agrees with), without making a record
        object for each message."""
        data = self.chunk_data(chunk, offset)
        found: list[tuple[int, bytes]] = []
        unpack_head, unpack_channel, message, head = _HEAD.unpack_from, _U16.unpack_from, Opcode.MESSAGE, _MESSAGE_HEAD.size
        pos, size = 0, len(data)
        while pos < size:
            if pos + 9 > size:
                raise Damage(offset, f"chunk: a record header runs past the chunk's data (at {pos} of {size})")
            opcode, length = unpack_head(data, pos)
            end = pos + 9 + length
            if end > size:
                raise Damage(offset, f"chunk: {opcode_name(opcode)} record of {length} bytes runs past the chunk's data (at {pos} of {size})")
            if opcode == message:
                if length < head:
                    raise Damage(offset, f"chunk: message record of {length} bytes is shorter than its fixed fields")
                (channel_id,) = unpack_channel(data, pos + 9)
                if channel_id in channels:
                    found.append((channel_id, data[pos + 9 + head : end]))
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                parse(opcode, data[pos + 9 : end], offset)
            else:
                raise _not_in_chunk(opcode, data, pos, offset)
            pos = end
        return found

    def chunk_records(self, chunk: Chunk, offset: int) -> list[McapRecord]:
        """Schemas, channels and messages in ``chunk`` (found at ``offset``), CRC checked."""
        data = self.chunk_data(chunk, offset)
        records: list[McapRecord] = []
        pos, size = 0, len(data)
        while pos < size:
            if pos + 9 > size:
                raise Damage(offset, f"chunk: a record header runs past the chunk's data (at {pos} of {size})")
            opcode, length = _HEAD.unpack_from(data, pos)
            if length > size - pos - 9:
                raise Damage(offset, f"chunk: {opcode_name(opcode)} record of {length} bytes runs past the chunk's data (at {pos} of {size})")
            if opcode == Opcode.MESSAGE:
                if length < _MESSAGE_HEAD.size:
                    raise Damage(offset, f"chunk: message record of {length} bytes is shorter than its fixed fields")
                channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(data, pos + 9)
                start = pos + 9 + _MESSAGE_HEAD.size
                records.append(
                    Message(
                        channel_id=channel_id,
                        log_time=log_time,
                        data=data[start : pos + 9 + length],
                        publish_time=publish_time,
                        sequence=sequence,
                    )
                )
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                record = parse(opcode, data[pos + 9 : pos + 9 + length], offset)
                assert record is not None
                records.append(record)
            else:
                raise _not_in_chunk(opcode, data, pos, offset)
            pos += 9 + length
        return records

    def scan(self) -> Iterator[tuple[int, int, McapRecord | None]]:
        """``(offset, end, record)`` for every record from the header on, in file order, up to
        and including the footer (chunks are yielded whole, not opened). Raises :class:`Damage`
        where a record cannot be read."""
        self.header()
        offset = len(MAGIC)
        unknown = 0
        counts = _Counts()
        while True:
            opcode, body, end = self.record_at(offset)
            if opcode == 0:  # no record: zeros (measured in C, never walked 9 bytes at a time)
                raise Damage(offset, _zeros_found(self.zero_run(offset), self.size - offset, "the end of the file"))
            counts.check(opcode, offset)
            record = parse(opcode, body, offset)
            if record is None:
                unknown += 1
                if unknown > MAX_UNKNOWN_RECORDS:
                    raise Damage(
                        offset,
                        f"more than {MAX_UNKNOWN_RECORDS} records of kinds no lagrseq log holds "
                        f"(this one: {opcode_name(opcode)}); not a lagrseq log, or damaged",
                    )
            yield offset, end, record
            if isinstance(record, Footer):
                if self.read(end, len(MAGIC), "closing magic") != MAGIC:
                    raise Damage(end, "no MCAP magic after the footer")
                return
            offset = end

    def zero_run(self, offset: int) -> int:
        """How many zero bytes follow ``offset`` (at most :data:`MAX_ZERO_SCAN`), measured a
        piece at a time in C, never record by record."""
        if self._data is not None:
            return _zero_run(memoryview(self._data)[offset:])
        run = 0
        self._handle.seek(offset)
        while run < MAX_ZERO_SCAN:
            piece = self._handle.read(min(_ZERO_PIECE, MAX_ZERO_SCAN - run))
            if not piece:
                break
            zeros = len(piece) - len(piece.lstrip(b"\0"))
            run += zeros
            if zeros < len(piece):
                break
        return run

    def verify(self) -> Summary:
        """Read everything a reader can ask for: footer, summary, metadata and every chunk.
        Raises :class:`Damage` at the first thing that cannot be read."""
        summary = self.summary()
        if summary is None:
            raise Damage(self.footer()[1], "the file has no summary section")
        self.metadata()
        for index in summary.chunk_indexes:
            self.chunk_records(self.chunk(index), index.chunk_start_offset)
        return summary
