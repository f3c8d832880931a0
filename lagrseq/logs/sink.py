"""The MCAP sink: one file per trial, JSON messages with JSON schemas, logical log times.

Layout of a file, so that tables are cheap to read: transitions go into chunks of their own; at
each episode end the sink closes the transition chunk and writes that episode's ``/query`` and
``/episode`` messages as a separate small chunk. A reader that asks only for ``/episode`` and
``/query`` (replay's tables, the costs table) then never decompresses a transition chunk.

Crash safety: the file is written as ``NAME.partial`` and renamed when finished; everything up to
the last episode flush is on disk, and ``lagrseq recover`` turns a crash-truncated file into a
valid one. ``finish()`` is idempotent and records whether the trial completed.
"""

from __future__ import annotations

import contextlib
import json
import math
import os

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: no lock, as before
    fcntl = None  # type: ignore[assignment]
from pathlib import Path
from typing import Any

from lagrseq.errors import LogError
from lagrseq.logs.events import (
    EPISODE_TOPIC,
    QUERY_TOPIC,
    TRANSITION_TOPIC,
    EpisodeEvent,
    Event,
    NullSink,
    QueryEvent,
    Sink,
    Transition,
    View,
    to_record,
)

__all__ = ["McapSink", "NullSink", "Sink"]
from lagrseq.logs.mcap_writer import LeanWriter
from lagrseq.logs.schemas import TOPICS, schema_bytes

PROFILE = "lagrseq"
RUN_METADATA = "lagrseq.run"
STATUS_METADATA = "lagrseq.status"
PARTIAL_SUFFIX = ".partial"

_dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def _encode(record: dict[str, Any]) -> bytes:
    try:
        return _dumps(record).encode()
    except (TypeError, ValueError) as exc:
        raise LogError(f"record is not JSON-serialisable ({exc}): {sorted(record)}") from None


_HEAD = b'{"trial":%d,"episode":%d,"step":%d,"global_step":%d,'
_BOOL = {True: "true", False: "false"}
_CACHE_LIMIT = 100_000
"""Most distinct tails memoised per process (cube stacks and their rewards repeat all the time)."""


def _flat_ints(state: Any) -> bool:
    """Whether ``state`` is a flat tuple or list of ints (what the fast encoders format)."""
    return isinstance(state, (tuple, list)) and (not state or type(state[0]) is int)


def _state_text(state: tuple[int, ...] | list[int]) -> str:
    return "[" + ",".join(map(str, state)) + "]"


_TRANSITION_TAILS: dict[tuple[Any, ...], bytes] = {}


def _transition_tail(event: Transition) -> bytes | None:
    """The JSON of a transition from ``state`` on, or None when it needs the slow path."""
    _, _, _, _, state, action, reward, terminated, truncated, guided = event
    if type(reward) is not float or not math.isfinite(reward) or not _flat_ints(state) or type(action) is not int:
        return None
    return (
        f'"state":{_state_text(state)},"action":{action},"reward":{reward!r},"terminated":{_BOOL[terminated]},'
        f'"truncated":{_BOOL[truncated]},"guided":{_BOOL[guided]}}}'
    ).encode()


def _encode_transition(event: Transition) -> bytes:
    """The hot path: one transition per environment step. The same bytes as ``_encode``, several
    times faster: the part from ``state`` on repeats (a cube trial meets a few hundred distinct
    ones) and is memoised; anything unusual (grids' nested states, a non-finite reward) takes
    the slow path, which also refuses what JSON cannot hold."""
    key = event[4:]
    try:
        tail = _TRANSITION_TAILS[key] if type(event[6]) is float else None
    except KeyError:
        tail = _transition_tail(event)
        if tail is not None and len(_TRANSITION_TAILS) < _CACHE_LIMIT:
            _TRANSITION_TAILS[key] = tail
    except TypeError:  # an unhashable state: a grid's nested lists
        tail = None
    if tail is None:
        return _encode(to_record(event))
    return _HEAD % event[:4] + tail


# A decision not to query (most /query messages): every field after ``decision`` is at its
# default except ``query_reward``, so the JSON from ``state`` on depends on (state, decision,
# query_reward) alone and is memoised like a transition's.
_QUERY_FIELDS = QueryEvent._fields[:-1]  # the contract's; ``extra`` follows them
_REWARD_AT = QueryEvent._fields.index("query_reward")
_SKIP_HEAD = QueryEvent(0, 0, 0, 0, (), 0)[6:_REWARD_AT]
_SKIP_TAIL = QueryEvent(0, 0, 0, 0, (), 0)[_REWARD_AT + 1 :]
_SKIP_MIDDLE = ",".join(f'"{k}":{json.dumps(v)}' for k, v in zip(_QUERY_FIELDS[6:_REWARD_AT], _SKIP_HEAD))
_SKIP_END = ",".join(f'"{k}":{json.dumps(v)}' for k, v in zip(_QUERY_FIELDS[_REWARD_AT + 1 :], _SKIP_TAIL))
_SKIP_TAILS: dict[tuple[Any, ...], bytes] = {}


def _skip_tail(event: QueryEvent) -> bytes | None:
    state, decision, reward = event[4], event[5], event[_REWARD_AT]
    if type(reward) is not float or not math.isfinite(reward) or not _flat_ints(state) or type(decision) is not int:
        return None
    return (
        f'"state":{_state_text(state)},"decision":{decision},{_SKIP_MIDDLE},"query_reward":{reward!r},{_SKIP_END}}}'
    ).encode()


def _encode_query(event: QueryEvent) -> bytes:
    """A decision not to query through the memoised tail; every other record through json."""
    if event[6:_REWARD_AT] != _SKIP_HEAD or event[_REWARD_AT + 1 :] != _SKIP_TAIL:
        return _encode(to_record(event))
    key = (event[4], event[5], event[_REWARD_AT])
    try:
        tail = _SKIP_TAILS[key] if type(event[_REWARD_AT]) is float else None
    except KeyError:
        tail = _skip_tail(event)
        if tail is not None and len(_SKIP_TAILS) < _CACHE_LIMIT:
            _SKIP_TAILS[key] = tail
    except TypeError:
        tail = None
    if tail is None:
        return _encode(to_record(event))
    return _HEAD % event[:4] + tail


def _open_exclusive(partial: Path) -> Any:
    """``partial`` opened for writing from scratch, locked against a second lagrseq process that
    would write the same trial (two identical runs at once): that one is refused, and the file
    the first is writing is never truncated under it. A ``.partial`` left by a crash is not
    locked, so a rerun writes it anew."""
    descriptor = os.open(partial, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if fcntl is not None:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
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
    return os.fdopen(descriptor, "wb")


class McapSink:
    """Write one trial's events. Use as a context manager; ``write(topic, record, log_time)``."""

    def __init__(
        self,
        path: str | Path,
        metadata: dict[str, str],
        extra_topics: dict[str, tuple[str, str, bytes]] | None = None,
    ) -> None:
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = _open_exclusive(self.partial)
        self._writer = LeanWriter(self._stream, library="lagrseq", profile=PROFILE)
        self._channels: dict[str, int] = {}
        for topic, schema in TOPICS.items():
            schema_id = self._writer.register_schema(
                name=schema["title"], encoding="jsonschema", data=schema_bytes(schema)
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        for topic, (name, encoding, data) in (extra_topics or {}).items():
            schema_id = self._writer.register_schema(name=name, encoding=encoding, data=data)
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        self._transition_channel = self._channels[TRANSITION_TOPIC]
        self._writer.add_metadata(RUN_METADATA, metadata)
        self._chunk: list[tuple[int, int, bytes]] = []
        """Transitions and pictures of the current episode: (channel id, log time, data)."""
        self._pending: list[tuple[str, bytes, int]] = []
        self._finished = False

    def write(self, event: Event) -> None:
        """Add one event. Transitions and pictures go to the current chunk; queries and episodes
        are held until :meth:`flush` writes them into a chunk of their own."""
        kind = type(event)
        if kind is Transition:
            self._chunk.append((self._transition_channel, event[3], _encode_transition(event)))  # type: ignore[arg-type,misc]
        elif kind is QueryEvent:
            self._pending.append((QUERY_TOPIC, _encode_query(event), event[3]))  # type: ignore[arg-type,misc]
        elif kind is EpisodeEvent:
            self._pending.append((EPISODE_TOPIC, _encode(to_record(event)), max(event[-1] - 1, 0)))  # type: ignore[index,operator]
        elif kind is View:
            self._chunk.append((self._channels[event.topic], event.log_time, _encode(event.message)))  # type: ignore[union-attr]
        else:
            raise LogError(f"cannot log a {kind.__name__}; expected Transition, QueryEvent, EpisodeEvent or View")

    def write_record(self, topic: str, record: dict[str, Any], log_time: int) -> None:
        """Add one JSON object to ``topic`` as it is (tools and tests that write their own)."""
        if topic not in self._channels:
            raise LogError(f"topic {topic!r} is not registered in {self.path.name}")
        if topic == TRANSITION_TOPIC or topic.startswith("/view"):
            self._chunk.append((self._channels[topic], log_time, _encode(record)))
        else:
            self._pending.append((topic, _encode(record), log_time))

    def _add(self, topic: str, data: bytes, log_time: int) -> None:
        self._writer.add_message(self._channels[topic], log_time, data)

    @property
    def messages(self) -> int:
        """Messages written so far (every topic)."""
        return self._writer.messages

    def flush(self) -> None:
        """End of an episode: close the transition chunk, write the held messages as their own
        chunk, and push everything to the operating system."""
        self._writer.add_messages(self._chunk)
        self._chunk.clear()
        self._writer.flush(push=not self._pending)
        if self._pending:
            for topic, data, log_time in self._pending:
                self._add(topic, data, log_time)
            self._pending.clear()
            self._writer.flush()

    def finish(self, status: str = "complete", error: str = "") -> Path:
        """Write the summary and rename the file to its final name (idempotent)."""
        if self._finished:
            return self.path
        self._finished = True
        try:
            self.flush()
            self._writer.add_metadata(
                STATUS_METADATA, {"status": status, "error": error, "messages": str(self.messages)}
            )
            self._writer.finish()
        finally:
            self._stream.close()
        os.replace(self.partial, self.path)
        return self.path

    def abandon(self) -> None:
        """Ctrl-C: stop writing and leave ``NAME.partial`` as it is on disk, every flushed
        episode in it (``lagrseq recover`` makes it a valid log; a rerun writes it anew)."""
        if self._finished:
            return
        self._finished = True
        with contextlib.suppress(OSError):
            self._stream.close()  # the unfinished episode's messages were never written

    def close(self) -> None:
        """Finish a trial that ended normally (idempotent)."""
        self.finish()

    def __enter__(self) -> McapSink:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.finish()
        elif exc_type is KeyboardInterrupt:
            self.abandon()
        else:
            self.finish("failed", f"{exc_type.__name__}: {exc}")
