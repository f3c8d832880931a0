"""Read lagrseq MCAP logs back: metadata, configuration and decoded messages.

Only the ``mcap`` library and the standard library: replay needs neither gymnasium nor torch.
Foreign errors (mcap, struct, json) become one-line :class:`~lagrseq.errors.LogError` messages.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import CRCValidationError, breakup_chunk

from lagrseq.errors import LogError
from lagrseq.logs.sink import RUN_METADATA, STATUS_METADATA

try:  # zstandard is what mcap decompresses chunks with; its errors enter here
    from zstandard import ZstdError as _ZstdError
except ImportError:  # pragma: no cover - mcap cannot read our files without it anyway
    _ZstdError = McapError  # type: ignore[misc,assignment]

_READ_ERRORS = (
    McapError,
    _ZstdError,
    struct.error,
    EOFError,
    ValueError,
    KeyError,
    IndexError,
    OSError,
)


@dataclass(frozen=True)
class LogInfo:
    """What a log says about itself (from its metadata records)."""

    path: Path
    run: dict[str, str]
    status: dict[str, str] = field(default_factory=dict)

    @property
    def config(self) -> dict[str, Any]:
        return json.loads(self.run["config"])

    @property
    def complete(self) -> bool:
        return self.status.get("status") == "complete"


def _broken(path: Path, exc: BaseException) -> LogError:
    if isinstance(exc, (CRCValidationError, _ZstdError)):
        return LogError(
            f"{path}: corrupt MCAP chunk ({type(exc).__name__}: {exc}); the file's bytes were "
            "changed after it was written, restore it from a copy or rerun the trial"
        )
    return LogError(
        f"{path}: not a readable MCAP log ({type(exc).__name__}: {exc}); "
        f"if a crash cut it short, run `lagrseq recover {path}`"
    )


def read_info(path: str | Path) -> LogInfo:
    """Metadata of a finished log (uses the summary section, no message data is read)."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            reader = make_reader(handle)
            records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except _READ_ERRORS as exc:
        raise _broken(path, exc) from None
    if RUN_METADATA not in records:
        raise LogError(f"{path}: MCAP file has no {RUN_METADATA!r} metadata; not a lagrseq log")
    return LogInfo(path, records[RUN_METADATA], records.get(STATUS_METADATA, {}))


def is_complete(path: str | Path) -> bool:
    """True when ``path`` is a readable log of a trial that ran to its end."""
    try:
        return read_info(path).complete
    except LogError:
        return False


def iter_messages(
    path: str | Path, topics: Sequence[str] | None = None
) -> Iterator[tuple[str, dict[str, Any]]]:
    """Decoded ``(topic, record)`` pairs in log-time order; ``topics`` restricts what is read
    (chunks holding none of them are not decompressed)."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            reader = make_reader(handle)
            for _schema, channel, message in reader.iter_messages(
                topics=list(topics) if topics else None, log_time_order=True
            ):
                yield channel.topic, json.loads(message.data)
    except _READ_ERRORS as exc:
        raise _broken(path, exc) from None


@dataclass
class ReadStats:
    """What :func:`read_topics` had to do: how many chunks it decompressed and how many it left
    alone because they hold none of the topics asked for (e.g. every transition chunk, when only
    ``/episode`` and ``/query`` are wanted)."""

    files: int = 0
    chunks: int = 0
    chunks_decompressed: int = 0
    bytes_decompressed: int = 0
    messages: int = 0

    def add(self, other: ReadStats) -> None:
        self.files += other.files
        self.chunks += other.chunks
        self.chunks_decompressed += other.chunks_decompressed
        self.bytes_decompressed += other.bytes_decompressed
        self.messages += other.messages


@dataclass(frozen=True)
class LogData:
    """One log read in a single pass over its summary: metadata, per-topic message counts (from
    the statistics) and the records of the topics asked for."""

    info: LogInfo
    counts: dict[str, int]
    topics: dict[str, list[dict[str, Any]]]


def _no_summary(path: Path) -> LogError:
    return LogError(
        f"{path}: MCAP file has no summary section (unfinished or cut short); "
        f"run `lagrseq recover {path}`"
    )


def read_log(
    path: str | Path, topics: Sequence[str] = (), stats: ReadStats | None = None
) -> LogData:
    """Metadata, message counts and every record of ``topics``, per topic, in file order (which
    is log-time order for lagrseq logs).

    Uses the chunk index: a chunk that holds none of ``topics`` is never read from disk nor
    decompressed, and ``stats`` (if given) counts what was. Chunk CRCs are checked.
    """
    path = Path(path)
    out: dict[str, list[dict[str, Any]]] = {topic: [] for topic in topics}
    local = ReadStats(files=1)
    try:
        with path.open("rb") as handle:
            reader = make_reader(handle)
            summary = reader.get_summary()
            if summary is None:
                raise _no_summary(path)
            records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            statistics = summary.statistics
            counts = {
                ch.topic: int(statistics.channel_message_counts.get(cid, 0)) if statistics else 0
                for cid, ch in summary.channels.items()
            }
            wanted = {cid: ch.topic for cid, ch in summary.channels.items() if ch.topic in out}
            chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
            local.chunks = len(chunks)
            for index in chunks:
                if not wanted.keys() & index.message_index_offsets.keys():
                    continue
                handle.seek(index.chunk_start_offset + 1 + 8)  # skip opcode and record length
                chunk = Chunk.read(ReadDataStream(handle))
                local.chunks_decompressed += 1
                local.bytes_decompressed += chunk.uncompressed_size
                for record in breakup_chunk(chunk, validate_crc=True):
                    if isinstance(record, Message) and record.channel_id in wanted:
                        out[wanted[record.channel_id]].append(json.loads(record.data))
                        local.messages += 1
    except LogError:
        raise
    except _READ_ERRORS as exc:
        raise _broken(path, exc) from None
    if RUN_METADATA not in records:
        raise LogError(f"{path}: MCAP file has no {RUN_METADATA!r} metadata; not a lagrseq log")
    if stats is not None:
        stats.add(local)
    info = LogInfo(path, records[RUN_METADATA], records.get(STATUS_METADATA, {}))
    return LogData(info, counts, out)


def read_topics(
    path: str | Path, topics: Sequence[str], stats: ReadStats | None = None
) -> dict[str, list[dict[str, Any]]]:
    """Every record of the given topics, per topic (see :func:`read_log`)."""
    return read_log(path, topics, stats).topics


def message_counts(path: str | Path) -> dict[str, int]:
    """Messages per topic, from the summary's statistics (nothing is decompressed)."""
    return read_log(path).counts


def read_topic(path: str | Path, topic: str) -> list[dict[str, Any]]:
    """Every record of one topic."""
    return [record for _, record in iter_messages(path, [topic])]


def find_logs(paths: Sequence[str | Path]) -> list[Path]:
    """Every ``*.mcap`` file under the given files and directories, sorted."""
    found: list[Path] = []
    for item in paths:
        item = Path(item)
        if item.is_dir():
            found.extend(sorted(item.rglob("*.mcap")))
        elif item.suffix == ".mcap" and item.exists():
            found.append(item)
        else:
            raise LogError(f"{item}: no such MCAP file or directory")
    return sorted(set(found))
