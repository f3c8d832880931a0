"""The events of a trial, as frozen records: one type per MCAP topic.

Each record's fields are the topic's contract, in the order they appear in the JSON, declared
here once: name, type and description (``Annotated[..., about(...)]``), from which
``logs/schemas.py`` generates the topics' JSON schemas; ``docs/logs.md`` describes each (a test
compares the two). Only :class:`EpisodeEvent` departs in spelling: ``return`` is a Python
keyword, so the attribute is ``return_`` and the JSON field stays ``return``. Field names are a
public contract: add fields at the end, rename none.

The records are ``msgspec.Struct`` classes: made and encoded to JSON in C (about 1 microsecond a
transition, against 6 to 7 for a NamedTuple and a memoised hand encoder; ``benchmarks/bench_cube.py``
measures what logging costs). A sink dispatches on the record's type (``McapSink.write``);
:func:`to_record` gives the JSON object of any event.
"""

from __future__ import annotations

import functools
from itertools import groupby
from operator import attrgetter, itemgetter
from typing import Annotated, Any, Literal, NamedTuple, Protocol

import msgspec
import numpy as np

TRANSITION_TOPIC = "/transition"
QUERY_TOPIC = "/query"
EPISODE_TOPIC = "/episode"
TRANSITIONS_TOPIC = "/transitions"
"""Log format 3: an episode's transitions as one columnar record (readers give ``/transition``)."""
NO_QUERY_TOPIC = "/no_query"
"""Log format 3: an episode's decisions not to query as one columnar record (readers give them
as ``/query`` records)."""


def about(description: str, **json_schema: Any) -> msgspec.Meta:
    """A field's description (and, for a field typed ``Any``, its JSON type) for the topic's JSON
    schema, which :mod:`lagrseq.logs.schemas` generates from these records."""
    return msgspec.Meta(description=description, extra_json_schema=json_schema or None)


_ARRAY = {"type": "array"}
_NULLABLE_ARRAY = {"anyOf": [{"type": "array"}, {"type": "null"}]}

Source = Literal["live", "recorded", "mock", "miss", "calibrated"]
"""Where an answer came from (``lagrseq.llm.base.Source``)."""
Outcome = Literal["sent", "replayed", "mock", "mock_fallback", "refused_miss", "calibrated_draw"]
"""How a query was decided: ``sent`` to a live server (tokens and money spent), ``replayed`` from
a recorded store's sample, answered by the ``mock`` provider (the run's provider), or, for a query
a recorded store lacked, by the mock (``mock_fallback``), by a refusal (``refused_miss``) or by a
draw at the store's acceptance rate (``calibrated_draw``). Only ``sent`` reached a model."""
OUTCOMES: tuple[str, ...] = Outcome.__args__  # type: ignore[attr-defined]


def query_outcome(provider: str | None, source: str | None) -> str | None:
    """The ``outcome`` of a query answered from ``source`` for a run on ``provider`` (None: no
    query, or a source lagrseq does not know). Logs before format 4 have no ``outcome`` field;
    their readers derive it with this function."""
    if source == "mock":
        return "mock_fallback" if isinstance(provider, str) and provider.startswith("recorded") else "mock"
    return _OUTCOME_OF.get(source) if isinstance(source, str) else None


_OUTCOME_OF = {"live": "sent", "recorded": "replayed", "miss": "refused_miss", "calibrated": "calibrated_draw"}


class Transition(msgspec.Struct, frozen=True, gc=False, omit_defaults=True):
    """One environment step of the primary agent (``/transition``). Fields with a default are
    written only when set (``placement``: arm tasks), so other tasks' records are unchanged."""

    trial: Annotated[int, about("trial index within the run, from 0")]
    episode: Annotated[int, about("episode index within the trial, from 0")]
    step: Annotated[int, about("step within the episode, from 0")]
    global_step: Annotated[int, about("step within the trial, from 0 (also the log time)")]
    state: Annotated[Any, about("the partial pattern before the action (a list, nested for grids)", **_ARRAY)]
    action: Annotated[int, about("the action taken (the primary agent's, or pi_LLM's when guided)")]
    reward: Annotated[float, about("the reward the environment returned for the action")]
    terminated: Annotated[bool, about("the environment ended the episode on this step")]
    truncated: Annotated[bool, about("the environment cut the episode off on this step (its own step limit)")]
    guided: Annotated[bool, about("the action came from the LLM's solution (pi_LLM)")]
    placement: Annotated[Any, about(
        "arm tasks: the robot's placement on this step (row, col, outcome, ok, offset_mm, ...); "
        "left out on steps that placed nothing", anyOf=[{"type": "object"}, {"type": "null"}]
    )] = None


class QueryEvent(msgspec.Struct, frozen=True, gc=False, omit_defaults=True):
    """One decision of the secondary agent and, when it asked, the query (``/query``).

    Fields at their default are not written (log format 2): a decision not to ask is its first
    six fields; the readers put the defaults back
    (:func:`lagrseq.logs.reader.fill_query_defaults`), so old and new logs read alike."""

    trial: Annotated[int, about("trial index within the run, from 0")]
    episode: Annotated[int, about("episode index within the trial, from 0")]
    step: Annotated[int, about("step within the episode at which the decision was taken")]
    global_step: Annotated[int, about("step within the trial (also the log time)")]
    state: Annotated[Any, about("the partial pattern shown (or not) to the LLM", **_ARRAY)]
    decision: Annotated[int, about("1 = query, 0 = do not query")]
    queried: Annotated[bool, about(
        "the decision asked and the query was decided (an answer of any outcome, a refused miss "
        "and a calibrated draw included); whether a model was reached is outcome"
    )] = False
    prompt_sha256: Annotated[str | None, about(
        "SHA-256 (lowercase hex) of prompt, the user message's text encoded as UTF-8"
    )] = None
    answer: Annotated[str | None, about("the answer's text as it came back (empty for a refused miss)")] = None
    solution: Annotated[Any, about("the parsed answer; null when it could not be parsed", **_NULLABLE_ARRAY)] = None
    parse_error: Annotated[str | None, about("why the answer could not be parsed (null: parsed)")] = None
    evaluation: Annotated[float | None, about("E(s_LLM) / E(target) of the parsed answer, 0 if unparseable")] = None
    accepted: Annotated[bool | None, about(
        "the answer was accepted: parsed (parse_error null) and evaluation >= the run's lagr.threshold"
    )] = None
    query_reward: Annotated[float, about(
        "the secondary agent's reward for the decision, the query cost subtracted (0 when not asked)"
    )] = 0.0
    provider: Annotated[str | None, about("the run's provider (mock, recorded, recorded+live, live, ...)")] = None
    model: Annotated[str | None, about("the model the answer names (a server's dated model name)")] = None
    temperature: Annotated[float | None, about("the sampling temperature asked for")] = None
    prompt_tokens: Annotated[int | None, about(
        "prompt tokens the server reported (the mock: estimated); null when unknown or nothing was sent"
    )] = None
    completion_tokens: Annotated[int | None, about(
        "completion tokens the server reported (the mock: estimated); null when unknown or nothing was sent"
    )] = None
    cost_usd: Annotated[float | None, about(
        "US dollars this query cost the run (0 for a replayed, mock or decided answer); null when "
        "the model has no price"
    )] = None
    latency_s: Annotated[float | None, about("seconds the provider took to answer")] = None
    source: Annotated[Source | None, about(
        "where the answer came from: live, recorded, mock; miss: the recorded store lacked the query "
        "and a refusal answered it (--on-miss refuse); calibrated: a draw at the store's own "
        "acceptance rate answered it (--on-miss calibrated)"
    )] = None
    record_key: Annotated[str | None, about(
        "the recorded store's key of the query: SHA-256 of its canonical request (docs/logs.md)"
    )] = None
    sample_index: Annotated[int | None, about("which recorded sample of the key was served (from 0)")] = None
    finish_reason: Annotated[str | None, about("why the model stopped (stop, length, ...)")] = None
    system_fingerprint: Annotated[str | None, about("the server's backend fingerprint")] = None
    prompt: Annotated[str | None, about("the user message's text: the exact prompt the query asked (log format 4)")] = None
    cached_tokens: Annotated[int | None, about(
        "of prompt_tokens, those the server served from its prompt cache (priced at the cached rate); "
        "null as prompt_tokens (log format 4)"
    )] = None
    outcome: Annotated[Outcome | None, about(
        "how the query was decided: sent (to a live server), replayed (a recorded sample), mock, "
        "mock_fallback, refused_miss, calibrated_draw (log format 4; readers derive it for older logs)"
    )] = None


class ProbeQueryEvent(QueryEvent, frozen=True, gc=False):
    """A query of Fig. 4's accuracy probe: a ``/query`` record with the prefix it showed."""

    prefix_length: Annotated[int, about("accuracy probe: elements of the target shown")] = 0
    fraction: Annotated[float, about("accuracy probe: prefix_length / the target's length")] = 0.0


class EpisodeEvent(msgspec.Struct, frozen=True, gc=False):
    """Summary of one episode (``/episode``). ``return`` is a Python keyword, so the attribute
    is ``return_`` and the JSON field stays ``return``."""

    trial: Annotated[int, about("trial index within the run, from 0")]
    episode: Annotated[int, about("episode index within the trial, from 0")]
    return_: Annotated[float, about("the episode's return: the sum of its transitions' rewards")] = msgspec.field(name="return")
    length: Annotated[int, about("the episode's steps (its transitions)")] = 0
    queries: Annotated[int, about("queries decided in this episode (its /query records with queried true)")] = 0
    accepted: Annotated[int, about("accepted answers in this episode")] = 0
    epsilon: Annotated[float, about("the primary agent's exploration rate at the episode's last step")] = 0.0
    solved: Annotated[bool, about("the target pattern was reached in the episode")] = False
    guided_steps: Annotated[int, about("steps whose action came from pi_LLM (transitions with guided true)")] = 0
    global_step: Annotated[int, about("steps of the trial so far, this episode's included")] = 0
    cut_by_step_budget: Annotated[bool | None, about(
        "the trial's step budget (run.max_steps) ended the episode: its last step reached the budget "
        "with neither terminated nor truncated (log format 4; null in older logs)"
    )] = False


class ArmEpisodeEvent(EpisodeEvent, frozen=True, gc=False):
    """``/episode`` of an arm task: the summary plus the robot's placements."""

    placements: Annotated[int, about("arm tasks: placements the robot executed in this episode")] = 0
    failed_placements: Annotated[int, about(
        "arm tasks: of those, the ones that failed (unreachable, outside the cell, tipped, not resting)"
    )] = 0


EPISODE_RECORDS: tuple[type[EpisodeEvent], ...] = (ArmEpisodeEvent,)
"""The ``/episode`` records with extra fields, found by those fields (see :func:`episode_event`)."""


def episode_event(extra: dict[str, Any] | None = None, **summary: Any) -> EpisodeEvent:
    """The ``/episode`` record of ``summary``, with the extra fields an env counted
    (``info["log_episode"]``): the record type whose extra fields they are."""
    if not extra:
        return EpisodeEvent(**summary)
    for record in EPISODE_RECORDS:
        if set(extra) == set(record.__struct_fields__) - set(EpisodeEvent.__struct_fields__):
            return record(**summary, **extra)
    raise ValueError(f"no /episode record has the fields {sorted(extra)}")


TRANSITION_COLUMNS: tuple[str, ...] = tuple(
    f.encode_name for f in msgspec.structs.fields(Transition) if f.default is msgspec.NODEFAULT
)[2:]
"""The columns of every ``/transitions`` record, after ``trial`` and ``episode`` (log format 3)."""
TRANSITION_OPTIONAL: tuple[str, ...] = tuple(
    f.encode_name for f in msgspec.structs.fields(Transition) if f.default is not msgspec.NODEFAULT
)
"""The columns a ``/transitions`` record has only when one of its steps set them (``placement``);
their entries are null where a step did not, and a step's ``/transition`` record then lacks them."""


@functools.cache
def optional_columns(record: type[Transition]) -> tuple[str, ...]:
    """The optional columns of a ``/transitions`` record of ``record``s: :data:`TRANSITION_OPTIONAL`,
    then a task's own step fields (``lagrseq.logs.task_fields``)."""
    return tuple(f.encode_name for f in msgspec.structs.fields(record) if f.default is not msgspec.NODEFAULT)


NO_QUERY_COLUMNS: tuple[str, ...] = ("step", "global_step", "state")
"""The columns of every ``/no_query`` record, after ``trial`` and ``episode`` (log format 3)."""
astuple = msgspec.structs.astuple
_NOT_ASKED = astuple(QueryEvent(0, 0, 0, 0, None, 0))[5:]
"""A decision not to query from its ``decision`` field on: 0 and every later field at its default."""


def not_asked(event: QueryEvent) -> bool:
    """Whether ``event`` is a decision not to query and nothing more (decision 0, every field
    after it at its default): what a ``/no_query`` record holds (log format 3)."""
    return type(event) is QueryEvent and astuple(event)[5:] == _NOT_ASKED


_COLUMNS_FROM = 2
"""Where the columns start in a record's fields (after ``trial`` and ``episode``)."""
decision_entry = attrgetter("trial", "episode", *NO_QUERY_COLUMNS)
"""A decision not to query as what its ``/no_query`` record keeps: (trial, episode, step,
global_step, state)."""
_EPISODE_OF = attrgetter("trial", "episode")


def _one_episode(columns: list[tuple[Any, ...]], count: int) -> bool:
    """Whether the first two columns (trial, episode) hold one value each."""
    trials, episodes = columns[0], columns[1]
    return trials.count(trials[0]) == count and episodes.count(episodes[0]) == count


def transitions_records(steps: list[Transition]) -> list[dict[str, Any]]:
    """Transitions as the columns of ``/transitions`` records (log format 3), one per episode
    (a run of steps with one trial and episode; the loop gives one). Columns are tuples (JSON
    arrays), made by transposing the records in C."""
    columns = list(zip(*map(astuple, steps)))
    if not _one_episode(columns, len(steps)):
        return [record for _, group in groupby(steps, _EPISODE_OF) for record in transitions_records(list(group))]
    record: dict[str, Any] = {"trial": columns[0][0], "episode": columns[1][0]}
    record.update(zip(TRANSITION_COLUMNS, columns[_COLUMNS_FROM:]))
    optional = TRANSITION_OPTIONAL if type(steps[0]) is Transition else optional_columns(type(steps[0]))
    for name, column in zip(optional, columns[_COLUMNS_FROM + len(TRANSITION_COLUMNS):]):
        if column.count(None) < len(column):  # written only by the tasks that set it
            record[name] = column
    return [record]


def no_query_records(decisions: list[tuple[Any, ...]]) -> list[dict[str, Any]]:
    """Decisions not to query, each as its :data:`decision_entry`, as the columns of
    ``/no_query`` records (log format 3), one per episode (a run of decisions with one trial and
    episode)."""
    columns = list(zip(*decisions))
    if not _one_episode(columns, len(decisions)):
        return [record for _, group in groupby(decisions, itemgetter(0, 1)) for record in no_query_records(list(group))]
    record: dict[str, Any] = {"trial": columns[0][0], "episode": columns[1][0]}
    record.update(zip(NO_QUERY_COLUMNS, columns[_COLUMNS_FROM:]))
    return [record]


class View(NamedTuple):
    """A picture of the state for Foxglove (``foxglove.RawImage`` or ``foxglove.Grid``)."""

    topic: str
    message: dict[str, Any]
    log_time: int


class EncodedMessage(dict):  # type: ignore[type-arg]
    """A view's message that carries its JSON already encoded (``json``: the very bytes the
    sink's own encoding of the message gives), so the sink writes them as they are; see
    :class:`lagrseq.logs.foxglove.RawImages`."""

    __slots__ = ("json",)
    json: bytes


class NotAsked(msgspec.Struct, frozen=True, gc=False):
    """A decision not to query and nothing more: ``QueryEvent(trial, episode, step, global_step,
    state, 0)``, which the readers give back. The loop writes it so, and the MCAP sink keeps its
    fields for the episode's ``/no_query`` record (log format 3) with no check of a QueryEvent's
    other fields."""

    trial: int
    episode: int
    step: int
    global_step: int
    state: Any


Event = Transition | QueryEvent | NotAsked | EpisodeEvent | ArmEpisodeEvent | View

def _numpy_scalar(value: Any) -> Any:
    """msgspec's hook for what it cannot encode itself: numpy scalars become Python numbers."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot log a {type(value).__name__}")


_ENCODER = msgspec.json.Encoder(enc_hook=_numpy_scalar)
encode = _ENCODER.encode
"""An event (or a JSON-ready object) as compact JSON bytes; non-finite floats are checked by
the sink (msgspec would write them as null)."""
encode_into = _ENCODER.encode_into
"""``encode_into(event, buffer, -1)`` appends what :data:`encode` gives to a bytearray."""


def log_time(event: Event) -> int:
    """An event's logical log time: the trial's step counter (an episode ends at its last step)."""
    if type(event) is View:
        return event.log_time
    if isinstance(event, EpisodeEvent):  # a task's own episode record too
        return max(event.global_step - 1, 0)
    return event.global_step  # type: ignore[union-attr]


def to_record(event: Event) -> dict[str, Any]:
    """The JSON object of an event, with the contract's field names, in contract order."""
    if type(event) is View:
        return event.message
    if type(event) is NotAsked:  # the /query record it stands for
        event = QueryEvent(*astuple(event), decision=0)  # type: ignore[misc]
    record = msgspec.structs.asdict(event)  # type: ignore[arg-type]
    if isinstance(event, Transition):  # as encoded: optional fields (an arm's placement) only when set
        for name in optional_columns(type(event)):
            if record[name] is None:
                del record[name]
    if isinstance(event, EpisodeEvent):
        return {("return" if k == "return_" else k): v for k, v in record.items()}
    return record


class Sink(Protocol):
    """Where a trial's events go: the MCAP file of the trial, or nowhere (benchmarks). A sink
    buffers an episode itself: its ``/episode`` record ends it (what a Ctrl-C keeps from then
    on). As a context manager it finishes the log, or, on a Ctrl-C, keeps the finished episodes."""

    def write(self, event: Event) -> None:
        """Take one event; its topic and log time follow from its type."""

    def close(self) -> None:
        """Finish (idempotent)."""

    def __enter__(self) -> Any: ...

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None: ...


class NullSink:
    """A sink that keeps nothing: runs without a log (benchmarks measure the logging's cost)."""

    def write(self, event: Event) -> None:
        return None

    def flush(self) -> None:
        return None

    def close(self) -> None:
        return None

    def __enter__(self) -> NullSink:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def jsonable(pattern: Any) -> Any:
    """A pattern as JSON-ready data: a tuple of ints stays as it is (it encodes as a list), an
    array becomes nested lists."""
    if pattern is None:
        return None
    if isinstance(pattern, np.ndarray):
        return pattern.tolist()
    if isinstance(pattern, tuple):
        return pattern
    return [int(x) for x in pattern]
