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

import json
import math
import operator
import os
from pathlib import Path
from typing import Any

from lagrseq.errors import LogError
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


_TRANSITION = (
    '{"trial":%d,"episode":%d,"step":%d,"global_step":%d,"state":%s,"action":%d,'
    '"reward":%s,"terminated":%s,"truncated":%s,"guided":%s}'
)
_BOOL = {True: "true", False: "false"}
_TRANSITION_KEYS = (
    "trial", "episode", "step", "global_step", "state", "action", "reward", "terminated", "truncated", "guided",
)


_STATE_TEXT: dict[tuple[int, ...], str] = {}


def _state_text(state: tuple[int, ...] | list[int]) -> str:
    """JSON of a flat integer pattern, memoised for tuples (cube stacks repeat all the time)."""
    if type(state) is tuple:
        text = _STATE_TEXT.get(state)
        if text is None:
            text = "[" + ",".join(map(str, state)) + "]"
            if len(_STATE_TEXT) < 100_000:
                _STATE_TEXT[state] = text
        return text
    return "[" + ",".join(map(str, state)) + "]"


_SKIP_VARIABLE = ("trial", "episode", "step", "global_step", "state", "decision", "query_reward")


class _SkipTemplate:
    """For one key order of decision records (``queried`` false): the JSON text with %-format slots
    for the variable fields, and the constant fields' values, which must all be None or false."""

    def __init__(self, record: dict[str, Any]) -> None:
        variable = [k for k in record if k in _SKIP_VARIABLE]
        constant = [k for k in record if k not in _SKIP_VARIABLE]
        parts = []
        for key in record:
            if key in ("state", "query_reward"):
                value = "%s"
            elif key in _SKIP_VARIABLE:
                value = "%d"
            else:
                value = json.dumps(record[key])
            parts.append(f'"{key}":{value}')
        self.text = "{" + ",".join(parts) + "}"
        self.variable = operator.itemgetter(*variable)
        self.state_at = variable.index("state")
        self.reward_at = variable.index("query_reward")
        self.constant = operator.itemgetter(*constant)
        self.constants = self.constant(record)


_SKIP_TEMPLATES: dict[tuple[str, ...], _SkipTemplate | None] = {}


def _encode_query(record: dict[str, Any]) -> bytes:
    """A decision not to query (most ``/query`` messages) through a cached template; every other
    record through json."""
    if record.get("queried") is not False:
        return _encode(record)
    keys = tuple(record)
    template = _SKIP_TEMPLATES.get(keys)
    if template is None:
        usable = all(k in record for k in _SKIP_VARIABLE) and len(keys) > len(_SKIP_VARIABLE) + 1
        usable = usable and all(record[k] in (None, False) for k in keys if k not in _SKIP_VARIABLE)
        template = _SKIP_TEMPLATES[keys] = _SkipTemplate(record) if usable else None
        if template is None:
            return _encode(record)
    values = list(template.variable(record))
    state, reward = values[template.state_at], values[template.reward_at]
    if (
        template.constant(record) != template.constants
        or type(reward) is not float
        or not math.isfinite(reward)
        or not isinstance(state, (tuple, list))
        or (state and type(state[0]) is not int)
    ):
        return _encode(record)
    values[template.state_at] = _state_text(state)
    values[template.reward_at] = repr(reward)
    return (template.text % tuple(values)).encode()


def _encode_transition(record: dict[str, Any]) -> bytes:
    """The hot path: one transition per environment step. Same JSON as ``_encode`` (key order
    aside) for the contract fields, several times faster; anything unusual takes the slow path."""
    if len(record) != len(_TRANSITION_KEYS):
        return _encode(record)
    state, reward = record.get("state"), record.get("reward")
    if (
        type(reward) is not float
        or not math.isfinite(reward)
        or not isinstance(state, (tuple, list))
        or (state and type(state[0]) is not int)
    ):
        return _encode(record)
    return (
        _TRANSITION
        % (
            record["trial"],
            record["episode"],
            record["step"],
            record["global_step"],
            _state_text(state),
            record["action"],
            repr(reward),
            _BOOL[record["terminated"]],
            _BOOL[record["truncated"]],
            _BOOL[record["guided"]],
        )
    ).encode()


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
        self._stream = self.partial.open("wb")
        self._writer = LeanWriter(self._stream, library="lagrseq", profile=PROFILE)
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
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
        self._sequence = {topic: 0 for topic in self._channels}
        self._writer.add_metadata(RUN_METADATA, metadata)
        self._pending: list[tuple[str, bytes, int]] = []
        self._finished = False
        self.messages = 0

    def write(self, topic: str, record: dict[str, Any], log_time: int) -> None:
        """Add one message. ``/transition`` (and picture topics) go to the current chunk;
        every other topic is held until :meth:`flush` writes it into a summary chunk."""
        if topic == "/transition":
            data = _encode_transition(record)
        elif topic == "/query":
            data = _encode_query(record)
        else:
            data = _encode(record)
        if topic == "/transition" or topic.startswith("/view"):
            self._add(topic, data, log_time)
        else:
            self._pending.append((topic, data, log_time))

    def _add(self, topic: str, data: bytes, log_time: int) -> None:
        sequence = self._sequence[topic]
        self._sequence[topic] = sequence + 1
        self._writer.add_message(self._channels[topic], log_time, data, sequence)
        self.messages += 1

    def flush(self) -> None:
        """End of an episode: close the transition chunk, write the held messages as their own
        chunk, and push everything to the operating system."""
        self._writer.flush()
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

    def __enter__(self) -> McapSink:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.finish()
        elif exc_type is KeyboardInterrupt:
            self.finish("interrupted", "interrupted by the user")
        else:
            self.finish("failed", f"{exc_type.__name__}: {exc}")
