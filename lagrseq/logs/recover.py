"""Recover a crash-truncated MCAP log: keep everything up to the last episode flush.

A trial killed mid-run (SIGKILL, power cut, out of memory) leaves ``NAME.mcap.partial``: a valid
MCAP data section cut off somewhere after its last complete record, with no summary and no footer.
The sink closes a chunk at every episode end and writes that episode's ``/query`` and ``/episode``
messages as a chunk of their own (see :mod:`lagrseq.logs.sink`), so the file holds every finished
episode. Recovery reads records in order with ``mcap.stream_reader.StreamReader`` until the first
record that cannot be read, keeps the messages up to the end of the last flushed episode, and
writes them with a fresh ``Writer`` (same schemas, channels, metadata and chunk boundaries), plus a
``lagrseq.status`` record saying ``recovered``.

A truncated file and a corrupted one are told apart: truncation means the unreadable record runs
past the end of the file (and the file does not end with the MCAP magic); anything else (a chunk
CRC mismatch, garbage where a record should start) is corruption, which recovery refuses with one
line rather than silently dropping the rest of the file.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from lagrseq.errors import LogError
from lagrseq.logs.reader import _READ_ERRORS
from lagrseq.logs.sink import PARTIAL_SUFFIX, PROFILE, STATUS_METADATA

MAGIC = b"\x89MCAP0\r\n"
# Topics written at episode flushes (their chunk ends a flushed episode); the rest (transitions,
# picture views) is written as the episode runs and is only kept up to the last flush.
_STEP_TOPICS = ("/transition",)
_STEP_PREFIXES = ("/view",)


@dataclass(frozen=True)
class Recovered:
    """What :func:`recover` wrote."""

    source: Path
    path: Path
    episodes: int
    messages: int
    dropped_bytes: int
    backup: Path | None = None

    def summary(self) -> str:
        kept = f"{self.episodes} episodes, {self.messages} messages kept"
        dropped = f"{self.dropped_bytes} bytes after the last episode flush dropped"
        backup = f"; original kept as {self.backup}" if self.backup else ""
        return f"recovered {self.source} -> {self.path}: {kept}; {dropped}{backup}"


def _is_step_topic(topic: str) -> bool:
    return topic in _STEP_TOPICS or topic.startswith(_STEP_PREFIXES)


def default_output(path: Path) -> Path:
    """``NAME.mcap.partial`` -> ``NAME.mcap``; a ``NAME.mcap`` is repaired in place."""
    if path.name.endswith(".mcap" + PARTIAL_SUFFIX):
        return path.with_name(path.name[: -len(PARTIAL_SUFFIX)])
    return path


def _classify_failure(path: Path, data_end: int, size: int, exc: BaseException) -> None:
    """Raise LogError unless the unreadable record at ``data_end`` runs past the end of the file."""
    with path.open("rb") as handle:
        handle.seek(max(size - MAGIC_SIZE, 0))
        ends_with_magic = handle.read(MAGIC_SIZE) == MAGIC
        handle.seek(data_end)
        head = handle.read(9)
    if not ends_with_magic:
        if len(head) < 9:
            return  # cut inside a record header: truncation
        (length,) = struct.unpack_from("<Q", head, 1)
        if data_end + 9 + length > size:
            return  # the record runs past the end of the file: truncation
    raise LogError(
        f"{path}: corrupt at byte {data_end} of {size} ({type(exc).__name__}: {exc}); "
        "this is damage inside the file, not a crash cut-off, so `lagrseq recover` cannot "
        "repair it: restore the file from a copy or rerun the trial"
    )


def recover(path: str | Path, out: str | Path | None = None) -> Recovered:
    """Rewrite the readable, flushed part of a truncated log as a valid MCAP file.

    ``out`` defaults to :func:`default_output`. Repairing ``NAME.mcap`` in place keeps the
    original as ``NAME.mcap.truncated``. Raises :class:`LogError` (one line) for a file that is
    complete already, not MCAP at all, corrupt rather than truncated, or holds no flushed episode.
    """
    source = Path(path)
    if not source.is_file():
        raise LogError(f"{source}: no such file")
    size = source.stat().st_size
    target = Path(out) if out is not None else default_output(source)
    if target != source and target.exists():
        raise LogError(f"{target} exists already; pass --out to write the recovered log elsewhere")

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: list[Metadata] = []
    chunks: list[list[Message]] = []
    data_end = 0
    data_complete = finished = False
    with source.open("rb") as handle:
        reader = StreamReader(handle, emit_chunks=True, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Chunk):
                    # A whole chunk was read, so damage inside it is corruption, not truncation.
                    messages: list[Message] = []
                    for inner in breakup_chunk(record, validate_crc=True):
                        if isinstance(inner, Schema):
                            schemas[inner.id] = inner
                        elif isinstance(inner, Channel):
                            channels[inner.id] = inner
                        elif isinstance(inner, Message):
                            messages.append(inner)
                    chunks.append(messages)
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata):
                    metadata.append(record)
                elif isinstance(record, DataEnd):
                    data_complete = True  # every chunk is in; only the summary can be missing
                elif isinstance(record, Footer):
                    finished = True
                elif isinstance(record, Header) and record.profile != PROFILE:
                    raise LogError(
                        f"{source}: MCAP profile {record.profile!r}, expected {PROFILE!r}; "
                        "not a lagrseq log"
                    )
                data_end = handle.tell()  # end of the last complete record
        except LogError:
            raise
        except _READ_ERRORS as exc:
            if data_end == 0:
                raise LogError(
                    f"{source}: not an MCAP file ({type(exc).__name__}: {exc})"
                ) from None
            if not data_complete:
                _classify_failure(source, data_end, size, exc)
    if finished:
        raise LogError(f"{source}: the log is complete and readable; there is nothing to recover")

    # Keep chunks up to the last one written at an episode flush.
    last_flush = -1
    for i, messages in enumerate(chunks):
        if any(not _is_step_topic(channels[m.channel_id].topic) for m in messages):
            last_flush = i
    if last_flush < 0:
        raise LogError(
            f"{source}: no episode was flushed before the log was cut off ({size} bytes); "
            "there is nothing to recover, rerun the trial"
        )
    kept = chunks[: last_flush + 1]
    episode_ids = {cid for cid, ch in channels.items() if ch.topic == "/episode"}
    episodes = sum(1 for messages in kept for m in messages if m.channel_id in episode_ids)
    count = sum(len(messages) for messages in kept)
    kept_bytes = _write(source, target, schemas, channels, metadata, kept, episodes, count)

    backup = None
    if target == source:
        backup = source.with_name(source.name + ".truncated")
    tmp = target.with_name(target.name + ".recovering")
    tmp.write_bytes(kept_bytes)
    if backup is not None:
        os.replace(source, backup)
    os.replace(tmp, target)
    return Recovered(
        source,
        target,
        episodes,
        count,
        max(size - data_end, 0) + _dropped(chunks, last_flush),
        backup,
    )


def _dropped(chunks: list[list[Message]], last_flush: int) -> int:
    return sum(len(m.data) for messages in chunks[last_flush + 1 :] for m in messages)


def _write(
    source: Path,
    target: Path,
    schemas: dict[int, Schema],
    channels: dict[int, Channel],
    metadata: list[Metadata],
    chunks: list[list[Message]],
    episodes: int,
    count: int,
) -> bytes:
    import io

    buffer = io.BytesIO()
    writer = Writer(buffer, compression=CompressionType.ZSTD, chunk_size=1 << 22)
    writer.start(profile=PROFILE, library="lagrseq recover")
    schema_ids = {
        old: writer.register_schema(name=s.name, encoding=s.encoding, data=s.data)
        for old, s in sorted(schemas.items())
    }
    channel_ids = {
        old: writer.register_channel(
            topic=c.topic,
            message_encoding=c.message_encoding,
            schema_id=schema_ids.get(c.schema_id, 0),
            metadata=dict(c.metadata),
        )
        for old, c in sorted(channels.items())
    }
    for record in metadata:
        if record.name != STATUS_METADATA:
            writer.add_metadata(record.name, dict(record.metadata))
    for messages in chunks:
        for m in messages:
            writer.add_message(
                channel_id=channel_ids[m.channel_id],
                log_time=m.log_time,
                data=m.data,
                publish_time=m.publish_time,
                sequence=m.sequence,
            )
        writer.flush()  # keep the original chunk boundaries: summary chunks stay separate
    writer.add_metadata(
        STATUS_METADATA,
        {
            "status": "recovered",
            "error": f"recovered from a truncated log {source.name}: {episodes} episodes kept",
            "messages": str(count),
        },
    )
    writer.finish()
    return buffer.getvalue()
