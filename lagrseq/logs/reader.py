"""Read lagrseq MCAP logs back: metadata, configuration and decoded messages.

Only the ``mcap`` record classes and the standard library: replay needs neither gymnasium nor
torch. Files are read through :class:`~lagrseq.logs.mcap_reader.McapFile`, which checks every
length and offset against the file before it reads or allocates anything, so a damaged log costs
at most its own size in memory. What goes wrong (damage, a message that is not JSON, an OS error)
becomes one :class:`~lagrseq.errors.LogError` line naming the log's full path and saying whether
``lagrseq recover`` can repair it, with the command to run.
"""

from __future__ import annotations

import functools
import json
import math
import os
import shlex
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
from typing import Any

import msgspec
from mcap.records import Message

from lagrseq.errors import LogError
from lagrseq.logs.columns import (
    EXPANDS,
    QUERY_FIELDS,
    Expand,
    by_global_step,
    fill_query_defaults,
    no_query_rows,
)
from lagrseq.logs.columns import (
    QUERY_DEFAULTS as QUERY_DEFAULTS,  # where readers of format 2 found it
)
from lagrseq.logs.events import NO_QUERY_TOPIC, QUERY_TOPIC, TRANSITION_TOPIC
from lagrseq.logs.mcap_reader import MAGIC, Damage, McapFile, Summary
from lagrseq.logs.sink import RECORDS_METADATA, RUN_METADATA, STATUS_METADATA
from lagrseq.logs.task_fields import declared
from lagrseq.paths import expand_user, input_path, open_input, walk_files

_decode = msgspec.json.Decoder().decode
"""Message data as Python objects, in C (about 3x faster than ``json.loads`` on a transition);
the same objects as ``json.loads`` gives for what lagrseq writes (compact JSON, finite numbers)."""


@dataclass(frozen=True)
class LogInfo:
    """What a log says about itself (from its metadata records)."""

    path: Path
    run: dict[str, str]
    status: dict[str, str] = field(default_factory=dict)

    @property
    def config(self) -> dict[str, Any]:
        try:
            config = json.loads(self.run["config"])
        except (KeyError, ValueError, RecursionError) as exc:
            raise LogError(
                f"{self.path}: the log's {RUN_METADATA!r} metadata has no readable configuration "
                f"({type(exc).__name__}); not a lagrseq trial log"
            ) from None
        if not isinstance(config, dict):
            raise LogError(f"{self.path}: the logged configuration is not a table; not a lagrseq trial log")
        return config

    @property
    def complete(self) -> bool:
        return self.status.get("status") == "complete"


def full_path(path: str | Path) -> Path:
    """``path`` made absolute (what messages name, so that a suggested command runs anywhere)."""
    return Path(path).absolute()


def recover_command(path: str | Path) -> str:
    """The shell command that repairs ``path``, quoted so it can be pasted as written."""
    return f"lagrseq recover {shlex.quote(str(full_path(path)))}"


def damaged(path: str | Path, damage: Damage | str) -> LogError:
    """The one-line error for a damaged log: where it is damaged and, after checking what
    :func:`lagrseq.logs.recover.recover` could do with it, either the command that repairs it or
    that it cannot be repaired."""
    from lagrseq.logs.recover import diagnose

    full = full_path(path)
    if isinstance(damage, Damage) and damage.offset == 0 and not _starts_with_magic(full):
        return LogError(
            f"{full}: not a readable MCAP log (it does not start with the MCAP magic bytes); "
            "lagrseq logs are the .mcap files that `lagrseq run` writes"
        )
    verdict = diagnose(full)
    if verdict.recoverable:
        advice = f"run `{recover_command(full)}` to repair it ({verdict.detail})"
    else:
        advice = (
            f"`lagrseq recover` cannot repair it ({verdict.detail}): restore it from a copy or "
            "rerun the trial"
        )
    return LogError(f"{full}: damaged MCAP log ({damage}); {advice}")


def _starts_with_magic(path: Path) -> bool:
    try:
        with open_input(path, "log", LogError) as handle:
            return handle.read(len(MAGIC)) == MAGIC
    except (OSError, LogError):
        return False


def _fail(path: Path, exc: Damage | OSError) -> LogError:
    if isinstance(exc, OSError):
        reason = exc.strerror or type(exc).__name__
        return LogError(f"{full_path(path)}: cannot read the log ({reason}); check the path and its permissions")
    return damaged(path, exc)


def _fills_defaults(metadata: Sequence[Any]) -> bool:
    """Whether a log's ``/query`` records may leave defaults out (log format 2 and later)."""
    for record in metadata:
        if record.name == RUN_METADATA:
            return record.metadata.get("log_format", "1") != "1"
    return False


def _json(data: bytes, topic: str, offset: int, fill: bool = False) -> dict[str, Any]:
    try:
        record = _decode(data)
    except (ValueError, RecursionError) as exc:
        raise Damage(offset, f"a {topic} message in this chunk is not JSON ({type(exc).__name__})") from None
    if not isinstance(record, dict):
        raise Damage(offset, f"a {topic} message in this chunk is not a JSON object")
    if fill and topic == QUERY_TOPIC:
        return fill_query_defaults(record)
    return record


def _info(path: Path, metadata: Sequence[Any]) -> LogInfo:
    records = {m.name: dict(m.metadata) for m in metadata}
    if RUN_METADATA not in records:
        raise LogError(f"{full_path(path)}: MCAP file has no {RUN_METADATA!r} metadata; not a lagrseq log")
    return LogInfo(path, records[RUN_METADATA], records.get(STATUS_METADATA, {}))


def _summary(log: McapFile) -> Summary:
    summary = log.summary()
    if summary is None:
        footer_offset = log.footer()[1]
        raise Damage(footer_offset, "the file has no summary section")
    return summary


def read_info(path: str | Path) -> LogInfo:
    """Metadata of a finished log (through the summary's index; no message data is read)."""
    path = Path(path)
    try:
        with McapFile(path) as log:
            metadata = log.metadata()
    except (Damage, OSError) as exc:
        raise _fail(path, exc) from None
    return _info(path, metadata)


def is_complete(path: str | Path) -> bool:
    """True when ``path`` is a readable log of a trial that ran to its end."""
    try:
        return read_info(path).complete
    except LogError:
        return False


def iter_messages(
    path: str | Path, topics: Sequence[str] | None = None
) -> Iterator[tuple[str, dict[str, Any]]]:
    """Decoded ``(topic, record)`` pairs in log-time order (ties in file order); ``topics``
    restricts what is read (chunks holding none of them are not decompressed)."""
    path = Path(path)
    found: list[tuple[tuple[int, ...], str, dict[str, Any]]] = []
    try:
        with McapFile(path) as log:
            summary = _summary(log)
            fill = _fills_defaults(log.metadata())
            wanted = _wanted(summary, topics)
            for index in summary.chunk_indexes:
                if index.message_index_offsets and not wanted.keys() & index.message_index_offsets.keys():
                    continue
                offset = index.chunk_start_offset
                records = log.chunk_records(log.chunk(index), offset)
                for position, item in enumerate(records):
                    if isinstance(item, Message) and item.channel_id in wanted:
                        source, topic, expand = wanted[item.channel_id]
                        record = _json(item.data, source, offset, fill)
                        if expand is None:
                            found.append(((item.log_time, offset, position), topic, record))
                            continue
                        # Format 3: each row at its own step; an episode's transitions go before
                        # the pictures of the same step in their chunk, as format 2 wrote them.
                        rank = -1 if topic == TRANSITION_TOPIC else position
                        for i, row in enumerate(expand(record, offset)):
                            found.append(((row["global_step"], offset, rank, i), topic, row))
    except (Damage, OSError) as exc:
        raise _fail(path, exc) from None
    found.sort(key=itemgetter(0))
    for _key, topic, record in found:
        yield topic, record


def _wanted(summary: Summary, topics: Sequence[str] | None) -> dict[int, tuple[str, str, Expand | None]]:
    """Channel id -> (its topic, the topic its records are read as, how to expand them) for the
    channels that hold ``topics`` (None: every channel); format 3's columnar channels are read as
    ``/transition`` and ``/query``."""
    wanted: dict[int, tuple[str, str, Expand | None]] = {}
    for cid, channel in summary.channels.items():
        if topics is None or channel.topic in topics:
            if channel.topic in EXPANDS and topics is None:
                wanted[cid] = (channel.topic, *EXPANDS[channel.topic])
            else:
                wanted[cid] = (channel.topic, channel.topic, None)
        elif channel.topic in EXPANDS and EXPANDS[channel.topic][0] in topics:
            wanted[cid] = (channel.topic, *EXPANDS[channel.topic])
    return wanted


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
    """Records given (log format 3: each transition and decision of a columnar record)."""

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


def read_log(
    path: str | Path, topics: Sequence[str] = (), stats: ReadStats | None = None
) -> LogData:
    """Metadata, message counts and every record of ``topics``, per topic, in file order (which
    is log-time order for lagrseq logs).

    Uses the chunk index: a chunk that holds none of ``topics`` is never read from disk nor
    decompressed, and ``stats`` (if given) counts what was. Chunk CRCs are checked.
    """
    info, counts, out = _read(Path(path), topics, stats, _chunk_dicts)
    return LogData(info, counts, out)


ChunkReader = Callable[
    [list[tuple[int, bytes]], dict[int, tuple[str, str, Expand | None]], int, bool], dict[str, list[Any]]
]
"""``read(messages, wanted, offset, fill)``: a chunk's ``(channel id, data)`` messages (those of
the ``wanted`` channels, in order) as records per topic."""


def _read(
    path: Path,
    topics: Sequence[str],
    stats: ReadStats | None,
    read_chunk: ChunkReader,
    on_summary: Callable[[Summary], None] | None = None,
) -> tuple[LogInfo, dict[str, int], dict[str, list[Any]]]:
    """What :func:`read_log` and :func:`read_rows` share: one pass over the log's summary and
    the chunks that hold ``topics``, each chunk's messages made records by ``read_chunk``
    (``on_summary(summary)`` is called before any chunk is read)."""
    out: dict[str, list[Any]] = {topic: [] for topic in topics}
    local = ReadStats(files=1)
    try:
        with McapFile(path) as log:
            summary = _summary(log)
            if on_summary is not None:
                on_summary(summary)
            metadata = log.metadata()
            fill = _fills_defaults(metadata)
            statistics = summary.statistics
            counts = {
                ch.topic: int(statistics.channel_message_counts.get(cid, 0)) if statistics else 0
                for cid, ch in summary.channels.items()
            }
            if EXPANDS.keys() & counts.keys():
                counts = _expanded_counts(log, summary, metadata, counts)
            wanted = _wanted(summary, list(out))
            chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
            local.chunks = len(chunks)
            for index in chunks:
                if not wanted.keys() & index.message_index_offsets.keys():
                    continue
                chunk = log.chunk(index)
                local.chunks_decompressed += 1
                local.bytes_decompressed += chunk.uncompressed_size
                offset = index.chunk_start_offset
                messages = log.chunk_messages(chunk, offset, wanted)
                for topic, records in read_chunk(messages, wanted, offset, fill).items():
                    out[topic] += records
                    local.messages += len(records)
    except (Damage, OSError) as exc:
        raise _fail(path, exc) from None
    info = _info(path, metadata)
    if stats is not None:
        stats.add(local)
    return info, counts, out


def _chunk_dicts(
    messages: list[tuple[int, bytes]], wanted: dict[int, tuple[str, str, Expand | None]], offset: int, fill: bool
) -> dict[str, list[Any]]:
    """A chunk's messages as records (dicts) per topic, in file order; format 3's columnar
    records expanded, and a chunk's ``/query`` records in step order where it held a
    ``/no_query`` record."""
    found: dict[str, list[Any]] = {}
    merge = False
    for cid, data in messages:
        source, topic, expand = wanted[cid]
        if expand is None:
            found.setdefault(topic, []).append(_json(data, source, offset, fill))
        else:
            found.setdefault(topic, []).extend(expand(_json(data, source, offset), offset))
            merge = merge or topic == QUERY_TOPIC
    if merge:
        found[QUERY_TOPIC] = by_global_step(found[QUERY_TOPIC], offset)
    return found


@dataclass(frozen=True)
class LogRows:
    """One log read by :func:`read_rows`: metadata, per-topic message counts, and the records of
    the topics asked for as tuples of the columns asked for."""

    info: LogInfo
    counts: dict[str, int]
    rows: dict[str, list[tuple[Any, ...]]]
    task_fields: dict[str, tuple[tuple[str, str], ...]] = field(default_factory=dict)
    """``read_rows(task_fields=True)``: per topic, the task's own fields its schema names (name,
    JSON type), whose values follow the columns asked for in each row."""
    declared: dict[str, tuple[tuple[str, str], ...]] = field(default_factory=dict)
    """``read_rows(task_fields=True)``: the task's own fields of every topic of the log, read or
    not (a caller reads a topic's records only where they hold fields it wants)."""


def read_rows(
    path: str | Path,
    columns: Mapping[str, Sequence[str]],
    stats: ReadStats | None = None,
    missing: Any = math.nan,
    task_fields: bool = False,
) -> LogRows:
    """:func:`read_log` of the topics ``columns`` names, each record given as the tuple of its
    values of ``columns[topic]`` (``missing`` for a field the record lacks: with ``numpy.nan``,
    what ``pandas.DataFrame.from_records(records, columns=...)`` makes of the records), in the
    same order.

    The same records, cheaper: a message is decoded straight into its columns (a
    ``msgspec.Struct`` made for them; fields that are not asked for are skipped, not built into
    Python objects), and a format-3 ``/no_query`` record's rows are made without a dict each. A
    chunk holding anything that way does not read exactly as :func:`read_log` reads it (a record
    that is not a JSON object or names a field a ``/query`` record cannot have, an accuracy
    probe's query in a log that leaves defaults out, a step told twice) is read the way
    :func:`read_log` reads it, so the two agree on every log, its errors included.

    ``task_fields``: each topic's rows also hold, after ``columns[topic]``, the fields of the
    run's task that the topic's schema in the log names (``lagrseq.logs.task_fields``), listed
    in :attr:`LogRows.task_fields`.
    """
    wanted = {topic: tuple(names) for topic, names in columns.items()}
    own: dict[str, tuple[tuple[str, str], ...]] = {}
    every: dict[str, tuple[tuple[str, str], ...]] = {}

    def add_task_fields(summary: Summary) -> None:
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            topic = EXPANDS[channel.topic][0] if channel.topic in EXPANDS else channel.topic  # format 3's columns: the topic read
            if schema is not None and topic not in every:
                every[topic] = declared(schema.data)
            if schema is not None and topic in wanted and topic not in own:
                found = tuple(f for f in declared(schema.data) if f[0] not in wanted[topic])
                if found:
                    own[topic] = found
                    wanted[topic] = (*wanted[topic], *(name for name, _ in found))

    def read_chunk(
        messages: list[tuple[int, bytes]], channels: dict[int, tuple[str, str, Expand | None]], offset: int, fill: bool
    ) -> dict[str, list[Any]]:
        try:
            return _chunk_rows(messages, channels, fill, wanted, missing)
        except Exception:  # anything unusual, damage included: read_log's way, which says what is wrong
            found = _chunk_dicts(messages, channels, offset, fill)
            return {
                topic: [tuple([record.get(name, missing) for name in wanted[topic]]) for record in records]
                for topic, records in found.items()
            }

    info, counts, out = _read(Path(path), list(wanted), stats, read_chunk, add_task_fields if task_fields else None)
    return LogRows(info, counts, out, own, {topic: fields for topic, fields in every.items() if fields})


_PROBE_FIELDS = (b'"prefix_length"', b'"fraction"')


class _Unusual(Exception):
    """A chunk that :func:`_chunk_rows` leaves to :func:`_chunk_dicts`."""


@functools.lru_cache(maxsize=32)
def _row_decoder(names: tuple[str, ...], fill: bool, missing: Any) -> Callable[[list[bytes]], list[tuple[Any, ...]]]:
    """Messages' data -> the tuples of their ``names`` values (``missing`` where one lacks a
    field). With ``fill``
    (a ``/query`` record of log format 2 and later) a field with a default (:data:`QUERY_DEFAULTS`)
    that the record leaves out reads as that default, and a field no ``/query`` record has is an
    error (a record with unknown fields is read as :func:`read_log` reads it)."""
    fields: list[tuple[str, Any, Any]] = [
        (f"f{i}", Any, msgspec.field(name=name, default=QUERY_DEFAULTS.get(name, missing) if fill else missing))
        for i, name in enumerate(names)
    ]
    if fill:
        fields += [
            (f"g{i}", msgspec.Raw, msgspec.field(name=name, default=None))
            for i, name in enumerate(QUERY_FIELDS)
            if name not in names
        ]
    row = msgspec.defstruct("Row", fields, forbid_unknown_fields=fill, gc=False)
    decode = msgspec.json.Decoder(row).decode
    astuple = msgspec.structs.astuple
    if len(fields) > len(names):  # the fields after the columns were only checked
        cut = itemgetter(slice(0, len(names)))
        return lambda texts: list(map(cut, map(astuple, map(decode, texts))))
    return lambda texts: list(map(astuple, map(decode, texts)))


def _chunk_rows(
    messages: list[tuple[int, bytes]],
    wanted: dict[int, tuple[str, str, Expand | None]],
    fill: bool,
    columns: dict[str, tuple[str, ...]],
    missing: Any,
) -> dict[str, list[Any]]:
    """:func:`_chunk_dicts` as rows of ``columns``, for chunks as lagrseq writes them; raises
    where a chunk is anything else."""
    plain: dict[str, int] = {}
    expanded: dict[str, int] = {}
    for cid in {cid for cid, _ in messages}:
        _source, topic, expand = wanted[cid]
        group = plain if expand is None else expanded
        if topic in group:  # two channels of one topic: their records interleave
            raise _Unusual
        group[topic] = cid
    found: dict[str, list[Any]] = {}
    for topic, cid in plain.items():
        texts = [d for c, d in messages if c == cid]
        query = fill and wanted[cid][0] == QUERY_TOPIC
        if query:
            joined = b"\0".join(texts)
            if any(name in joined for name in _PROBE_FIELDS):
                raise _Unusual  # format 2's defaults are put back by a record's field count
        found[topic] = _row_decoder(columns[topic], query, missing)(texts)
    for topic, cid in expanded.items():
        source, _topic, expand = wanted[cid]
        rows = found.setdefault(topic, [])
        for data in (d for c, d in messages if c == cid):
            record = _decode(data)
            if not isinstance(record, dict):
                raise _Unusual
            if source == NO_QUERY_TOPIC:
                rows += no_query_rows(record, columns[topic], missing)
            elif expand is not None:
                rows += [tuple([row.get(name, missing) for name in columns[topic]]) for row in expand(record, 0)]
    if QUERY_TOPIC in expanded:  # format 3: an episode's decisions after the queries it sent
        step = columns[QUERY_TOPIC].index("global_step")
        rows = found[QUERY_TOPIC]
        steps = [row[step] for row in rows]
        if not all(type(s) is int for s in steps) or len(set(steps)) != len(steps):
            raise _Unusual
        found[QUERY_TOPIC] = sorted(rows, key=itemgetter(step))
    return found


def _expanded_counts(log: McapFile, summary: Summary, metadata: Sequence[Any], counts: dict[str, int]) -> dict[str, int]:
    """Format 3: the message counts per topic as the readers give the records (``/transition``:
    steps, ``/query``: decisions), from the ``lagrseq.records`` metadata the sink writes at the
    end; a log without a readable one has its columnar records read and counted."""
    out = {topic: count for topic, count in counts.items() if topic not in EXPANDS}
    for expanded, _ in EXPANDS.values():
        out.setdefault(expanded, 0)
    written = next((dict(m.metadata) for m in metadata if m.name == RECORDS_METADATA), {})
    try:
        said = {topic: int(written[topic]) for topic in (TRANSITION_TOPIC, QUERY_TOPIC)}
    except (KeyError, ValueError):
        said = {}
    if said and min(said.values()) >= 0:
        return {**out, **said}
    columnar = {cid: ch.topic for cid, ch in summary.channels.items() if ch.topic in EXPANDS}
    for index in summary.chunk_indexes:
        if not columnar.keys() & index.message_index_offsets.keys():
            continue
        offset = index.chunk_start_offset
        for record in log.chunk_records(log.chunk(index), offset):
            if isinstance(record, Message) and record.channel_id in columnar:
                topic, expand = EXPANDS[columnar[record.channel_id]]
                out[topic] += len(expand(_json(record.data, columnar[record.channel_id], offset), offset))
    return out


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
        if not os.path.lexists(expand_user(item, "logs", LogError)):
            raise LogError(f"{item}: no such MCAP file or directory")
        item = input_path(item, "logs", "any", LogError)
        if item.is_dir():
            # every match checked before anything opens it: a FIFO named *.mcap would block the reader
            found.extend(input_path(path, "log", "file", LogError) for path in walk_files(item, lambda name: name.endswith(".mcap")))
        elif item.suffix == ".mcap":
            found.append(item)
        else:
            raise LogError(f"{item}: no such MCAP file or directory")
    return sorted(set(found))
