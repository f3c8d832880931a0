"""Providers over a recorded store: replay (:class:`RecordedProvider`) and record
(:class:`RecordingProvider`, a wrapper around the provider that answers misses).

Replaying: a query's key (:func:`~lagrseq.llm.store.query_key`) selects the recorded samples and
:class:`~lagrseq.llm.store.SampleChooser` picks one from (run seed, key, occurrence). An entry is
read once per provider and then kept, so a trial sees one fixed set of samples per key even while
another process appends to the store. A miss goes to the ``fallback`` provider (its answer is not
stored; :class:`RefusingProvider` answers it with a refusal) or raises
:class:`~lagrseq.errors.RecordMiss` naming the nearest recorded keys.

Recording, with vcrpy's record modes:

========  ===========================================================================
``once``  record only into a store that was empty when opened; otherwise a miss is an error
``new``   replay what is recorded; top every key asked up to ``samples`` answers (default)
``none``  replay only; a miss is an error (the strict mode of a recorded run)
``all``   always ask the inner provider for ``samples`` fresh answers and append them
========  ===========================================================================

Answers are written to the store as soon as each request returns, one transaction per request,
so an interrupted recording loses nothing already answered.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from lagrseq.errors import RecordMiss
from lagrseq.llm.base import (
    Answer,
    Provider,
    Query,
    pinned,
    sample,
    samplers_of,
    samples_per_request,
    with_samplers,
)
from lagrseq.llm.servers import LLAMA_CPP_SAMPLERS, RECORD_MODES
from lagrseq.llm.store import (
    Entry,
    JsonlStore,
    RecordStore,
    Sample,
    SampleChooser,
    miss_message,
    query_key,
    sample_from_answer,
)

RecordMode = Literal["once", "new", "none", "all"]


class RefusingProvider:
    """The fallback of ``--on-miss refuse``: every query it gets (one a recorded store lacks) is
    answered by a refusal, an empty answer with source ``miss`` that costs nothing and that the loop
    never accepts (:func:`lagrseq.loop.lagr.consult`). The query still counts as a query, so no asking
    policy can gain from answers that were never recorded."""

    name = "refuse"
    REASON = "refused"
    """The refusal's ``finish_reason``."""

    def complete(self, query: Query) -> Answer:
        return Answer(text="", source="miss", model=query.model, finish_reason=self.REASON, cost_usd=0.0)

    def close(self) -> None:
        return None

    def __enter__(self) -> RefusingProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RecordedProvider:
    """Answer from ``store``; misses go to ``fallback`` or raise :class:`RecordMiss`."""

    name = "recorded"

    def __init__(
        self,
        store: RecordStore | JsonlStore,
        endpoint: str,
        run_seed: int,
        fallback: Provider | None = None,
    ) -> None:
        self.store = store
        self.endpoint = endpoint
        self.chooser = SampleChooser(run_seed)
        self.fallback = fallback
        self._entries: dict[str, Entry | None] = {}

    def complete(self, query: Query) -> Answer:
        key, request = query_key(query, self.endpoint)
        entry = self._entry(key)
        if (entry is None or not entry.samples) and not samplers_of(query):
            # answers recorded from llama.cpp carry its samplers pinned to OpenAI's meaning of
            # temperature: they answer the same request as one that names no samplers
            alternative = query_key(with_samplers(query, LLAMA_CPP_SAMPLERS), self.endpoint)[0]
            found = self._entry(alternative)
            if found is not None and found.samples:
                key, entry = alternative, found
        if entry is not None and entry.samples:
            index = self.chooser.choose(key, len(entry.samples))
            return entry.samples[index].answer(key, index)
        if self.fallback is not None:
            return self.fallback.complete(query)
        raise RecordMiss(miss_message(self.store, key, request, query.task))

    def draw_without_replacement(self) -> None:
        """Give each key's recorded samples once each before any is repeated (Fig. 4's probe:
        :class:`~lagrseq.llm.store.SampleChooser`)."""
        self.chooser.without_replacement = True

    def _entry(self, key: str) -> Entry | None:
        if key not in self._entries:
            self._entries[key] = self.store.entry(key)
        return self._entries[key]

    def close(self) -> None:
        if self.fallback is not None:
            self.fallback.close()
        self.store.close()

    def __enter__(self) -> RecordedProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RecordedProvider({self.store!r}, endpoint={self.endpoint!r})"


class JsonlRecordedProvider(RecordedProvider):
    """:class:`RecordedProvider` over a JSONL export (``--provider recorded:FILE.jsonl``), read into
    memory once per process (:class:`~lagrseq.llm.store.JsonlStore`). Its keys are matched under
    the endpoint the file's answers were recorded at (when they name one), so answers of a local
    server (endpoint ``local``) replay without ``--base-url``."""

    def __init__(self, path: str | Path, endpoint: str, run_seed: int, fallback: Provider | None = None) -> None:
        store = JsonlStore(path, Path(path).name)
        if len(store.endpoints) == 1:
            endpoint = str(next(iter(store.endpoints)))
        super().__init__(store, endpoint, run_seed, fallback)


CLAIM_WAIT_S = math.inf
"""How long :meth:`RecordingProvider.top_up` waits for a key that another recorder is filling, by
default (until it is done: the key's claim is let go when its answers are stored)."""


class RecordingProvider:
    """Replay from ``store`` and send what is missing to ``inner``, storing its answers."""

    def __init__(
        self,
        store: RecordStore,
        inner: Provider,
        endpoint: str,
        mode: RecordMode = "new",
        samples: int = 1,
        run_seed: int = 0,
    ) -> None:
        if mode not in RECORD_MODES:
            raise ValueError(f"record mode {mode!r}; expected one of {', '.join(RECORD_MODES)}")
        if samples < 1:
            raise ValueError(f"samples must be at least 1, got {samples}")
        self.store = store
        self.inner = inner
        self.endpoint = endpoint
        self.mode = mode
        self.samples = samples
        self.chooser = SampleChooser(run_seed)
        self.name = f"recorded+{inner.name}"
        self._may_record = mode in ("new", "all") or (mode == "once" and len(store) == 0)
        if self._may_record:
            store.writer()  # a store that cannot be written fails now, before any answer is bought

    def key(self, query: Query) -> tuple[str, dict[str, object]]:
        """``(key, request)`` of ``query`` as the inner provider sends it (with the samplers its
        server pins: :func:`lagrseq.llm.base.pinned`)."""
        return query_key(pinned(self.inner, query), self.endpoint)

    def draw_without_replacement(self) -> None:
        """As :meth:`RecordedProvider.draw_without_replacement`."""
        self.chooser.without_replacement = True

    def wanted(self, entry: Entry | None) -> int:
        """How many new answers this mode asks for, given what the key holds."""
        if not self._may_record:
            return 0
        if self.mode == "all":
            return self.samples
        return max(self.samples - (len(entry.samples) if entry else 0), 0)

    def top_up(
        self, query: Query, on_answers: Callable[[list[Answer]], None] | None = None, wait_s: float = CLAIM_WAIT_S
    ) -> list[Answer] | None:
        """Ask ``inner`` for the answers the mode wants for this query and store them, one request's
        worth at a time; return them (with their record key set). None: another recorder held
        the key's claim for ``wait_s`` seconds (nothing was asked; try again later)."""
        fetched = self._top_up(query, on_answers, wait_s)
        return None if fetched is None else [answer for _, answer in fetched]

    def _top_up(
        self, query: Query, on_answers: Callable[[list[Answer]], None] | None = None, wait_s: float = CLAIM_WAIT_S
    ) -> list[tuple[Sample, Answer]] | None:
        query = pinned(self.inner, query)
        key, request = query_key(query, self.endpoint)
        if self.wanted(self.store.entry(key)) <= 0:
            return []
        # another recorder into this store may be paying for this key right now: claim it, then
        # read it again and ask only for what it still lacks (llm/store.py: Claims)
        claim = self.store.claim(key, wait_s)
        if claim is None:
            return None
        with claim:
            need = self.wanted(self.store.entry(key))
            per_request = samples_per_request(self.inner)
            fetched: list[tuple[Sample, Answer]] = []
            while need > 0:
                batch = sample(self.inner, query, min(need, per_request))
                stored = [sample_from_answer(a, key) for a in batch]
                self.store.add(key, request, query.task, stored)
                fetched.extend((s, replace(a, record_key=key)) for s, a in zip(stored, batch, strict=True))
                need -= len(batch)
                if on_answers is not None:
                    on_answers(batch)
        return fetched

    def complete(self, query: Query) -> Answer:
        fresh = dict((s.id, a) for s, a in self._top_up(query) or ())
        key, request = self.key(query)
        if self.mode == "all" and fresh:
            return next(iter(fresh.values()))  # vcrpy's "all": the answer of a real request, every time
        entry = self.store.entry(key)
        if entry is None or not entry.samples:
            raise RecordMiss(miss_message(self.store, key, request, query.task) + self._why_not())
        # Choose among everything recorded (not just what was fetched now), so that a rerun, which
        # finds all of it recorded, receives the same answer.
        index = self.chooser.choose(key, len(entry.samples))
        chosen = entry.samples[index]
        answer = chosen.answer(key, index)
        paid = fresh.get(chosen.id)
        if paid is not None:  # this very answer was bought just now
            answer = replace(answer, source=paid.source, cost_usd=paid.cost_usd, latency_s=paid.latency_s)
        return answer

    def _why_not(self) -> str:
        if self.mode == "once" and not self._may_record:
            return " (record mode once: the store was not empty, so nothing new is recorded; use mode new)"
        return ""

    def close(self) -> None:
        self.inner.close()
        self.store.close()

    def __enter__(self) -> RecordingProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RecordingProvider({self.store!r}, {self.inner!r}, mode={self.mode!r}, samples={self.samples})"


@dataclass(frozen=True)
class RecordReport:
    """What a recording session did."""

    queries: int
    """Queries (keys) visited."""
    complete: int
    """Of them, keys that hold at least the wanted number of samples afterwards."""
    answers: int
    """New answers recorded."""


def record_queries(
    recorder: RecordingProvider,
    queries: list[Query],
    on_answers: Callable[[list[Answer]], None] | None = None,
    on_query: Callable[[Query], None] | None = None,
) -> RecordReport:
    """Top every query up to the recorder's sample count, in order; a query whose key another
    recorder is filling is left for the end (and then waited for). A budget stop or an
    interruption propagates; everything answered before it is already in the store."""
    answers = 0
    done = 0
    later: list[Query] = []
    for wait_s, batch in ((0.0, queries), (math.inf, later)):
        for query in batch:
            fetched = recorder.top_up(query, on_answers, wait_s)
            if fetched is None:
                later.append(query)
                continue
            answers += len(fetched)
            key, _ = recorder.key(query)
            entry = recorder.store.entry(key)
            done += int(entry is not None and len(entry.samples) >= recorder.samples)
            if on_query is not None:
                on_query(query)
    return RecordReport(queries=len(queries), complete=done, answers=answers)
