"""What a recorded answer may hold: the JSON Schemas of a JSONL line and of a store entry, and
the checks JSON Schema cannot express.

Everything a store or a JSONL file holds came from outside (a server, a hand edit, another
program), so both are checked field by field before they are used: imports before anything is
written (:func:`lagrseq.llm.store.import_jsonl`), store rows when they are read
(:meth:`lagrseq.llm.store.RecordStore.entry`), new samples before they are written. The format is
documented in ``recorded_llm/README.md``; the bounds are here:

* :data:`MAX_ANSWER_CHARS` characters of answer text (longer answers are refused, not cut);
* token counts from 0 to :data:`MAX_TOKEN_COUNT`;
* every number finite (no NaN or infinity), every string valid Unicode (no lone surrogates:
  it must encode as UTF-8);
* a JSONL line at most :data:`MAX_LINE_BYTES` long.

:func:`problems` returns what is wrong with a value as short phrases naming the field, what was
found and what was expected, e.g. ``request.messages[0] is 42, expected an object with role and
content``; an empty list means the value is valid.
"""

from __future__ import annotations

import functools
import math
import re
from collections import deque
from collections.abc import Iterable
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError

MAX_ANSWER_CHARS = 16_000
"""Longest answer text (characters) a store holds; the same value as ``lagrseq.tasks.base``'s,
whose parsers refuse longer answers (llm/ may not import tasks/: a test keeps the two equal). The
live provider cuts a longer answer to this length and marks it ``finish_reason = "lagrseq-clipped"``."""
MAX_TOKEN_COUNT = 10**7
"""Largest token count (prompt, completion, cached, max_tokens) believed."""
MAX_LINE_BYTES = 1 << 20
"""Longest JSONL line read (1 MiB); longer lines are refused with their line number."""
MAX_PROMPT_CHARS = 1_000_000
"""Longest message content of a request."""
JSONL_FORMAT = "lagrseq.recorded/1"
KEY_VERSION = 1
SAMPLE_ORIGINS = ("live", "authors-cache", "mock", "recorded")

_NULL_OR_STRING = ["string", "null"]


def _string(expected: str, max_length: int, min_length: int = 0, **more: Any) -> dict[str, Any]:
    return {"type": "string", "minLength": min_length, "maxLength": max_length, "x-expected": expected, **more}


def _optional(schema: dict[str, Any]) -> dict[str, Any]:
    types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    return {**schema, "type": [*types, "null"], "x-expected": schema["x-expected"] + " or null"}


_TOKENS = {
    "type": "integer",
    "minimum": 0,
    "maximum": MAX_TOKEN_COUNT,
    "x-expected": f"an integer from 0 to {MAX_TOKEN_COUNT}",
}

REQUEST_SCHEMA: dict[str, Any] = {
    "type": "object",
    "x-expected": "an object with key_version, endpoint, model, messages, temperature, top_p, max_tokens, stop and seed (and optionally top_k, min_p, repeat_penalty)",
    "required": ["key_version", "endpoint", "model", "messages", "temperature", "top_p", "max_tokens", "stop", "seed"],
    "additionalProperties": False,
    "properties": {
        "key_version": {"const": KEY_VERSION, "x-expected": f"{KEY_VERSION} (the key version this lagrseq reads)"},
        "endpoint": _string("a host or host:port, e.g. api.openai.com", 300, 1, pattern=r"^[^\s/@]+$"),
        "model": _string("a model name (1 to 200 characters)", 200, 1),
        "messages": {
            "type": "array",
            "minItems": 1,
            "maxItems": 1000,
            "x-expected": "a list of 1 to 1000 chat messages",
            "items": {
                "type": "object",
                "x-expected": "an object with role and content",
                "required": ["role", "content"],
                "additionalProperties": False,
                "properties": {
                    "role": {"enum": ["system", "user", "assistant"], "x-expected": "system, user or assistant"},
                    "content": _string(f"a string of at most {MAX_PROMPT_CHARS} characters", MAX_PROMPT_CHARS),
                },
            },
        },
        "temperature": {"type": "number", "minimum": 0, "maximum": 2, "x-expected": "a number from 0 to 2"},
        "top_p": {"type": "number", "minimum": 0, "maximum": 1, "x-expected": "a number from 0 to 1"},
        "max_tokens": _optional({**_TOKENS, "minimum": 1, "x-expected": f"an integer from 1 to {MAX_TOKEN_COUNT}"}),
        "stop": {
            "type": ["array", "null"],
            "minItems": 1,
            "maxItems": 16,
            "x-expected": "null or a list of 1 to 16 stop strings",
            "items": _string("a stop string of 1 to 1000 characters", 1000, 1),
        },
        "seed": {
            "type": ["integer", "null"],
            "minimum": -(2**63),
            "maximum": 2**63 - 1,
            "x-expected": "a 64-bit integer or null",
        },
        # llama.cpp's samplers (optional: present only in keys of requests that pinned them)
        "top_k": {"type": "integer", "minimum": 0, "maximum": 1_000_000, "x-expected": "an integer from 0 (off) to 1000000"},
        "min_p": {"type": "number", "minimum": 0, "maximum": 1, "x-expected": "a number from 0 (off) to 1"},
        "repeat_penalty": {"type": "number", "minimum": 0, "maximum": 10, "x-expected": "a number from 0 to 10 (1: off)"},
    },
}

SAMPLE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "x-expected": "an object with at least id, text and origin",
    "required": ["id", "text", "origin"],
    "additionalProperties": False,
    "properties": {
        "id": _string("an id of 1 to 200 characters without spaces", 200, 1, pattern=r"^\S+$"),
        "text": _string(f"an answer of at most {MAX_ANSWER_CHARS} characters (MAX_ANSWER_CHARS)", MAX_ANSWER_CHARS),
        "origin": {"enum": list(SAMPLE_ORIGINS), "x-expected": ", ".join(SAMPLE_ORIGINS[:-1]) + " or " + SAMPLE_ORIGINS[-1]},
        "recorded_as": {"enum": ["text", "array", "list"], "x-expected": "text, array or list"},
        "model": _optional(_string("a model name of at most 200 characters", 200)),
        "usage": {
            "type": ["object", "null"],
            "x-expected": "null or an object with prompt_tokens, completion_tokens and cached_tokens",
            "required": ["prompt_tokens", "completion_tokens", "cached_tokens"],
            "additionalProperties": False,
            "properties": {"prompt_tokens": _TOKENS, "completion_tokens": _TOKENS, "cached_tokens": _TOKENS},
        },
        "finish_reason": _optional(_string("a finish reason of at most 100 characters", 100)),
        "system_fingerprint": _optional(_string("a fingerprint of at most 200 characters", 200)),
        "latency_s": {
            "type": ["number", "null"],
            "minimum": 0,
            "maximum": 86_400,
            "x-expected": "seconds from 0 to 86400 or null",
        },
        "cost_usd": {
            "type": ["number", "null"],
            "minimum": 0,
            "maximum": 1_000_000,
            "x-expected": "US dollars from 0 to 1000000 or null",
        },
        "recorded_at": _optional(
            _string(
                "an ISO 8601 UTC time such as 2025-01-31T12:00:00Z",
                40,
                pattern=r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(\.\d+)?(Z|[+-]\d{2}:\d{2})$",
            )
        ),
        "provenance": _optional(_string("text of at most 1000 characters", 1000)),
    },
}

_TASK = _optional(_string("a task name such as cube-stacking", 100, 1, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$"))

RECORD_SCHEMA: dict[str, Any] = {
    "type": "object",
    "x-expected": f"a JSON object (a {JSONL_FORMAT} record)",
    "required": ["format", "request", "sample"],
    "additionalProperties": False,
    "properties": {
        "format": {"const": JSONL_FORMAT, "x-expected": repr(JSONL_FORMAT)},
        "key": _string("the sha256 of the request (64 lower-case hex digits)", 64, 64, pattern=r"^[0-9a-f]{64}$"),
        "index": {"type": "integer", "minimum": 0, "maximum": 10**9, "x-expected": "a non-negative integer"},
        "task": _TASK,
        "request": REQUEST_SCHEMA,
        "sample": SAMPLE_SCHEMA,
    },
}
"""One line of a JSONL export (``recorded_llm/README.md``)."""

ENTRY_SCHEMA: dict[str, Any] = {
    "type": "object",
    "x-expected": "an object with request, task and samples",
    "required": ["request", "samples"],
    "additionalProperties": False,
    "properties": {
        "request": REQUEST_SCHEMA,
        "task": _TASK,
        "samples": {"type": "array", "maxItems": 1_000_000, "x-expected": "a list of samples", "items": SAMPLE_SCHEMA},
    },
}
"""The value of one key in a store: ``{"request", "task", "samples"}``."""

_VALIDATORS = {id(s): Draft202012Validator(s) for s in (REQUEST_SCHEMA, SAMPLE_SCHEMA, RECORD_SCHEMA, ENTRY_SCHEMA)}
for _schema in (REQUEST_SCHEMA, SAMPLE_SCHEMA, RECORD_SCHEMA, ENTRY_SCHEMA):
    Draft202012Validator.check_schema(_schema)


# ------------------------------------------------------------------------------------------
# Messages
# ------------------------------------------------------------------------------------------
def path_text(path: Iterable[str | int], root: str = "", whole: str = "the record") -> str:
    """``["request", "messages", 0]`` -> ``request.messages[0]``; ``whole`` names the empty path."""
    text = root
    for part in path:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text or whole


def describe(value: Any) -> str:
    """A short, printable description of a JSON value (never its whole text)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, dict):
        return "an object" if value else "an empty object"
    if isinstance(value, list):
        return f"a list of {len(value)} item{'s' if len(value) != 1 else ''}" if value else "an empty list"
    if isinstance(value, str):
        if len(value) > 40:
            return f"a string of {len(value)} characters"
        return "an empty string" if not value else ascii(value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    text = repr(value)
    return text if len(text) <= 40 else f"a number of {len(text)} digits"


def _schema_problem(error: ValidationError, root: str, whole: str) -> tuple[str, str]:
    where = path_text(error.absolute_path, root, whole)
    schema = error.schema if isinstance(error.schema, dict) else {}
    instance = error.instance
    if error.validator == "required" and isinstance(instance, dict):
        missing = [name for name in error.validator_value if name not in instance]
        listed = ", ".join(repr(m) for m in missing)
        return where, f"{where} lacks field{'s' if len(missing) > 1 else ''} {listed}"
    if error.validator == "additionalProperties" and isinstance(instance, dict):
        known = sorted(schema.get("properties", {}))
        extra = sorted(str(name) for name in instance if name not in known)
        return where, f"{where} has unknown field {ascii(extra[0]) if extra else '?'}; fields are {', '.join(known)}"
    expected = schema.get("x-expected") or error.message[:80]
    return where, f"{where} is {describe(instance)}, expected {expected}"


def _deep_problems(value: Any, root: str, whole: str) -> list[tuple[str, str]]:
    """Non-finite numbers and strings that are not valid Unicode, anywhere in ``value``
    (iteratively: a value nested thousands deep cannot exhaust the stack)."""
    found: list[tuple[str, str]] = []
    stack: deque[tuple[tuple[str | int, ...], Any]] = deque([((), value)])
    while stack and len(found) < 10:
        path, item = stack.pop()
        if isinstance(item, float) and not math.isfinite(item):
            where = path_text(path, root, whole)
            found.append((where, f"{where} is {item}, expected a finite number"))
        elif isinstance(item, str):
            problem = _unicode_problem(item)
            if problem:
                where = path_text(path, root, whole)
                found.append((where, f"{where} {problem}"))
        elif isinstance(item, dict):
            for name, inner in item.items():
                problem = _unicode_problem(name) if isinstance(name, str) else None
                if problem:
                    where = path_text(path, root, whole)
                    found.append((where, f"{where} has a field name that {problem}"))
                stack.append(((*path, str(name)), inner))
        elif isinstance(item, list):
            stack.extend(((*path, i), inner) for i, inner in enumerate(item))
    return found


def _unicode_problem(text: str) -> str | None:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        return f"holds a lone surrogate {ascii(text[exc.start])} at character {exc.start}, expected valid Unicode text"
    return None


def _same(value: Any, expected: Any) -> bool:
    """JSON Schema equality: ``true`` is not ``1``."""
    if isinstance(value, bool) or isinstance(expected, bool):
        return isinstance(value, bool) and isinstance(expected, bool) and value == expected
    return bool(type(value) in (int, float, str) and value == expected)


def _is_type(value: Any, name: str) -> bool:
    if name == "string":
        return isinstance(value, str)
    if name == "null":
        return value is None
    if name == "object":
        return isinstance(value, dict)
    if name == "array":
        return isinstance(value, list)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return name == "number" or isinstance(value, int) or value.is_integer()


def fits(value: Any, schema: dict[str, Any]) -> bool:
    """Whether ``value`` is valid under ``schema``: the same verdict as jsonschema for the keywords
    this module's schemas use, about a hundred times faster (jsonschema then explains a failure;
    a test checks that the two agree)."""
    if "const" in schema and not _same(value, schema["const"]):
        return False
    if "enum" in schema and not any(_same(value, option) for option in schema["enum"]):
        return False
    types = schema.get("type")
    if types is not None and not any(_is_type(value, t) for t in (types if isinstance(types, list) else [types])):
        return False
    if isinstance(value, str):
        if len(value) < schema.get("minLength", 0) or len(value) > schema.get("maxLength", len(value)):
            return False
        pattern = schema.get("pattern")
        return pattern is None or _pattern(pattern).search(value) is not None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return not (
            ("minimum" in schema and value < schema["minimum"]) or ("maximum" in schema and value > schema["maximum"])
        )
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0) or len(value) > schema.get("maxItems", len(value)):
            return False
        items = schema.get("items")
        return items is None or all(fits(item, items) for item in value)
    if isinstance(value, dict):
        properties = schema.get("properties", {})
        if any(name not in value for name in schema.get("required", ())):
            return False
        if schema.get("additionalProperties") is False and any(name not in properties for name in value):
            return False
        return all(fits(value[name], sub) for name, sub in properties.items() if name in value)
    return True


@functools.lru_cache(maxsize=64)
def _pattern(pattern: str) -> re.Pattern[str]:
    return re.compile(pattern)


def problems(
    value: Any, schema: dict[str, Any], root: str = "", limit: int = 5, whole: str = "the record"
) -> list[str]:
    """What is wrong with ``value`` under ``schema`` (one of this module's) and the checks JSON
    Schema cannot express; at most ``limit`` phrases, one per field, in field order. Fields are
    named from ``root``; ``whole`` names the value itself."""
    deep = _deep_problems(value, root, whole)
    if not deep and fits(value, schema):
        return []
    found: dict[str, str] = {}
    errors = sorted(
        _VALIDATORS[id(schema)].iter_errors(value), key=lambda e: [str(p) for p in e.absolute_path]
    )
    for error in errors:
        where, text = _schema_problem(error, root, whole)
        found.setdefault(where, text)
    for where, text in deep:
        found.setdefault(where, text)
    return list(found.values())[:limit]


def normalise_request(request: dict[str, Any]) -> dict[str, Any]:
    """A valid request with its numbers written as the key recipe writes them (floats for
    ``temperature`` and ``top_p``, integers for ``max_tokens`` and ``seed``), so that a
    hand-written ``0`` and ``0.0`` make one key."""
    out = dict(request)
    out["key_version"] = int(out["key_version"])
    out["temperature"] = float(out["temperature"])
    out["top_p"] = float(out["top_p"])
    for name in ("min_p", "repeat_penalty"):
        if out.get(name) is not None:
            out[name] = float(out[name])
    if out.get("top_k") is not None:
        out["top_k"] = int(out["top_k"])
    for name in ("max_tokens", "seed"):
        if out.get(name) is not None:
            out[name] = int(out[name])
    return out


def normalise_sample(sample: dict[str, Any]) -> dict[str, Any]:
    """A valid sample with integral token counts written as integers."""
    usage = sample.get("usage")
    if isinstance(usage, dict):
        return {**sample, "usage": {name: int(count) for name, count in usage.items()}}
    return dict(sample)
