"""Recover a damaged or crash-truncated MCAP log: keep everything up to the last good episode.

A trial killed mid-run (SIGKILL, power cut, out of memory) leaves ``NAME.mcap.partial``: a valid
MCAP data section cut off somewhere after its last complete record, with no summary and no footer.
The sink closes chunks at episode ends only and writes those episodes' ``/query``, ``/no_query``
and ``/episode`` messages as a chunk of their own after their transitions (see
:mod:`lagrseq.logs.sink`), so the file holds every episode finished before its last chunk. In log
format 3 an episode's transitions are one ``/transitions`` record, so a kept chunk never holds
part of an episode; the ``lagrseq.records`` metadata (records per topic as readers count them)
is worked out again from what is kept. Recovery reads the records in order (through the checked reader,
:class:`~lagrseq.logs.mcap_reader.McapFile`, so a damaged length never makes it allocate more than
the file) until the first record that cannot be read, and rewrites what it kept with a fresh
``Writer`` (same schemas, channels, metadata and chunk boundaries). What is kept depends on where
the damage is:

- the whole data section reads (up to its ``DataEnd`` record) but the summary, footer or closing
  magic does not (a file one byte short, bytes appended, a flipped bit in an index): everything is
  kept and the summary rebuilt; the trial's own status record is kept, with a note added;
- the data section stops being readable and the file does not end with a valid footer (a crash
  cut-off, or garbage or zeros where the crash left the file): the chunks up to the last episode
  flush before that point are kept, marked ``recovered``;
- the data section is damaged but the file ends with a valid footer: the file was finished and
  then changed. That is corruption, not a cut-off, and recovery refuses it with one line rather
  than silently dropping the rest of the file.

:func:`recover` raises :class:`~lagrseq.errors.LogError` when it can do nothing; :func:`recover_all`
reports per file (:class:`Outcome`) so that one bad file does not stop the others;
:func:`diagnose` says, without writing anything, whether recovery would do something.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: no lock to look at
    fcntl = None  # type: ignore[assignment]

from mcap.records import Channel, Chunk, DataEnd, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from lagrseq.errors import LogError, UsageError
from lagrseq.logs.columns import columnar_rows
from lagrseq.logs.mcap_reader import Damage, McapFile
from lagrseq.logs.sink import PARTIAL_SUFFIX, PROFILE, RECORDS_METADATA, STATUS_METADATA
from lagrseq.paths import expand_user, input_path, open_new, place_new, refuse_link

# Topics written as the episode runs (transitions, picture views): kept only up to the last flush.
_STEP_TOPICS = ("/transition", "/transitions")
_STEP_PREFIXES = ("/view",)
_WRITE_PIECE = 1 << 20
BACKUP_SUFFIX = ".truncated"
TEMP_SUFFIX = ".recovering"


@dataclass(frozen=True)
class Recovered:
    """What :func:`recover` wrote."""

    source: Path
    path: Path
    episodes: int
    messages: int
    dropped_bytes: int
    backup: Path | None = None
    complete: bool = False
    """True when the whole data section was intact and only the summary was rebuilt."""

    def summary(self) -> str:
        if self.complete:
            kept = f"all {self.episodes} episodes, {self.messages} messages kept"
            dropped = f"summary rebuilt, {self.dropped_bytes} bytes of old summary and tail replaced"
        else:
            kept = f"{self.episodes} episodes, {self.messages} messages kept"
            dropped = f"{self.dropped_bytes} bytes after the last episode flush dropped"
        backup = f"; original kept as {self.backup}" if self.backup else ""
        return f"recovered {self.source} -> {self.path}: {kept}; {dropped}{backup}"


@dataclass(frozen=True)
class Verdict:
    """What :func:`recover` could do with a file (see :func:`diagnose`)."""

    recoverable: bool
    detail: str
    """Recoverable: what would be kept; otherwise why nothing can be done."""


@dataclass(frozen=True)
class Outcome:
    """The result of recovering one file in :func:`recover_all`.

    ``status`` is ``recovered`` (``result`` says what was written), ``intact`` (the log reads as
    it is; nothing was written) or ``failed`` (nothing was written; ``message`` says why)."""

    source: Path
    status: str
    message: str
    result: Recovered | None = None

    @property
    def ok(self) -> bool:
        return self.status != "failed"


class _Cannot(Exception):
    """Recovery can do nothing with the file: ``detail`` says why, ``advice`` what to do."""

    def __init__(self, detail: str, advice: str, intact: bool = False) -> None:
        super().__init__(detail)
        self.detail = detail
        self.advice = advice
        self.intact = intact


class _Intact(LogError):
    """:func:`recover` was given a log that reads as it is."""


_RESTORE = "restore the file from a copy or rerun the trial"


@dataclass
class _Plan:
    size: int
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[Metadata] = field(default_factory=list)
    chunks: list[list[Message]] = field(default_factory=list)
    good_end: int = 0
    """End of the last record read whole (of the data section, when it is complete)."""
    complete: bool = False
    """The data section reads whole, up to its DataEnd record."""
    damage: Damage | None = None

    def keep(self) -> int:
        """How many chunks to keep: all of a complete data section, else up to the last flush."""
        if self.complete:
            return len(self.chunks)
        last = -1
        for i, messages in enumerate(self.chunks):
            if any(not _is_step_topic(self.channels[m.channel_id].topic) for m in messages):
                last = i
        return last + 1

    def episodes(self, kept: int) -> int:
        ids = {cid for cid, ch in self.channels.items() if ch.topic == "/episode"}
        return sum(1 for messages in self.chunks[:kept] for m in messages if m.channel_id in ids)


def _is_step_topic(topic: str) -> bool:
    return topic in _STEP_TOPICS or topic.startswith(_STEP_PREFIXES)


def default_output(path: Path) -> Path:
    """``NAME.mcap.partial`` -> ``NAME.mcap``; a ``NAME.mcap`` is repaired in place."""
    if path.name.endswith(".mcap" + PARTIAL_SUFFIX):
        return path.with_name(path.name[: -len(PARTIAL_SUFFIX)])
    return path


def _scan(log: McapFile) -> _Plan:
    plan = _Plan(log.size)
    try:
        for _offset, end, record in log.scan():
            if isinstance(record, Header) and record.profile != PROFILE:
                raise _Cannot(
                    f"MCAP profile {record.profile[:40]!r}, expected {PROFILE!r}; not a lagrseq log",
                    "recover only repairs lagrseq logs",
                )
            if isinstance(record, Chunk):
                messages: list[Message] = []
                for inner in log.chunk_records(record, _offset):
                    if isinstance(inner, Schema):
                        plan.schemas[inner.id] = inner
                    elif isinstance(inner, Channel):
                        plan.channels[inner.id] = inner
                    elif isinstance(inner, Message):
                        if inner.channel_id not in plan.channels:
                            raise Damage(_offset, f"chunk: a message on undeclared channel {inner.channel_id}")
                        messages.append(inner)
                plan.chunks.append(messages)
            elif isinstance(record, Schema):
                plan.schemas[record.id] = record
            elif isinstance(record, Channel):
                if record.schema_id and record.schema_id not in plan.schemas:
                    raise Damage(_offset, f"channel {record.id} names undeclared schema {record.schema_id}")
                plan.channels[record.id] = record
            elif isinstance(record, Metadata):
                plan.metadata.append(record)
            plan.good_end = end
            if isinstance(record, DataEnd):
                plan.complete = True
                break
    except Damage as exc:
        if plan.good_end == 0:
            raise _Cannot(f"not an MCAP file ({exc.what})", "recover only repairs lagrseq logs") from None
        plan.damage = exc
    return plan


def _plan(source: Path) -> _Plan:
    """What recovery would keep; raises :class:`_Cannot` when it can do nothing."""
    try:
        with McapFile(source) as log:
            plan = _scan(log)
            if plan.complete:
                try:
                    log.verify()
                except Damage as exc:
                    plan.damage = exc
                else:
                    raise _Cannot(
                        "the log is complete and readable; there is nothing to recover",
                        "use it as it is",
                        intact=True,
                    )
                return plan
            assert plan.damage is not None  # the scan stopped before the data section ended
            try:
                log.footer()
            except Damage:
                pass  # the file does not end like a finished log: cut short or garbage-tailed
            else:
                raise _Cannot(
                    f"corrupt at byte {plan.damage.offset} of {plan.size} ({plan.damage.what}); "
                    "this is damage inside a finished file, not a crash cut-off",
                    f"so `lagrseq recover` cannot repair it: {_RESTORE}",
                )
    except OSError as exc:
        raise LogError(f"{source}: cannot read ({exc.strerror or type(exc).__name__})") from None
    if plan.keep() == 0:
        raise _Cannot(
            f"no episode was flushed before byte {plan.good_end} of {plan.size}, where the log "
            f"is cut off or damaged ({plan.damage.what})",
            "there is nothing to recover, rerun the trial",
        )
    return plan


def diagnose(path: str | Path) -> Verdict:
    """Whether :func:`recover` would repair ``path`` and what it would keep (nothing is written)."""
    try:
        plan = _plan(Path(path))
    except _Cannot as exc:
        return Verdict(False, exc.detail)
    except LogError as exc:
        return Verdict(False, str(exc))
    kept = plan.keep()
    if plan.complete:
        return Verdict(True, f"its data is intact: all {plan.episodes(kept)} episodes would be kept")
    episodes = plan.episodes(kept)
    return Verdict(True, f"{episodes} flushed episode{'' if episodes == 1 else 's'} would be kept")


def _target(source: Path, out: str | Path | None) -> Path:
    if out is None:
        return default_output(source)
    out = Path(out)
    if out.is_dir():
        return out / default_output(source).name
    return out


def recover(path: str | Path, out: str | Path | None = None) -> Recovered:
    """Rewrite the readable part of a truncated or damaged log as a valid MCAP file.

    ``out`` defaults to :func:`default_output`; an existing directory means ``out/NAME.mcap``.
    Repairing ``NAME.mcap`` in place keeps the original as ``NAME.mcap.truncated``. Raises
    :class:`LogError` (one line) for a file that is complete already, not MCAP at all, corrupt
    inside a finished file, or holds no flushed episode, and when the result cannot be written
    (the source is then left as it was and no temporary file remains).
    """
    source = expand_user(path, "log", LogError)
    if source.is_dir():
        raise LogError(f"{source}: a directory, not a log: give the .mcap or .mcap.partial files in it")
    source = input_path(source, "log", "file", LogError)  # a FIFO or device would block the reader
    target = _target(source, out)
    in_place = target.absolute() == source.absolute()
    flag = "--out" if out is not None else "the recovered log"
    refuse_link(target, flag, LogError)  # never written through a link (one planted in a shared folder)
    if not in_place and target.exists():
        if out is None:
            advice = "pass --out FILE or --out DIRECTORY to write the recovered log elsewhere"
        else:
            advice = "recover never overwrites a log: give --out a new file name or another directory"
        raise LogError(f"{target} exists already; {advice}")
    _check_not_being_written(source)
    try:
        plan = _plan(source)
    except _Cannot as exc:
        error = _Intact if exc.intact else LogError
        raise error(f"{source}: {exc.detail}; {exc.advice}") from None
    backup = source.with_name(source.name + BACKUP_SUFFIX) if in_place else None
    if backup is not None:
        refuse_link(backup, "the copy of the original", LogError)
    if backup is not None and backup.exists():
        raise LogError(
            f"{backup} exists already (a copy kept by an earlier recovery); move it away, or "
            "pass --out to write the recovered log elsewhere"
        )

    kept = plan.keep()
    episodes = plan.episodes(kept)
    count = sum(len(messages) for messages in plan.chunks[:kept])
    data = _write(source, plan, kept, episodes, count)
    dropped = max(plan.size - plan.good_end, 0) + sum(
        len(m.data) for messages in plan.chunks[kept:] for m in messages
    )
    _commit(source, target, data, backup, elsewhere=out is None, flag=flag)
    return Recovered(source, target, episodes, count, dropped, backup, plan.complete)


def _check_not_being_written(source: Path) -> None:
    """A ``.partial`` file that a running trial holds locked (:mod:`lagrseq.logs.sink`) is
    refused: its writer would rename its own file over the recovered one when it finishes."""
    if fcntl is None or not source.name.endswith(PARTIAL_SUFFIX):
        return
    try:
        with source.open("rb") as handle:
            fcntl.flock(handle.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        raise LogError(
            f"{source} is being written by a running lagrseq trial; wait for it to end (or stop it), then recover"
        ) from None
    except OSError:
        return  # unreadable: _plan says why


def recover_all(paths: list[Path] | tuple[Path, ...], out: str | Path | None = None) -> list[Outcome]:
    """Recover each file, never stopping at a bad one: one :class:`Outcome` per file, in order.

    ``out`` is either one file (with one path only) or an existing directory."""
    if out is not None and len(paths) > 1 and not Path(out).is_dir():
        raise UsageError(
            f"--out {out} is not an existing directory, so it can take one FILE only; "
            "give a directory to recover several files into it"
        )
    outcomes = []
    for path in paths:
        try:
            result = recover(path, out)
        except _Intact as exc:
            outcomes.append(Outcome(Path(path), "intact", str(exc)))
        except LogError as exc:
            outcomes.append(Outcome(Path(path), "failed", str(exc)))
        else:
            outcomes.append(Outcome(Path(path), "recovered", result.summary(), result))
    return outcomes


def _write_all(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file ``path``, never through a link: a leftover regular file of a
    recovery that crashed is removed first, and the file is created with ``O_EXCL |
    O_NOFOLLOW`` (a name planted meanwhile fails; a link is not followed)."""
    with contextlib.suppress(FileNotFoundError):
        if not os.path.islink(path):
            os.unlink(path)  # only the name goes: a file with other links keeps its data
    fd = open_new(path)
    try:
        view = memoryview(data)
        while view:
            written = os.write(fd, view[:_WRITE_PIECE])
            if written <= 0:
                raise OSError(errno.EIO, "write made no progress")
            view = view[written:]
        os.fsync(fd)
    finally:
        os.close(fd)


def _commit(
    source: Path, target: Path, data: bytes, backup: Path | None, elsewhere: bool = True, flag: str = "--out",
) -> None:
    """Write ``data`` to ``target`` through a temporary file; on any OS error, remove the
    temporary file, put the source back where it was, and raise one LogError line (which
    suggests --out only where ``elsewhere``: none was given). Nothing is written through a
    symbolic link: the temporary file is created new (``O_EXCL | O_NOFOLLOW``; a link planted
    at its name is refused), and a new ``target`` is put in place only where no name is."""
    tmp = target.with_name(target.name + TEMP_SUFFIX)
    refuse_link(tmp, "the temporary file", LogError)
    moved = False
    try:
        _write_all(tmp, data)
        if backup is not None:
            os.replace(source, backup)  # renames the name: never writes through a link
            moved = True
            os.replace(tmp, target)
        else:
            place_new(tmp, target, flag, LogError)  # a name planted since the check: refused
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
    except LogError:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if moved and backup is not None and not source.exists():
            with contextlib.suppress(OSError):
                os.replace(backup, source)
        where = exc.filename if isinstance(exc.filename, str) else str(tmp)
        fix = "free some space or pass --out to write elsewhere" if elsewhere else (
            f"free some space in {target.parent} or give --out a writable place")
        raise LogError(
            f"{where}: cannot write the recovered log ({exc.strerror or type(exc).__name__}); "
            f"{source} was left as it was: {fix}"
        ) from None


def _records(plan: _Plan, kept: int) -> dict[str, str] | None:
    """Log format 3: the records per topic of the kept chunks as the readers give them (the
    ``lagrseq.records`` metadata); None for a log without columnar records (formats 1 and 2)."""
    topics = {cid: channel.topic for cid, channel in plan.channels.items()}
    if not any(columnar_rows(topic) is not None for topic in topics.values()):
        return None
    counts: dict[str, int] = {}
    for messages in plan.chunks[:kept]:
        for m in messages:
            read_as = columnar_rows(topics[m.channel_id])
            if read_as is None:
                counts[topics[m.channel_id]] = counts.get(topics[m.channel_id], 0) + 1
            else:
                topic, rows = read_as
                counts[topic] = counts.get(topic, 0) + rows(m)
    for topic in topics.values():
        read_as = columnar_rows(topic)
        counts.setdefault(topic if read_as is None else read_as[0], 0)
    return {topic: str(count) for topic, count in counts.items()}


def _write(source: Path, plan: _Plan, kept: int, episodes: int, count: int) -> bytes:
    buffer = io.BytesIO()
    writer = Writer(buffer, compression=CompressionType.ZSTD, chunk_size=1 << 22)
    writer.start(profile=PROFILE, library="lagrseq recover")
    schema_ids = {
        old: writer.register_schema(name=s.name, encoding=s.encoding, data=s.data)
        for old, s in sorted(plan.schemas.items())
    }
    channel_ids = {
        old: writer.register_channel(
            topic=c.topic,
            message_encoding=c.message_encoding,
            schema_id=schema_ids.get(c.schema_id, 0),
            metadata=dict(c.metadata),
        )
        for old, c in sorted(plan.channels.items())
    }
    status: dict[str, str] | None = None
    for record in plan.metadata:
        if record.name == STATUS_METADATA:
            status = dict(record.metadata)
        elif record.name != RECORDS_METADATA:  # worked out again below from what is kept
            writer.add_metadata(record.name, dict(record.metadata))
    records = _records(plan, kept)
    if records is not None:
        writer.add_metadata(RECORDS_METADATA, records)
    for messages in plan.chunks[:kept]:
        for m in messages:
            writer.add_message(
                channel_id=channel_ids[m.channel_id],
                log_time=m.log_time,
                data=m.data,
                publish_time=m.publish_time,
                sequence=m.sequence,
            )
        writer.flush()  # keep the original chunk boundaries: summary chunks stay separate
    if plan.complete and status is not None:
        # The trial wrote all of its data and its own status; only the end of the file was lost.
        status["recovered"] = f"summary rebuilt by lagrseq recover from {source.name}"
    else:
        status = {
            "status": "recovered",
            "error": f"recovered from a truncated log {source.name}: {episodes} episodes kept",
            "messages": str(count),
        }
    writer.add_metadata(STATUS_METADATA, status)
    writer.finish()
    return buffer.getvalue()
