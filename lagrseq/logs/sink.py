"""The MCAP sink: one file per trial, JSON messages with JSON schemas, logical log times.

Log format 3 (:data:`LOG_FORMAT`): an episode's transitions are one ``/transitions`` record
(columns: entry i of each array is step i) and its decisions not to query one ``/no_query``
record; queries that were sent and ``/episode`` summaries stay one record each, pictures
(``/view...``) one per step. Both columnar records are written at the episode's end (when its
``/episode`` record arrives, or at :meth:`McapSink.flush`): the sink buffers the episode, the
loop hands it every record as it comes (:meth:`McapSink.write`). The readers
(:mod:`lagrseq.logs.reader`) expand them into the ``/transition`` and ``/query`` records that
format 2 wrote one message each, and take the expanded counts per topic from the
``lagrseq.records`` metadata written at the end. Framing and indexing a message cost more than
encoding it, so fewer records is what makes logging cheap (``benchmarks/bench_cube.py`` measures
it). ``log_format="2"`` writes format 2 (tests and benchmarks compare the two).

Layout of a file, so that tables are cheap to read: transitions (and pictures) go into chunks of
their own; at each episode end the sink closes the transition chunk and writes that episode's
``/query``, ``/no_query`` and ``/episode`` messages as a separate small chunk. A reader that asks
only for ``/episode`` and ``/query`` (replay's tables, the costs table) then never decompresses a
transition chunk.

Chunks end at episode ends, once the open transition chunk holds :data:`CHUNK_BYTES` of records
(a cube-stacking episode is about 2 KB in format 3, 9 KB in format 2, so about 30 or 7 episodes a
chunk; an episode bigger than that is a chunk of its own), and are then handed to the operating system. Every chunk costs a
fixed amount of work (compression, indexes, a write), which one chunk per episode made about a
third of what logging costs a cube trial.

Crash safety: the file is written as ``NAME.partial`` and renamed when finished. A Ctrl-C
(``abandon``) writes every episode finished before it, as it did when each episode was its own
chunk, and drops the unfinished one. A process killed outright (SIGKILL, power loss) leaves
everything up to the last chunk written, at most :data:`CHUNK_BYTES` of records short of the last
finished episode; ``lagrseq recover`` turns such a file into a valid one. ``finish()`` is
idempotent and records whether the trial completed.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import stat

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: no lock, as before
    fcntl = None  # type: ignore[assignment]
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from lagrseq.errors import LogError
from lagrseq.keys import active as keys_active
from lagrseq.keys import scrub_value
from lagrseq.logs.events import (
    EPISODE_TOPIC,
    NO_QUERY_TOPIC,
    QUERY_TOPIC,
    TRANSITION_TOPIC,
    TRANSITIONS_TOPIC,
    ArmEpisodeEvent,
    EncodedMessage,
    EpisodeEvent,
    Event,
    NotAsked,
    NullSink,
    ProbeQueryEvent,
    QueryEvent,
    Sink,
    Transition,
    View,
    astuple,
    decision_entry,
    encode,
    encode_into,
    no_query_records,
    not_asked,
    transitions_records,
)
from lagrseq.logs.mcap_writer import LeanWriter, Mark
from lagrseq.logs.schemas import SCHEMA_BYTES, TOPICS, TOPICS_3

if TYPE_CHECKING:
    from lagrseq.logs.task_fields import TaskFields

__all__ = ["McapSink", "NullSink", "Sink"]

PROFILE = "lagrseq"
RUN_METADATA = "lagrseq.run"
STATUS_METADATA = "lagrseq.status"
RECORDS_METADATA = "lagrseq.records"
"""Log format 3: the records per topic as the readers give them (``/transition``: steps,
``/query``: decisions, ``/episode``, pictures), so counts need no message read."""
PARTIAL_SUFFIX = ".partial"
LOG_FORMAT = "4"
"""The log format, written as ``log_format`` in the ``lagrseq.run`` metadata. 4: format 3 whose
``/query`` records carry ``prompt`` and ``outcome`` and ``/episode`` records
``cut_by_step_budget`` (``docs/logs.md``). 3: an episode's
transitions and its decisions not to query are one columnar record each (``/transitions``,
``/no_query``); 2: one record per transition and per decision, ``/query`` records leave out the
fields at their default (:class:`~lagrseq.logs.events.QueryEvent`); 1 (no ``log_format``): every
field written. Readers take all four and give the same records."""
LOG_FORMATS = ("2", "3", "4")
"""The formats the sink writes (``McapSink(log_format=...)``)."""

CHUNK_BYTES = 64 * 1024
"""An episode's end closes the open chunks once the transition chunk holds this many bytes of
message records. Measured on cube LaGR-SEQ trials (``benchmarks/bench_cube.py``, paired): a chunk
per episode put logging at +33%; every 4 episodes (about 36 KB) +23%, every 8 (about 72 KB) +19%."""

_HUGE = float("inf")
_dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def _encode(record: dict[str, Any]) -> bytes:
    try:
        return _dumps(record).encode()
    except (TypeError, ValueError) as exc:
        raise LogError(f"record is not JSON-serialisable ({exc}): {sorted(record)}") from None


def _finite(event: Any, fields: tuple[str, ...]) -> None:
    """JSON holds no NaN or infinity (msgspec would write null): refuse them by name."""
    for name in fields:
        value = getattr(event, name)
        if value is not None and not math.isfinite(value):
            raise LogError(f"record is not JSON-serialisable (field {name} = {value}): {type(event).__name__}")


_QUERY_FLOATS = ("evaluation", "query_reward", "temperature", "cost_usd", "latency_s")
_EPISODE_FLOATS = ("return_", "epsilon")


_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_BUFFER_BYTES = 64 * 1024
"""The file's write buffer: a chunk and its message indexes go to the operating system in one
write when the sink pushes them (a few writes a trial, not one per record)."""


def _scrubbed(event: Any) -> Any:
    """A query event with the guarded API keys blanked out of its text fields."""
    changes = {name: scrub_value(value) for name in _QUERY_TEXT if (value := getattr(event, name, None)) is not None}
    changes = {name: value for name, value in changes.items() if value != getattr(event, name)}
    return msgspec.structs.replace(event, **changes) if changes else event


_QUERY_TEXT = ("answer", "parse_error", "provider", "model", "record_key", "finish_reason", "system_fingerprint", "solution")


def _refuse_link(path: Path) -> None:
    """A LogError when ``path`` is a symbolic link (planted in a shared output folder: writing
    through it, or renaming onto it, would put the log over someone's file)."""
    if os.path.islink(path):
        raise LogError(
            f"{path} is a symbolic link; lagrseq never writes a log through a link: remove the link "
            "or give another --out"
        )


def _still_named(descriptor: int, partial: Path) -> bool:
    """Whether ``partial`` still names the open file ``descriptor``: a writer renames its file to
    the log's name before it lets go of the lock, so a file found renamed is a finished log."""
    try:
        named = os.lstat(partial)
    except FileNotFoundError:
        return False
    opened = os.fstat(descriptor)
    return (named.st_dev, named.st_ino) == (opened.st_dev, opened.st_ino)


def _open_exclusive(partial: Path) -> Any:
    """``partial`` opened for writing from scratch, locked against a second lagrseq process that
    would write the same trial (two identical runs at once): that one is refused, and the file
    the first is writing is never truncated under it. A ``.partial`` left by a crash is not
    locked, so a rerun writes it anew. Opened with ``O_NOFOLLOW``: a symbolic link planted under
    the name is refused (one line), never written through; so is anything but a regular file,
    and a file with other hard links (a link planted to someone's file)."""
    try:
        descriptor = os.open(partial, os.O_RDWR | os.O_CREAT | _NOFOLLOW | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NONBLOCK", 0), 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP or os.path.islink(partial):
            _refuse_link(partial)
        raise
    try:
        info = os.fstat(descriptor)
        if not stat.S_ISREG(info.st_mode) or info.st_nlink > 1:
            what = "has other hard links" if stat.S_ISREG(info.st_mode) else "is not a regular file"
            raise LogError(f"{partial} {what}; lagrseq writes a log only into a file of its own: remove it or give another --out")
        if hasattr(os, "set_blocking"):
            os.set_blocking(descriptor, True)
        if fcntl is not None:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if not _still_named(descriptor, partial):  # its writer finished it meanwhile: a log now
                raise BlockingIOError
        if os.fstat(descriptor).st_size:  # a crash's leftover (truncating a new, empty file costs a journal entry)
            os.ftruncate(descriptor, 0)
    except BlockingIOError:
        os.close(descriptor)
        raise LogError(
            f"{partial} is being written by another lagrseq process; wait for it to finish "
            "(a rerun then skips the trial) or give another --out or --name"
        ) from None
    except BaseException:
        os.close(descriptor)
        raise
    return os.fdopen(descriptor, "wb", buffering=_BUFFER_BYTES)


class McapSink:
    """Write one trial's events. Use as a context manager; ``write(topic, record, log_time)``."""

    def __init__(
        self,
        path: str | Path,
        metadata: dict[str, str],
        extra_topics: dict[str, tuple[str, str, bytes]] | None = None,
        chunk_bytes: int = CHUNK_BYTES,
        log_format: str = LOG_FORMAT,
        task_fields: TaskFields | None = None,
    ) -> None:
        """``chunk_bytes``: an episode's end writes the open chunks once the transition chunk
        holds this many bytes (0: at every episode's end). ``log_format``: ``"3"`` (columnar
        episodes) or ``"2"`` (a record per transition and per decision). ``task_fields``: the
        records and schemas of a task that logs fields of its own (None: lagrseq's)."""
        if log_format not in LOG_FORMATS:
            raise LogError(f"log format {log_format!r} cannot be written; expected one of {', '.join(LOG_FORMATS)}")
        self.path = Path(path)
        self._chunk_bytes = chunk_bytes
        self._columnar = log_format != "2"
        self.partial = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        if not self.path.parent.is_dir():  # one stat where the folder exists (every trial but the first)
            self.path.parent.mkdir(parents=True, exist_ok=True)
        _refuse_link(self.path)
        self._stream = _open_exclusive(self.partial)
        self._writer = LeanWriter(self._stream, library="lagrseq", profile=PROFILE)
        self._channels: dict[str, int] = {}
        for topic, schema in (TOPICS_3 if self._columnar else TOPICS).items():
            data = SCHEMA_BYTES[schema["title"]] if task_fields is None else task_fields.schema(schema["title"])
            schema_id = self._writer.register_schema(name=schema["title"], encoding="jsonschema", data=data)
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        for topic, (name, encoding, data) in (extra_topics or {}).items():
            schema_id = self._writer.register_schema(name=name, encoding=encoding, data=data)
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        self._transition_channel = self._channels[TRANSITIONS_TOPIC if self._columnar else TRANSITION_TOPIC]
        self._query_channel = self._channels[QUERY_TOPIC]
        self._no_query_channel = self._channels.get(NO_QUERY_TOPIC, 0)
        self._episode_channel = self._channels[EPISODE_TOPIC]
        # A task's own record types (None: it has none, and only lagrseq's types are taken)
        self._task_transition = None if task_fields is None or task_fields.transition is Transition else task_fields.transition
        self._task_episode = None if task_fields is None or task_fields.episode is EpisodeEvent else task_fields.episode
        # the metadata holds the config (a base URL, a model name: text a user gave) and every
        # query the answer a server sent: the guarded API keys are blanked out of both
        self._writer.add_metadata(RUN_METADATA, scrub_value({**metadata, "log_format": log_format}))
        # Format 3: the current episode's transitions and decisions not to query, held until
        # its end, when each becomes one columnar record.
        self._steps: list[Transition] = []
        self._not_asked: list[NotAsked] = []
        """Format 3: the episode's decisions not to query (made entries at its end, in one pass)."""
        self._expanded = {TRANSITION_TOPIC: 0, QUERY_TOPIC: 0}
        """Format 3: records written inside columnar ones, per topic the readers give them as."""
        # Transitions and pictures of the current episode go straight into the writer's open
        # chunk (encoded into it, in order); the chunk is written at the episode's end.
        self._pending: list[tuple[int, int, bytes]] = []
        """Queries and episodes held until the chunks are written: (channel id, log time, data)."""
        self._episode_end: tuple[Mark, int] = (self._writer.mark(), 0)
        """Where the open chunk and the held messages stood at the last episode's end."""
        self._writing = False
        self._finished = False
        self._guarded: bool | None = None
        """Whether an API key is guarded (:func:`lagrseq.keys.active`), read at each episode's
        first query (None: not yet read in this episode), not at every query: reading the
        environment costs about a microsecond, a fifth of what logging a query costs."""

    def write(self, event: Event) -> None:
        """Add one event. Transitions and pictures go to the current chunk; queries and episodes
        are held until the chunks are written, then go into a chunk of their own. Format 3: an
        episode's transitions and decisions not to query are held until its ``/episode`` record
        (or :meth:`flush`) and then written as one columnar record each. An ``/episode`` record
        ends its episode: from then on a Ctrl-C keeps it (:meth:`abandon`)."""
        kind = type(event)
        try:
            if kind is Transition or kind is self._task_transition:
                reward = event.reward  # type: ignore[union-attr]
                # finite: x - x is 0.0; NaN and the infinities give NaN. One operation a step
                # (timeit: about 38 ns against 54 for the chained comparison with -inf and inf)
                if reward - reward != 0.0:
                    _finite(event, ("reward",))
                if self._columnar:
                    self._steps.append(event)  # type: ignore[arg-type]
                else:
                    self._writer.append_encoded(self._transition_channel, event.global_step, event, encode_into)  # type: ignore[union-attr]
                return
            if kind is NotAsked:
                if self._columnar:
                    self._not_asked.append(event)  # type: ignore[arg-type]
                else:
                    self.write(QueryEvent(*astuple(event), decision=0))  # type: ignore[arg-type, misc]
                return
            if kind is QueryEvent or kind is ProbeQueryEvent:
                # a query asked (decision 1, what every QueryEvent the loop writes is) is no
                # /no_query entry: its decision alone says so, without a look at every field
                if self._columnar and event.decision == 0 and not_asked(event):  # type: ignore[union-attr, arg-type]
                    self._not_asked.append(NotAsked(*decision_entry(event)))
                    return
                e = event
                for value in (e.evaluation, e.query_reward, e.temperature, e.cost_usd, e.latency_s):  # type: ignore[union-attr]
                    if value is not None and not -_HUGE < value < _HUGE:
                        _finite(event, _QUERY_FLOATS)
                guarded = self._guarded
                if guarded is None:  # the episode's first query
                    guarded = self._guarded = keys_active()
                if guarded:
                    event = _scrubbed(event)  # type: ignore[arg-type]
                self._pending.append((self._query_channel, event.global_step, encode(event)))  # type: ignore[union-attr]
                return
            if kind is EpisodeEvent or kind is ArmEpisodeEvent or kind is self._task_episode:
                total, epsilon = event.return_, event.epsilon  # type: ignore[union-attr]
                # x - x is 0.0 for a finite float, NaN (true) for NaN and the infinities
                if type(total) is not float or type(epsilon) is not float or total - total or epsilon - epsilon:
                    _finite(event, _EPISODE_FLOATS)
                self._write_columns()  # the episode's columnar records go before its summary
                self._pending.append((self._episode_channel, max(event.global_step - 1, 0), encode(event)))  # type: ignore[union-attr]
                self._end_episode()
                return
        except (TypeError, ValueError, OverflowError) as exc:
            raise LogError(f"record is not JSON-serialisable ({exc}): {kind.__name__}") from None
        if kind is View:
            message = event.message  # type: ignore[union-attr]
            data = message.json if type(message) is EncodedMessage else _encode(message)
            self._writer.add_message(self._channels[event.topic], event.log_time, data)  # type: ignore[union-attr]
        else:
            raise LogError(f"cannot log a {kind.__name__}; expected Transition, QueryEvent, NotAsked, EpisodeEvent or View")

    def _write_columns(self) -> None:
        """Format 3: the held transitions into the open chunk and the held decisions not to
        query into the held messages, one columnar record per episode (log time: the global
        step of its first entry). What cannot be encoded is dropped with a LogError; nothing
        else is lost."""
        steps, not_asked = self._steps, self._not_asked
        if not steps and not not_asked:
            return
        self._steps, self._not_asked = [], []
        try:
            if steps:
                for record in transitions_records(steps):  # encoded straight into the open chunk
                    self._writer.append_encoded(self._transition_channel, record["global_step"][0], record, encode_into)
                self._expanded[TRANSITION_TOPIC] += len(steps)
            if not_asked:
                for record in no_query_records(list(map(astuple, not_asked))):
                    self._pending.append((self._no_query_channel, record["global_step"][0], encode(record)))
                self._expanded[QUERY_TOPIC] += len(not_asked)
        except (TypeError, ValueError, OverflowError) as exc:
            raise LogError(f"record is not JSON-serialisable ({exc}): an episode's Transition or QueryEvent") from None

    def write_record(self, topic: str, record: dict[str, Any], log_time: int) -> None:
        """Add one JSON object to ``topic`` as it is (tools and tests that write their own), the
        guarded API keys blanked out of its strings."""
        if topic not in self._channels:
            raise LogError(f"topic {topic!r} is not registered in {self.path.name}")
        if keys_active() and topic not in (TRANSITION_TOPIC, TRANSITIONS_TOPIC):
            record = scrub_value(record)
        if topic in (TRANSITIONS_TOPIC, NO_QUERY_TOPIC):  # count what the readers will expand
            column = record.get("global_step")
            self._expanded[TRANSITION_TOPIC if topic == TRANSITIONS_TOPIC else QUERY_TOPIC] += len(column) if isinstance(column, list) else 0
        if topic in (TRANSITION_TOPIC, TRANSITIONS_TOPIC) or topic.startswith("/view"):
            self._writer.add_message(self._channels[topic], log_time, _encode(record))
        else:
            self._pending.append((self._channels[topic], log_time, _encode(record)))

    @property
    def messages(self) -> int:
        """Messages written so far (every topic)."""
        return self._writer.messages

    def records(self) -> dict[str, str]:
        """Records written so far per topic as the readers give them (format 3's columnar
        records counted as the transitions and decisions they hold): the ``lagrseq.records``
        metadata."""
        counts = self._writer.channel_counts()
        columnar = {self._transition_channel, self._no_query_channel} if self._columnar else set()
        out = {TRANSITION_TOPIC: self._expanded[TRANSITION_TOPIC], QUERY_TOPIC: self._expanded[QUERY_TOPIC]}
        for topic, channel in self._channels.items():
            if channel not in columnar:
                out[topic] = out.get(topic, 0) + counts.get(channel, 0)
        return {topic: str(count) for topic, count in out.items()}

    def flush(self) -> None:
        """End an episode that has no ``/episode`` record (a tool's own records): write its
        columnar records and what :meth:`write` of an ``/episode`` record writes after it."""
        self._write_columns()
        self._end_episode()

    def _end_episode(self) -> None:
        """Once the open transition chunk holds ``chunk_bytes``, close it, write the held
        messages as a chunk of their own and push everything to the operating system;
        otherwise remember where the episode ended (for :meth:`abandon`)."""
        if self._writer.chunk_size >= self._chunk_bytes:
            self._write_chunks()
        self._episode_end = (self._writer.mark(), len(self._pending))
        self._guarded = None

    def _write_chunks(self) -> None:
        """Close the transition chunk, write the held messages as their own chunk, and push
        everything to the operating system."""
        self._writing = True
        self._writer.flush(push=not self._pending)
        if self._pending:
            self._writer.add_messages(self._pending)
            self._pending.clear()
            self._writer.flush()
        self._writing = False

    def finish(self, status: str = "complete", error: str = "") -> Path:
        """Write the summary and rename the file to its final name (idempotent)."""
        if self._finished:
            return self.path
        self._finished = True
        try:
            self._write_columns()
            self._write_chunks()
            if self._columnar:
                self._writer.add_metadata(RECORDS_METADATA, self.records())
            self._writer.add_metadata(
                STATUS_METADATA, scrub_value({"status": status, "error": error, "messages": str(self.messages)})
            )
            self._writer.finish()
            _refuse_link(self.path)  # planted while the trial ran: the log stays NAME.partial
            # renamed while the file is still locked (the lock goes when it is closed): a second
            # lagrseq process that opens NAME.partial from now on makes a file of its own, and
            # one that opened it before finds it renamed once it holds the lock
            os.replace(self.partial, self.path)  # rename replaces a name, never writes through a link
        finally:
            self._stream.close()
        return self.path

    def abandon(self) -> None:
        """Ctrl-C: write every episode finished so far, drop the unfinished one and leave
        ``NAME.partial`` (``lagrseq recover`` makes it a valid log; a rerun writes it anew)."""
        if self._finished:
            return
        self._finished = True
        with contextlib.suppress(OSError):
            if not self._writing:  # interrupted inside a chunk's write: leave the file as it is
                mark, held = self._episode_end
                self._writer.rollback(mark)
                del self._pending[held:]
                self._steps, self._not_asked = [], []  # the unfinished episode's
                self._write_chunks()
            self._stream.close()

    def close(self) -> None:
        """Finish a trial that ended normally (idempotent)."""
        self.finish()

    def __enter__(self) -> McapSink:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):  # Ctrl-C, SIGTERM
            self.abandon()
            return
        try:
            if exc_type is None:
                self.finish()
            else:
                self.finish("failed", f"{exc_type.__name__}: {exc}")
        except OSError as error:  # a full disk, a file-size limit: one line naming the file
            raise self._cannot_write(error) from None
        if isinstance(exc, OSError) and exc.filename is None:  # the trial's own write failed
            raise self._cannot_write(exc) from None

    def _cannot_write(self, error: OSError) -> LogError:
        reason = error.strerror or type(error).__name__
        return LogError(
            f"{self.partial}: cannot write the log ({reason}); it keeps the episodes written before "
            f"(`lagrseq recover` makes them a log) and no file named {self.path.name} was made: "
            "free some space and run the same command again"
        )
