"""Log format 3's columnar records, expanded into the records format 2 wrote one message each.

An episode's transitions are one ``/transitions`` record and its decisions not to query one
``/no_query`` record (:mod:`lagrseq.logs.sink`); the readers (:mod:`lagrseq.logs.reader`) and
``lagrseq recover`` (:mod:`lagrseq.logs.recover`) turn each into ``/transition`` and ``/query``
records with the functions here. A columnar record is checked before it is expanded (lists of
one length, integer global steps), and what does not fit is :class:`~lagrseq.logs.mcap_reader.Damage`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from operator import itemgetter
from typing import Any

import msgspec
from mcap.records import Message

from lagrseq.logs.events import (
    NO_QUERY_COLUMNS,
    NO_QUERY_TOPIC,
    QUERY_TOPIC,
    TRANSITION_COLUMNS,
    TRANSITION_OPTIONAL,
    TRANSITION_TOPIC,
    TRANSITIONS_TOPIC,
    QueryEvent,
)
from lagrseq.logs.mcap_reader import Damage

_decode = msgspec.json.Decoder().decode

QUERY_DEFAULTS: dict[str, Any] = {
    f.encode_name: f.default
    for f in msgspec.structs.fields(QueryEvent)
    if f.default is not msgspec.NODEFAULT
}
"""The ``/query`` fields a record may leave out, with the value they then have. Since log format 2
(:data:`lagrseq.logs.sink.LOG_FORMAT`) a decision record omits every field at its default (a
decision not to ask: the 19 nulls, ``queried`` false and ``query_reward`` 0); readers put them
back, so a record reads the same from an old log and a new one."""
QUERY_FIELDS = tuple(f.encode_name for f in msgspec.structs.fields(QueryEvent))
"""The fields a ``/query`` record may have (an accuracy probe's add ``prefix_length`` and ``fraction``)."""
_QUERY_FIELDS = len(QUERY_FIELDS)


def fill_query_defaults(record: dict[str, Any]) -> dict[str, Any]:
    """A ``/query`` record with the fields it left out at their defaults (see
    :data:`QUERY_DEFAULTS`); a complete record is returned as it is."""
    if len(record) < _QUERY_FIELDS:  # a complete record (format 1, or a query sent) has them all
        for name, default in QUERY_DEFAULTS.items():
            if name not in record:
                record[name] = default
    return record


def _columns(record: dict[str, Any], names: Sequence[str], topic: str, offset: int) -> tuple[list[Any], ...]:
    """The columns ``names`` of a format-3 columnar record, checked: lists of one length, the
    global steps integers (they order the expanded records)."""
    try:
        columns = tuple(record[name] for name in names)
    except KeyError as missing:
        raise Damage(offset, f"a {topic} message in this chunk lacks its {missing} field") from None
    if not all(type(column) is list for column in columns) or len({len(column) for column in columns}) != 1:
        raise Damage(offset, f"a {topic} message in this chunk does not hold columns of one length")
    if not all(type(step) is int for step in record["global_step"]):
        raise Damage(offset, f"a {topic} message in this chunk has a global_step that is not an integer")
    if "trial" not in record or "episode" not in record:
        raise Damage(offset, f"a {topic} message in this chunk lacks its trial or episode field")
    return columns


_TRANSITION_KEYS = frozenset(("trial", "episode", *TRANSITION_COLUMNS, *TRANSITION_OPTIONAL))


def expand_transitions(record: dict[str, Any], offset: int = 0) -> list[dict[str, Any]]:
    """The ``/transition`` records of one format-3 ``/transitions`` record, one per step, as
    format 2 wrote them (a ``placement`` entry that is null is left out, as format 2 did; so is
    a null entry of a task's own column, ``lagrseq.logs.task_fields``)."""
    columns = _columns(record, TRANSITION_COLUMNS, TRANSITIONS_TOPIC, offset)
    trial, episode = record["trial"], record["episode"]
    rows = [
        {"trial": trial, "episode": episode, "step": step, "global_step": global_step, "state": state,
         "action": action, "reward": reward, "terminated": terminated, "truncated": truncated, "guided": guided}
        for step, global_step, state, action, reward, terminated, truncated, guided in zip(*columns)
    ]
    # the optional columns: an arm's placement, then a task's own step fields (any other key)
    optional = [*TRANSITION_OPTIONAL, *(k for k in record if k not in _TRANSITION_KEYS)]
    for name in optional:
        if name in record:
            (column,) = _columns(record, (name, "global_step"), TRANSITIONS_TOPIC, offset)[:1]
            for row, value in zip(rows, column):
                if value is not None:
                    row[name] = value
    return rows


def expand_no_query(record: dict[str, Any], offset: int = 0) -> list[dict[str, Any]]:
    """The ``/query`` records of one format-3 ``/no_query`` record, one per decision not to
    query: decision 0 and every other field at its default, as format 2's readers give them."""
    columns = _columns(record, NO_QUERY_COLUMNS, NO_QUERY_TOPIC, offset)
    trial, episode = record["trial"], record["episode"]
    return [
        {"trial": trial, "episode": episode, "step": step, "global_step": global_step, "state": state,
         "decision": 0, **QUERY_DEFAULTS}
        for step, global_step, state in zip(*columns)
    ]


def no_query_rows(record: dict[str, Any], names: Sequence[str], missing: Any) -> list[tuple[Any, ...]]:
    """The ``/query`` records one format-3 ``/no_query`` record holds, as rows of ``names``
    (``missing`` for a field the records lack): :func:`expand_no_query`'s records, checked the
    same way, without making a dict for each."""
    columns = dict(zip(NO_QUERY_COLUMNS, _columns(record, NO_QUERY_COLUMNS, NO_QUERY_TOPIC, offset=0), strict=True))
    count = len(columns["global_step"])
    constant = {"trial": record["trial"], "episode": record["episode"], "decision": 0, **QUERY_DEFAULTS}
    parts = [
        columns[name] if name in columns else itertools.repeat(constant.get(name, missing), count)
        for name in names
    ]
    return list(zip(*parts)) if parts else [() for _ in range(count)]


Expand = Callable[[dict[str, Any], int], list[dict[str, Any]]]
"""``expand(record, offset)``: the records a columnar record holds (``offset``: where its chunk
is, for the error)."""

EXPANDS: dict[str, tuple[str, Expand]] = {
    TRANSITIONS_TOPIC: (TRANSITION_TOPIC, expand_transitions),
    NO_QUERY_TOPIC: (QUERY_TOPIC, expand_no_query),
}
"""Log format 3's columnar topics: the topic their records are read as, and how."""


def columnar_rows(topic: str) -> tuple[str, Callable[[Message], int]] | None:
    """For a format-3 columnar topic: the topic its records are read as, and how many records a
    message of it holds (0 when it is not a readable columnar record); None for other topics."""
    if topic not in EXPANDS:
        return None
    read_as, expand = EXPANDS[topic]

    def rows(message: Message) -> int:
        try:
            record = _decode(message.data)
            return len(expand(record, 0)) if isinstance(record, dict) else 0
        except (ValueError, RecursionError, Damage):
            return 0

    return read_as, rows


_global_step = itemgetter("global_step")


def by_global_step(records: list[dict[str, Any]], offset: int) -> list[dict[str, Any]]:
    """``/query`` records of one chunk in step order: format 3 writes an episode's decisions not
    to query after the queries it sent; format 2 wrote them all in step order."""
    try:
        return sorted(records, key=_global_step)
    except (TypeError, KeyError):
        raise Damage(offset, f"a {QUERY_TOPIC} message in this chunk has no integer global_step") from None
