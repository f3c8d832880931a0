"""JSON schemas of the MCAP topics. Field names are a public contract: add fields, rename none."""

from __future__ import annotations

import json
from typing import Any

_INT = {"type": "integer"}
_NUM = {"type": "number"}
_BOOL = {"type": "boolean"}


def _nullable(schema: dict[str, Any]) -> dict[str, Any]:
    return {"anyOf": [schema, {"type": "null"}]}


def _object(title: str, description: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": list(properties),
    }


TRANSITION = _object(
    "lagrseq.Transition",
    "One environment step of the primary agent.",
    {
        "trial": _INT,
        "episode": _INT,
        "step": {**_INT, "description": "step within the episode, from 0"},
        "global_step": {**_INT, "description": "step within the trial, from 0 (also the log time)"},
        "state": {"type": "array", "description": "the partial pattern before the action"},
        "action": _INT,
        "reward": _NUM,
        "terminated": _BOOL,
        "truncated": _BOOL,
        "guided": {**_BOOL, "description": "the action came from the LLM's solution (pi_LLM)"},
    },
)

QUERY = _object(
    "lagrseq.Query",
    "One decision of the secondary agent (or of LaGR without SEQ) and, if sent, the query.",
    {
        "trial": _INT,
        "episode": _INT,
        "step": _INT,
        "global_step": _INT,
        "state": {"type": "array", "description": "the partial pattern shown (or not) to the LLM"},
        "decision": {**_INT, "description": "1 = query, 0 = do not query"},
        "queried": {**_BOOL, "description": "a query was actually sent to a provider"},
        "prompt_sha256": _nullable({"type": "string"}),
        "answer": _nullable({"type": "string"}),
        "solution": _nullable({"type": "array"}),
        "parse_error": _nullable({"type": "string"}),
        "evaluation": _nullable({**_NUM, "description": "E(s_LLM) / E(target), 0 if unparseable"}),
        "accepted": _nullable(_BOOL),
        "query_reward": _NUM,
        "provider": _nullable({"type": "string"}),
        "model": _nullable({"type": "string"}),
        "temperature": _nullable(_NUM),
        "prompt_tokens": _nullable(_INT),
        "completion_tokens": _nullable(_INT),
        "cost_usd": _nullable(_NUM),
        "latency_s": _nullable(_NUM),
        "source": _nullable({"enum": ["live", "recorded", "mock", "miss", "calibrated"], "description": "miss: the recorded store lacked the query and a refusal answered it (--on-miss refuse); calibrated: a draw at the store's own acceptance rate answered it (--on-miss calibrated)"}),
        "record_key": _nullable({"type": "string", "description": "recorded store key of the query"}),
        "sample_index": _nullable({**_INT, "description": "which recorded sample of the key was served"}),
        "finish_reason": _nullable({"type": "string", "description": "why the model stopped (stop, length, ...)"}),
        "system_fingerprint": _nullable({"type": "string", "description": "the server's backend fingerprint"}),
    },
)

QUERY["description"] += (
    " Log format 2: fields at their default (null; queried false; query_reward 0) are left out"
    " and readers fill them in."
)
QUERY["required"] = ["trial", "episode", "step", "global_step", "state", "decision"]

EPISODE = _object(
    "lagrseq.Episode",
    "Summary of one episode.",
    {
        "trial": _INT,
        "episode": _INT,
        "return": _NUM,
        "length": _INT,
        "queries": {**_INT, "description": "queries sent in this episode"},
        "accepted": {**_INT, "description": "accepted answers in this episode"},
        "epsilon": _NUM,
        "solved": {**_BOOL, "description": "the target pattern was reached"},
        "guided_steps": _INT,
        "global_step": {**_INT, "description": "trial step count at the end of the episode"},
    },
)

# Arm tasks add optional fields (written only by them).
TRANSITION["properties"]["placement"] = _nullable(
    {"type": "object", "description": "arm tasks: the robot's placement on this step (row, col, outcome, ok, offset_mm, ...)"}
)
EPISODE["properties"]["placements"] = {**_INT, "description": "arm tasks: placements executed"}
EPISODE["properties"]["failed_placements"] = {**_INT, "description": "arm tasks: placements that failed"}

ACCURACY_METHOD = "llm-accuracy"
"""``method`` in the ``lagrseq.run`` metadata of an accuracy-probe log (Fig. 4: the LLM alone,
no RL): its ``/query`` records carry ``prefix_length`` and ``fraction`` of the sequence shown."""

TOPICS: dict[str, dict[str, Any]] = {
    "/transition": TRANSITION,
    "/query": QUERY,
    "/episode": EPISODE,
}
"""The topics of log formats 1 and 2: one message per transition and per decision."""


def column(item: dict[str, Any], description: str) -> dict[str, Any]:
    """The schema of a column of a format-3 record: an array of ``item``."""
    return {"type": "array", "items": item, "description": description}


_column = column


TRANSITIONS = _object(
    "lagrseq.Transitions",
    "The primary agent's steps of one episode, as columns (log format 3): entry i of every array"
    " is step i of the episode. Readers expand it into one /transition record per step"
    " (lagrseq.Transition: trial, episode, then entry i of each array).",
    {
        "trial": _INT,
        "episode": _INT,
        "step": _column(_INT, "step within the episode, from 0"),
        "global_step": _column(_INT, "step within the trial, from 0 (the /transition log time)"),
        "state": _column({"type": "array"}, "the partial pattern before the action"),
        "action": _column(_INT, "the action taken"),
        "reward": _column(_NUM, "the reward received"),
        "terminated": _column(_BOOL, "the episode ended on this step"),
        "truncated": _column(_BOOL, "the episode was cut off on this step"),
        "guided": _column(_BOOL, "the action came from the LLM's solution (pi_LLM)"),
    },
)
TRANSITIONS["properties"]["placement"] = _column(
    _nullable({"type": "object"}),
    "arm tasks: the robot's placement on each step (null on steps that placed nothing); only in"
    " records of episodes that placed something",
)

NO_QUERIES = _object(
    "lagrseq.NoQueries",
    "The secondary agent's decisions not to query in one episode, as columns (log format 3):"
    " entry i of every array is one decision (decision 0: nothing was sent). Readers expand it"
    " into one /query record per decision, with decision 0 and every other field at its default"
    " (null; queried false; query_reward 0). Queries that were sent stay one /query record each.",
    {
        "trial": _INT,
        "episode": _INT,
        "step": _column(_INT, "step within the episode at which the decision was taken"),
        "global_step": _column(_INT, "step within the trial (the /query log time)"),
        "state": _column({"type": "array"}, "the partial pattern not shown to the LLM"),
    },
)

TOPICS_3: dict[str, dict[str, Any]] = {
    "/transitions": TRANSITIONS,
    "/query": QUERY,
    "/no_query": NO_QUERIES,
    "/episode": EPISODE,
}
"""The topics of log format 3: an episode's transitions and its decisions not to query are one
record each (``/transitions``, ``/no_query``); queries sent and episodes are one record each."""


def schema_bytes(schema: dict[str, Any]) -> bytes:
    return json.dumps(schema, sort_keys=True).encode()


SCHEMA_BYTES: dict[str, bytes] = {
    schema["title"]: schema_bytes(schema) for schema in (*TOPICS.values(), *TOPICS_3.values())
}
"""Every topic's schema as the bytes a log stores, by title (worked out once, not per trial)."""
