"""The MCAP sink: one file per trial, JSON messages with JSON schemas, logical log times.

Log format 3 (:data:`LOG_FORMAT`): an episode's transitions are one ``/transitions`` record
(columns: entry i of each array is step i) and its decisions not to query one ``/no_query``
record; queries that were sent and ``/episode`` summaries stay one record each, pictures
(``/view...``) one per step. The loop hands the sink every event as it comes
(:meth:`McapSink.write`); the sink holds an episode until its ``/episode`` record (or
:meth:`McapSink.flush`) ends it. The readers (:mod:`lagrseq.logs.reader`) expand the columnar
records into the ``/transition`` and ``/query`` records that format 2 wrote one message each, and
take the expanded counts per topic from the ``lagrseq.records`` metadata written at the end.
Framing and indexing a message cost more than encoding it, so fewer records is what makes
logging cheap (``benchmarks/bench_cube.py`` measures it). ``log_format="2"`` writes format 2
(tests and benchmarks compare the two).

Layout of a file, so that tables are cheap to read: transitions (and pictures) go into chunks of
their own, and each is followed by a chunk of the same episodes' ``/query``, ``/no_query`` and
``/episode`` messages. A reader that asks only for ``/episode`` and ``/query`` (replay's tables,
the costs table) then never decompresses a transition chunk.

Chunks end at episode ends, once the transition chunk holds :data:`CHUNK_BYTES` of records (an
episode bigger than that is a chunk of its own), and are then handed to the operating system.
Finished episodes are encoded many at a time, not one by one: they wait until their transitions
would take :data:`BATCH_BYTES`, then are encoded in order in one pass, and each chunk ends after
the first episode that fills it, as it would had each episode been encoded at its end: the same
bytes. One pass over many episodes costs less than a pass each.

Crash safety: the file is written as ``NAME.partial`` and renamed when finished. A Ctrl-C
(``abandon``) writes every episode finished before it and drops the unfinished one. A process
killed outright (SIGKILL, power loss) leaves everything up to the last chunk written: the
finished episodes after it, up to about :data:`BATCH_BYTES` of transitions, are lost;
``lagrseq recover`` turns such a file into a valid one. ``finish()`` is idempotent and records
whether the trial completed.
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
from typing import TYPE_CHECKING, Any, NamedTuple

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
"""An episode's end writes the open chunk, then the held messages as a chunk of their own, once
the open chunk holds this many bytes of transition records (format 3: about 30 cube-stacking
episodes)."""
BATCH_BYTES = 256 * 1024
"""Finished episodes wait to be encoded until their transitions would take this many bytes (at
the bytes a step has taken so far), then are encoded in one pass, each chunk ending where
:data:`CHUNK_BYTES` ends it. One pass over many episodes costs less than one each
(``benchmarks/bench_cube.py`` measures the logging's cost); a process killed outright loses the
finished episodes not yet written, up to about this many bytes of transitions. A task that logs
pictures encodes each episode before the next one's first picture (the file keeps its order)."""

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


class _Kept(NamedTuple):
    """What a Ctrl-C keeps (:meth:`McapSink.abandon`), as it stood at the last episode's end:
    where the writer's chunks stood; the number of held messages (queries, decisions not to
    query, summaries) of finished episodes, counted from the trial's first; and the finished
    episodes whose transitions are not encoded yet, each with the number of its first held
    message."""

    chunks: Mark
    messages: int
    episodes: tuple[tuple[list[Any], int], ...] = ()


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
        self._pending: list[tuple[int, int, Any]] = []
        """The messages of the chunk after the transitions' (queries, decisions not to query,
        episode summaries), not yet encoded: (channel id, log time, item), in order; an item is
        an event, an episode's list of NotAsked (its ``/no_query`` record) or encoded bytes."""
        self._pending_from = 0
        """The number of the first message in ``_pending``, counted from the trial's first."""
        self._kept = _Kept(self._writer.mark(), 0)
        self._held_steps = 0
        """Steps of the finished episodes whose transitions are not encoded yet."""
        self._step_bytes = (0, 0)
        """Bytes and steps of the transitions encoded so far: what a step takes."""
        self._failure: LogError | None = None
        """The first record that could not be encoded since the last check (it was dropped)."""
        self._writing = False
        self._finished = False

    def write(self, event: Event) -> None:
        """Add one event. Pictures (and format 2's transitions) go to the open chunk; queries and
        episode summaries are held until the chunks are written, then go into a chunk of their
        own. Format 3: an episode's transitions and decisions not to query are held, to become
        one columnar record each, encoded with other finished episodes' (the module docstring).
        An ``/episode`` record ends its episode: from then on a Ctrl-C keeps it (:meth:`abandon`).
        A non-finite number is refused here; a record that cannot be encoded is dropped with a
        LogError when it is encoded."""
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
                # one sum: finite where every value is (NaN, an infinity or an overflow is not,
                # and then each value is looked at); 5 comparisons each cost as much
                total = (e.evaluation or 0.0) + (e.query_reward or 0.0) + (e.temperature or 0.0) + (e.cost_usd or 0.0) + (e.latency_s or 0.0)  # type: ignore[union-attr]
                if total - total != 0.0:
                    _finite(event, _QUERY_FLOATS)
                self._pending.append((self._query_channel, event.global_step, event))  # type: ignore[union-attr]
                return
            if kind is EpisodeEvent or kind is ArmEpisodeEvent or kind is self._task_episode:
                total, epsilon = event.return_, event.epsilon  # type: ignore[union-attr]
                # x - x is 0.0 for a finite float, NaN (true) for NaN and the infinities
                if type(total) is not float or type(epsilon) is not float or total - total or epsilon - epsilon:
                    _finite(event, _EPISODE_FLOATS)
                self._end_episode((self._episode_channel, max(event.global_step - 1, 0), event))  # type: ignore[union-attr]
                return
        except (TypeError, ValueError, OverflowError) as exc:
            raise LogError(f"record is not JSON-serialisable ({exc}): {kind.__name__}") from None
        if kind is View:
            message = event.message  # type: ignore[union-attr]
            data = message.json if type(message) is EncodedMessage else _encode(message)
            if self._kept.episodes:  # the finished episodes' transitions go before this picture
                self._encode_steps()
                self._raise_failure()
            self._writer.add_message(self._channels[event.topic], event.log_time, data)  # type: ignore[union-attr]
        else:
            raise LogError(f"cannot log a {kind.__name__}; expected Transition, QueryEvent, NotAsked, EpisodeEvent or View")

    def write_record(self, topic: str, record: dict[str, Any], log_time: int) -> None:
        """Add one JSON object to ``topic`` as it is (tools and tests that write their own), the
        guarded API keys blanked out of its strings."""
        if topic not in self._channels:
            raise LogError(f"topic {topic!r} is not registered in {self.path.name}")
        if keys_active() and topic not in (TRANSITION_TOPIC, TRANSITIONS_TOPIC):
            record = scrub_value(record)
        data = _encode(record)
        if topic in (TRANSITIONS_TOPIC, NO_QUERY_TOPIC):  # count what the readers will expand
            column = record.get("global_step")
            self._expanded[TRANSITION_TOPIC if topic == TRANSITIONS_TOPIC else QUERY_TOPIC] += len(column) if isinstance(column, list) else 0
        if topic in (TRANSITION_TOPIC, TRANSITIONS_TOPIC) or topic.startswith("/view"):
            self._encode_steps()  # the finished episodes' transitions go before it
            self._raise_failure()
            self._writer.add_message(self._channels[topic], log_time, data)
        else:
            self._pending.append((self._channels[topic], log_time, data))

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
        """End an episode that has no ``/episode`` record (a tool's own records): what
        :meth:`write` of an ``/episode`` record does, without that record."""
        self._end_episode(None)

    def _end_episode(self, summary: tuple[int, int, Any] | None) -> None:
        """The current episode is finished, and from here on a Ctrl-C keeps it: its decisions
        not to query and its summary join the held messages, its transitions the finished
        episodes. Once those would take :data:`BATCH_BYTES` (or the open chunk is full), they
        are encoded, and written chunk by chunk."""
        steps, not_asked = self._steps, self._not_asked
        self._steps, self._not_asked = [], []
        if not_asked:
            self._pending.append((self._no_query_channel, not_asked[0].global_step, not_asked))
        if summary is not None:
            self._pending.append(summary)
        kept = self._kept
        episodes = (*kept.episodes, (steps, kept.messages)) if steps else kept.episodes
        # one assignment: the open chunk (pictures, format 2's transitions) and the held
        # messages so far are the finished episodes'
        self._kept = _Kept(self._writer.mark(), self._pending_from + len(self._pending), episodes)
        self._held_steps += len(steps)
        if self._held_bytes() >= BATCH_BYTES or self._writer.chunk_size >= self._chunk_bytes:
            self._encode_steps(episode_end=True)
        self._raise_failure()

    def _held_bytes(self) -> float:
        """The bytes the finished episodes' transitions not encoded yet will take: each step at
        the bytes a step took so far (infinite before the first is encoded)."""
        if not self._held_steps:
            return 0
        encoded, steps = self._step_bytes
        return self._held_steps * encoded / steps if steps else math.inf

    def _encode_steps(self, final: bool = False, episode_end: bool = False) -> None:
        """Encode the finished episodes' transitions into the open chunk, one columnar record
        each, in order (many episodes in one pass cost less than one at a time). At an
        episode's end where the open chunk holds ``chunk_bytes`` (and, with ``final``, at the
        last), the chunk is written, then the held messages up to that episode's end as a chunk
        of their own. ``episode_end``: called as an episode ends (a format-2 log holds no
        episodes back). A Ctrl-C in between finds ``_kept`` as it was and encodes them again."""
        writer, kept = self._writer, self._kept
        episodes = kept.episodes
        for index, (steps, _) in enumerate(episodes):
            self._encode_columns(steps)
            if writer.chunk_size >= self._chunk_bytes:  # the chunk ends with this episode
                rest = episodes[index + 1 :]
                self._write_chunks(rest[0][1] if rest else kept.messages, rest)
        self._held_steps = 0
        if final or (episode_end and writer.chunk_size >= self._chunk_bytes):
            self._write_chunks(kept.messages, ())
        elif self._kept.episodes:  # every one encoded; the chunk stays open
            self._kept = _Kept(writer.mark(), kept.messages)

    def _encode_columns(self, steps: list[Any]) -> None:
        """One episode's transitions as ``/transitions`` records into the open chunk (format 3;
        log time: the global step of its first). What cannot be encoded is dropped (a
        LogError, raised once the episodes at hand are written); nothing else is lost."""
        writer = self._writer
        size = writer.chunk_size
        try:
            for record in transitions_records(steps):
                writer.append_encoded(self._transition_channel, record["global_step"][0], record, encode_into)
        except (TypeError, ValueError, OverflowError) as exc:
            self._fail(exc, "an episode's Transition")
            return
        self._expanded[TRANSITION_TOPIC] += len(steps)
        encoded, count = self._step_bytes
        self._step_bytes = (encoded + writer.chunk_size - size, count + len(steps))

    def _write_chunks(self, end: int, rest: tuple[tuple[list[Any], int], ...]) -> None:
        """Write the open chunk, then the held messages numbered below ``end`` as a chunk of
        their own, and push both to the operating system; ``rest``: the finished episodes whose
        transitions are still to encode."""
        count = end - self._pending_from
        self._encode_messages(self._pending[:count])
        self._writing = True
        self._writer.flush()
        del self._pending[:count]
        self._pending_from = end
        self._kept = _Kept(self._writer.mark(), self._kept.messages, rest)
        self._writing = False

    def _encode_messages(self, items: list[tuple[int, int, Any]]) -> None:
        """Held messages into the writer's held chunk: events encoded (a query with the guarded
        API keys blanked out), an episode's decisions not to query as one ``/no_query``
        record, bytes as they are."""
        writer, queries = self._writer, self._query_channel
        guarded = keys_active()  # read once a chunk: reading the environment costs a microsecond
        for channel, log_time, item in items:
            kind = type(item)
            try:
                if kind is bytes:
                    writer.add_message(channel, log_time, item, held=True)
                elif kind is list:
                    for record in no_query_records(list(map(astuple, item))):
                        writer.append_encoded(channel, record["global_step"][0], record, encode_into, held=True)
                    self._expanded[QUERY_TOPIC] += len(item)
                else:
                    if guarded and channel == queries:
                        item = _scrubbed(item)
                    writer.append_encoded(channel, log_time, item, encode_into, held=True)
            except (TypeError, ValueError, OverflowError) as exc:
                self._fail(exc, "an episode's QueryEvent" if kind is list else kind.__name__)

    def _fail(self, exc: Exception, what: str) -> None:
        if self._failure is None:
            self._failure = LogError(f"record is not JSON-serialisable ({exc}): {what}")

    def _raise_failure(self) -> None:
        failure, self._failure = self._failure, None
        if failure is not None:
            raise failure

    def finish(self, status: str = "complete", error: str = "") -> Path:
        """Write the summary and rename the file to its final name (idempotent). A record that
        could not be encoded at the end is dropped, the log says ``failed`` and the LogError is
        raised once the file is renamed."""
        if self._finished:
            return self.path
        self._finished = True
        failure = None
        try:
            try:
                self._end_episode(None)  # what the last episode left without its /episode record
                self._encode_steps(final=True)
                self._raise_failure()
            except LogError as exc:  # that record was dropped; everything else is written
                failure = exc
                self._encode_steps(final=True)
                if status == "complete":
                    status, error = "failed", f"LogError: {exc}"
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
        if failure is not None:
            raise failure
        return self.path

    def abandon(self) -> None:
        """Ctrl-C: write every episode finished so far, drop the unfinished one and leave
        ``NAME.partial`` (``lagrseq recover`` makes it a valid log; a rerun writes it anew)."""
        if self._finished:
            return
        self._finished = True
        with contextlib.suppress(OSError):
            if not self._writing:  # interrupted inside a chunk's write: leave the file as it is
                kept = self._kept
                self._writer.rollback(kept.chunks)  # what the unfinished episode added
                del self._pending[kept.messages - self._pending_from :]
                self._steps, self._not_asked = [], []
                self._encode_steps(final=True)
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
