"""JSON schemas of the MCAP topics, generated from the records of :mod:`lagrseq.logs.events`.

Each field is declared once, on its ``msgspec.Struct`` record (name, type, description); the
schemas here are ``msgspec.json.schema`` of those records, reshaped into one flat object schema
per topic (no ``$ref``, so Foxglove shows every property). Field names are a public contract: add
fields, rename none. ``docs/logs.md`` describes every field (a test compares it with these).
"""

from __future__ import annotations

import json
from typing import Any

import msgspec

from lagrseq.logs.events import (
    NO_QUERY_COLUMNS,
    ArmEpisodeEvent,
    EpisodeEvent,
    QueryEvent,
    Transition,
)

_DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _properties(record: type[msgspec.Struct]) -> dict[str, dict[str, Any]]:
    """The JSON schema of each field of ``record``, by JSON name, in field order (defaults left
    out: a default is the readers' business, not the message's)."""
    found = msgspec.json.schema(record)
    body = found["$defs"][found["$ref"].rsplit("/", 1)[-1]]
    return {name: {k: v for k, v in schema.items() if k != "default"} for name, schema in body["properties"].items()}


def _required(record: type[msgspec.Struct]) -> list[str]:
    """The fields every message of ``record`` has: all of them, or where the record leaves fields
    at their default out (``omit_defaults``), those without a default."""
    fields = msgspec.structs.fields(record)
    if record.__struct_config__.omit_defaults:
        return [f.encode_name for f in fields if f.default is msgspec.NODEFAULT and f.default_factory is msgspec.NODEFAULT]
    return [f.encode_name for f in fields]


def _object(title: str, description: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {
        "$schema": _DRAFT,
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": required,
    }


def record_schema(title: str, description: str, record: type[msgspec.Struct], base: type[msgspec.Struct]) -> dict[str, Any]:
    """The schema of a topic whose messages are ``record``s: every field of ``record`` (the
    optional fields of its subclasses included), required as ``base`` requires them."""
    return _object(title, description, _properties(record), _required(base))


TRANSITION = record_schema("lagrseq.Transition", "One environment step of the primary agent.", Transition, Transition)

QUERY = record_schema(
    "lagrseq.Query",
    "One decision of the secondary agent (or of LaGR without SEQ) and, if it asked, the query."
    " Log format 2 and later: fields at their default (null; queried false; query_reward 0) are"
    " left out and readers fill them in. Accuracy-probe logs add prefix_length and fraction"
    " (lagrseq.logs.events.ProbeQueryEvent).",
    QueryEvent,
    QueryEvent,
)

EPISODE = record_schema(
    "lagrseq.Episode", "Summary of one episode (arm tasks add placements and failed_placements).", ArmEpisodeEvent, EpisodeEvent
)

ACCURACY_METHOD = "llm-accuracy"
"""``method`` in the ``lagrseq.run`` metadata of an accuracy-probe log (Fig. 4: the LLM alone,
no RL): its ``/query`` records carry ``prefix_length`` and ``fraction`` of the sequence shown."""

TOPICS: dict[str, dict[str, Any]] = {
    "/transition": TRANSITION,
    "/query": QUERY,
    "/episode": EPISODE,
}
"""The topics of log format 2: one message per transition and per decision."""


def column(item: dict[str, Any], description: str) -> dict[str, Any]:
    """The schema of a column of a format-3 record: an array of ``item``."""
    return {"type": "array", "items": item, "description": description}


def _columns(properties: dict[str, dict[str, Any]], names: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """``trial`` and ``episode`` as they are, then each of ``names`` as a column of its field."""
    out: dict[str, Any] = {"trial": properties["trial"], "episode": properties["episode"]}
    for name in names:
        item = {k: v for k, v in properties[name].items() if k != "description"}
        out[name] = column(item, properties[name]["description"])
    return out


_TRANSITION_PROPERTIES = _properties(Transition)

TRANSITIONS = _object(
    "lagrseq.Transitions",
    "The primary agent's steps of one episode, as columns (log format 3 and later): entry i of"
    " every array is step i of the episode. Readers expand it into one /transition record per"
    " step (lagrseq.Transition: trial, episode, then entry i of each array). A placement column"
    " is there only for episodes that placed something (null on the steps that placed nothing).",
    _columns(_TRANSITION_PROPERTIES, [name for name in _TRANSITION_PROPERTIES if name not in ("trial", "episode")]),
    _required(Transition),
)

NO_QUERIES = _object(
    "lagrseq.NoQueries",
    "The secondary agent's decisions not to query in one episode, as columns (log format 3 and"
    " later): entry i of every array is one decision (decision 0: nothing was sent). Readers"
    " expand it into one /query record per decision, with decision 0 and every other field at"
    " its default (null; queried false; query_reward 0). Queries stay one /query record each.",
    _columns(_properties(QueryEvent), NO_QUERY_COLUMNS),
    ["trial", "episode", *NO_QUERY_COLUMNS],
)

TOPICS_3: dict[str, dict[str, Any]] = {
    "/transitions": TRANSITIONS,
    "/query": QUERY,
    "/no_query": NO_QUERIES,
    "/episode": EPISODE,
}
"""The topics of log formats 3 and 4: an episode's transitions and its decisions not to query are
one record each (``/transitions``, ``/no_query``); queries and episodes are one record each."""


def schema_bytes(schema: dict[str, Any]) -> bytes:
    return json.dumps(schema, sort_keys=True).encode()


SCHEMA_BYTES: dict[str, bytes] = {
    schema["title"]: schema_bytes(schema) for schema in (*TOPICS.values(), *TOPICS_3.values())
}
"""Every topic's schema as the bytes a log stores, by title (worked out once, not per trial)."""
