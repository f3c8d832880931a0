"""A task's own logged fields: what its env puts in ``info["log_episode"]`` and ``info["log_step"]``
beyond lagrseq's records, declared by the task (``TaskSpec.episode_fields``, ``step_fields``:
name -> JSON type).

A task that declares some logs its ``/episode`` and ``/transition`` records as subclasses of
:class:`~lagrseq.logs.events.EpisodeEvent` and :class:`~lagrseq.logs.events.Transition` with
those fields added (null where the env left one out), under schemas that carry them: the
declared properties are added to the topic's JSON schema, so Foxglove's message view shows them,
and the schema names them under :data:`SCHEMA_KEY`, so ``lagrseq replay`` reads them back from
the log alone (the plugin need not be installed). A task that declares none logs exactly as
before (the built-in tasks' golden logs are unchanged).

An env that logs a field its task does not declare, or a value not of its declared type, stops
the trial with one :class:`~lagrseq.errors.RecordError` line naming the field and the declaration
that would take it.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from lagrseq.errors import RecordError
from lagrseq.logs import schemas
from lagrseq.logs.events import EPISODE_RECORDS, EpisodeEvent, Transition, episode_event

SCHEMA_KEY = "x-lagrseq-task-fields"
"""The key of a topic's JSON schema that names the task's own fields and their JSON types
(``{"wrong_bits": "integer"}``); JSON Schema ignores keys it does not know."""
EPISODE_KEY = "log_episode"
"""``lagrseq.tasks.base.EPISODE_LOG`` (the logs layer imports no task code)."""
STEP_KEY = "log_step"
"""``lagrseq.tasks.base.STEP_LOG``."""

_JSON_TYPES = ("integer", "number", "boolean", "string")


def _value(kind: str, value: Any) -> Any:
    """``value`` as the JSON type ``kind`` (numpy scalars as Python's), or raise ValueError."""
    if value is None:
        return None
    if isinstance(value, np.generic):
        value = value.item()
    if kind == "integer" and type(value) is int:
        return value
    if kind == "number" and type(value) in (int, float):
        if math.isfinite(value):
            return value
        raise ValueError("not a finite number")
    if kind == "boolean" and type(value) is bool:
        return value
    if kind == "string" and type(value) is str:
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise ValueError("not valid UTF-8 text (a lone surrogate)") from None
        return value
    raise ValueError(f"{'an' if kind == 'integer' else 'a'} {kind} was declared, found {type(value).__name__}")


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


@dataclass(frozen=True)
class TaskFields:
    """The record types and schemas of a task that logs fields of its own."""

    task: str
    episode_fields: tuple[tuple[str, str], ...]
    step_fields: tuple[tuple[str, str], ...]
    transition: type[Transition]
    """``Transition`` with the step fields added (default None: not written)."""
    episode: type[EpisodeEvent]
    """``EpisodeEvent`` with the episode fields added (default None: written as null)."""

    def _checked(self, extra: Mapping[str, Any], declared: tuple[tuple[str, str], ...], key: str, what: str) -> dict[str, Any]:
        types = dict(declared)
        out: dict[str, Any] = {}
        for name, value in extra.items():
            if name not in types:
                raise RecordError(_undeclared(self.task, key, name, what, value))
            try:
                out[name] = _value(types[name], value)
            except ValueError as exc:
                raise RecordError(
                    f"task {self.task}: info[{key!r}][{name!r}] = {_shown(value)}: {exc}; log a {types[name]} "
                    f"or declare it as another type in TaskSpec.{what} (one of {', '.join(_JSON_TYPES)})"
                ) from None
        return out

    def step(self, fields: tuple[Any, ...], extra: Mapping[str, Any]) -> Transition:
        """The step's ``/transition`` record: ``fields`` (lagrseq's, in order) and the env's
        ``info["log_step"]``, checked against the declaration."""
        return self.transition(*fields, **self._checked(extra, self.step_fields, STEP_KEY, "step_fields"))

    def episode_event(self, extra: Mapping[str, Any] | None = None, **summary: Any) -> EpisodeEvent:
        """The ``/episode`` record of ``summary`` with the env's ``info["log_episode"]``,
        checked against the declaration."""
        if not extra:
            return self.episode(**summary)
        return self.episode(**summary, **self._checked(extra, self.episode_fields, EPISODE_KEY, "episode_fields"))

    def schema(self, title: str) -> bytes:
        """The bytes of the schema of the topic whose built-in schema is called ``title``, with
        the task's own fields added (the ``/episode``, ``/transition`` and ``/transitions``
        schemas; any other as it is)."""
        return _schema(title, self.episode_fields, self.step_fields, self.task)


def _undeclared(task: str, key: str, name: str, what: str, value: Any) -> str:
    kind = "number" if isinstance(value, (float, np.floating)) else "boolean" if isinstance(value, (bool, np.bool_)) else "string" if isinstance(value, str) else "integer"
    who = f"task {task}" if task else "the run's task"
    return (
        f"{who}: info[{key!r}] has the field {name!r}, which the task does not declare; "
        f"declare it in its TaskSpec: {what}={{{name!r}: {kind!r}}} (types: {', '.join(_JSON_TYPES)})"
    )


def builtin_step(fields: tuple[Any, ...], extra: Mapping[str, Any]) -> Transition:
    """A step's ``/transition`` record for a task without fields of its own: lagrseq's fields
    and those an env of a built-in task adds (the arm's ``placement``)."""
    try:
        return Transition(*fields, **extra)
    except TypeError:
        known = {f.encode_name for f in msgspec.structs.fields(Transition)}
        name = next((n for n in extra if n not in known), "?")
        raise RecordError(_undeclared("", STEP_KEY, name, "step_fields", extra.get(name))) from None


def builtin_episode(extra: Mapping[str, Any] | None = None, **summary: Any) -> EpisodeEvent:
    """The ``/episode`` record for a task without fields of its own (:func:`episode_event`)."""
    try:
        return episode_event(dict(extra) if extra else None, **summary)
    except ValueError as exc:
        known = {f.encode_name for record in EPISODE_RECORDS for f in msgspec.structs.fields(record)}
        name = next((n for n in sorted(extra or ()) if n not in known), None)
        if name is None:  # lagrseq's own fields, but not those of one record
            raise RecordError(f"{exc}; expected the fields of one record: {', '.join(sorted(known - {f.encode_name for f in msgspec.structs.fields(EpisodeEvent)}))}") from None
        raise RecordError(_undeclared("", EPISODE_KEY, name, "episode_fields", (extra or {}).get(name))) from None


def _schema(title: str, episode_fields: tuple[tuple[str, str], ...], step_fields: tuple[tuple[str, str], ...], task: str) -> bytes:
    if title == schemas.EPISODE["title"]:
        own, column = episode_fields, False
    elif title == schemas.TRANSITION["title"]:
        own, column = step_fields, False
    elif title == schemas.TRANSITIONS["title"]:
        own, column = step_fields, True
    else:
        own = ()
    if not own:
        return schemas.SCHEMA_BYTES[title]
    schema = json.loads(schemas.SCHEMA_BYTES[title])
    for name, kind in own:
        about = f"task {task}'s own field (declared by its TaskSpec); null where its env did not log it"
        item = {"type": [kind, "null"]}
        schema["properties"][name] = schemas.column(item, about) if column else {**item, "description": about}
    schema[SCHEMA_KEY] = dict(own)
    return schemas.schema_bytes(schema)


@functools.lru_cache(maxsize=64)
def task_fields(task: str, episode_fields: tuple[tuple[str, str], ...], step_fields: tuple[tuple[str, str], ...]) -> TaskFields | None:
    """The record types of a task that declares fields of its own (None: it declares none),
    made once per declaration."""
    if not episode_fields and not step_fields:
        return None
    transition: type[Transition] = Transition
    if step_fields:
        transition = msgspec.defstruct(  # type: ignore[assignment]
            "TaskTransition", [(name, Any, None) for name, _ in step_fields], bases=(Transition,),
            frozen=True, gc=False, omit_defaults=True,
        )
    episode: type[EpisodeEvent] = EpisodeEvent
    if episode_fields:
        episode = msgspec.defstruct(  # type: ignore[assignment]
            "TaskEpisodeEvent", [(name, Any, None) for name, _ in episode_fields], bases=(EpisodeEvent,),
            frozen=True, gc=False,
        )
    return TaskFields(task, episode_fields, step_fields, transition, episode)


def of_spec(spec: Any) -> TaskFields | None:
    """:func:`task_fields` of a registered ``TaskSpec`` (its declarations, in order)."""
    return task_fields(spec.name, tuple(dict(spec.episode_fields).items()), tuple(dict(spec.step_fields).items()))


def declared(schema_data: bytes) -> tuple[tuple[str, str], ...]:
    """The task's own fields a topic's logged schema names (empty: none), as (name, type)."""
    if SCHEMA_KEY.encode() not in schema_data:
        return ()
    try:
        found = json.loads(schema_data).get(SCHEMA_KEY)
    except (ValueError, AttributeError, RecursionError):
        return ()
    if not isinstance(found, dict):
        return ()
    return tuple((str(k), str(v)) for k, v in found.items() if isinstance(k, str) and v in _JSON_TYPES)

