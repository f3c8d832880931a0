"""Concurrent recording: N requests in flight, one shared backoff, the budget counting them all.

:func:`record_concurrently` is :func:`~lagrseq.llm.recorded.record_queries` at the server's pace:
every request a recording needs (one per sample on servers that ignore ``n``) is a unit of work;
up to ``concurrency`` of them are in flight on worker threads, sharing one HTTP client and one
:class:`~lagrseq.llm.live.SharedBackoff` (a 429 pauses them all). The dispatcher (the calling
thread) is the only one that touches the budget and the store:

- before sending a request it reserves the request's worst case in the
  :class:`~lagrseq.llm.budget.Budget` (answers asked and worst-case cost of every request in
  flight count), so ``--max-queries`` and ``--max-cost-usd`` hold however many are in flight; a
  request that could pass a limit is not sent, the ones in flight are waited for and stored, and
  then :class:`~lagrseq.errors.BudgetExceeded` is raised;
- each request's answers are stored as soon as it returns (requests that end together: one
  transaction), so an interrupted recording loses nothing already answered;
- a key's requests are made only once its claim is held (:meth:`RecordStore.claim`) and the key
  read again under it, so recorders in other processes into the same store share what they
  record; a key claimed elsewhere is tried again after the others.

A failed request (after the live provider's own retries) stops the dispatch the same way: what is
in flight is waited for and stored, then the error is raised.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import math
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

from lagrseq.errors import BudgetExceeded
from lagrseq.llm.base import Answer, Provider, Query, pinned, sample, samples_per_request
from lagrseq.llm.budget import Budget
from lagrseq.llm.pricing import PriceTable
from lagrseq.llm.recorded import RecordingProvider, RecordReport
from lagrseq.llm.store import KeyClaim, Sample, query_key, sample_from_answer


@dataclass
class _Unit:
    """One request: ``n`` samples of query number ``index``."""

    index: int
    query: Query
    n: int
    reserved: tuple[int, float] = (0, 0.0)
    """The budget ticket of the request in flight (answers asked, worst-case cost)."""


@contextlib.contextmanager
def _interrupt_after() -> Iterator[None]:
    """A Ctrl-C in here takes effect when the block has ended: a store transaction is never cut
    between its BEGIN and its end (a connection left inside a transaction made the next write
    retry its BEGIN for ever). A second Ctrl-C meanwhile ends the process at once (130)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def later(*_: Any) -> None:
        if caught:
            os._exit(130)
        caught.append(1)

    previous = signal.signal(signal.SIGINT, later)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


class _Recording:
    """What one :func:`record_concurrently` keeps track of: the queries to top up (``todo``), those
    whose key another recorder was filling (``later``, tried again once ``todo`` is empty), the
    requests ready to send, the keys this recorder has claimed and each query's requests not yet
    stored."""

    def __init__(
        self,
        recorder: RecordingProvider,
        queries: Sequence[Query],
        on_answers: Callable[[list[Answer]], None] | None,
        on_query: Callable[[Query], None] | None,
    ) -> None:
        self.recorder = recorder
        self.inner: Provider = recorder.inner
        self.per_request = samples_per_request(self.inner)
        self.queries = [pinned(self.inner, query) for query in queries]  # keyed as sent (llama.cpp's samplers)
        self.keys = [query_key(query, recorder.endpoint)[0] for query in self.queries]
        self.left = [0] * len(self.queries)
        """Per query: its requests not yet stored (set when its key is claimed)."""
        self.todo: deque[int] = deque()
        self.later: deque[int] = deque()
        self.ready: deque[_Unit] = deque()
        self.claims: dict[int, KeyClaim] = {}
        self.on_answers = on_answers
        self.on_query = on_query
        for index, query in enumerate(self.queries):
            if recorder.wanted(recorder.store.entry(self.keys[index])) > 0:
                self.todo.append(index)
            else:  # queries with nothing to ask are done at once
                self._done(query)

    def _done(self, query: Query) -> None:
        if self.on_query is not None:
            self.on_query(query)

    def next_unit(self) -> _Unit | None:
        """The next request to send: of a key this recorder has claimed and read again."""
        store = self.recorder.store
        while not self.ready:
            if not self.todo:
                return None
            index = self.todo.popleft()
            claim = store.claim(self.keys[index])
            if claim is None:
                self.later.append(index)
                continue
            need = self.recorder.wanted(store.entry(self.keys[index]))  # what the holder before left
            if need <= 0:
                claim.release()
                self._done(self.queries[index])
                continue
            self.claims[index] = claim
            self.left[index] = math.ceil(need / self.per_request)
            while need > 0:
                self.ready.append(_Unit(index, self.queries[index], min(need, self.per_request)))
                need -= self.per_request
        return self.ready.popleft()

    def ask(self, unit: _Unit) -> list[Answer]:
        return sample(self.inner, unit.query, unit.n)

    def store(self, arrived: list[tuple[_Unit, list[Answer]]]) -> int:
        """Store what arrived together in one transaction; tell the callbacks."""
        endpoint = self.recorder.endpoint
        groups: dict[str, tuple[dict[str, Any], str | None, list[Sample]]] = {}
        for unit, batch in arrived:
            key, request = query_key(unit.query, endpoint)
            groups.setdefault(key, (request, unit.query.task, []))[2].extend(sample_from_answer(a, key) for a in batch)
        if groups:
            self.recorder.store.add_many(groups)
        for unit, batch in arrived:
            if self.on_answers is not None:
                key = query_key(unit.query, endpoint)[0]
                self.on_answers([replace(a, record_key=key) for a in batch])
            self.left[unit.index] -= 1
            if self.left[unit.index] == 0:
                claim = self.claims.pop(unit.index, None)
                if claim is not None:  # its answers are stored: other recorders may read the key
                    claim.release()
                self._done(unit.query)
        return sum(len(batch) for _, batch in arrived)

    def retry_later(self) -> bool:
        """Once nothing else is left, put the keys other recorders were filling back in line;
        whether there were any."""
        if self.todo or self.ready or not self.later:
            return False
        self.todo.extend(self.later)
        self.later.clear()
        return True

    def complete(self) -> int:
        """The queries whose stored entry holds every sample."""
        complete = 0
        for query in self.queries:
            entry = self.recorder.store.entry(query_key(query, self.recorder.endpoint)[0])
            complete += int(entry is not None and len(entry.samples) >= self.recorder.samples)
        return complete


def _send(
    state: _Recording, flying: dict[cf.Future[list[Answer]], _Unit], pool: cf.ThreadPoolExecutor, budget: Budget,
    prices: PriceTable, concurrency: int,
) -> BudgetExceeded | None:
    """Send requests until ``concurrency`` are in flight or none is left, each reserved in the
    budget first; the budget's refusal, if one came."""
    while len(flying) < concurrency:
        unit = state.next_unit()
        if unit is None:
            return None
        requests = math.ceil(unit.n / state.per_request)
        try:
            unit.reserved = budget.reserve(unit.query, unit.n, prices.worst_case(unit.query, unit.n, requests))
        except BudgetExceeded as exc:
            return exc
        flying[pool.submit(state.ask, unit)] = unit
    return None


def _receive(
    flying: dict[cf.Future[list[Answer]], _Unit], budget: Budget, arrived: list[tuple[_Unit, list[Answer]]],
    stop: BaseException | None, poll_s: float,
) -> BaseException | None:
    """Wait up to ``poll_s`` for requests to end: settle each in the budget, add its answers to
    ``arrived``; returns what stops the recording (a request's failure outranks a budget stop)."""
    done, _ = cf.wait(flying, timeout=poll_s, return_when=cf.FIRST_COMPLETED)
    for future in done:
        unit = flying.pop(future)
        error = future.exception()
        batch = [] if error is not None else future.result()
        budget.settle(unit.reserved, batch)
        if error is None:
            arrived.append((unit, batch))
        elif stop is None or isinstance(stop, BudgetExceeded):
            stop = error
    return stop


def record_concurrently(
    recorder: RecordingProvider,
    queries: Sequence[Query],
    budget: Budget,
    prices: PriceTable,
    concurrency: int,
    on_answers: Callable[[list[Answer]], None] | None = None,
    on_query: Callable[[Query], None] | None = None,
    poll_s: float = 0.2,
) -> RecordReport:
    """Top every query up to the recorder's sample count with up to ``concurrency`` requests in
    flight. ``recorder.inner`` must be the unbudgeted provider (thread-safe: the live one);
    ``budget`` is checked and charged here."""
    if concurrency < 1:
        raise ValueError(f"concurrency must be at least 1, got {concurrency}")
    state = _Recording(recorder, queries, on_answers, on_query)
    answers = 0
    stop: BaseException | None = None
    flying: dict[cf.Future[list[Answer]], _Unit] = {}
    arrived: list[tuple[_Unit, list[Answer]]] = []
    pool = cf.ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="lagrseq-record")
    try:
        while True:
            # first send what the finished requests made room for, then store their answers
            if stop is None:
                stop = _send(state, flying, pool, budget, prices, concurrency)
            with _interrupt_after():
                answers += state.store(arrived)
                arrived = []
            if stop is None and state.retry_later() and not flying:  # keys other recorders were filling
                time.sleep(poll_s)
                continue
            if not flying:
                break
            stop = _receive(flying, budget, arrived, stop, poll_s)
    finally:
        if arrived:  # interrupted between a request's end and its storing: keep what was paid for
            with _interrupt_after():
                state.store(arrived)
        # on Ctrl-C nothing new starts; requests in flight end on their own deadline
        pool.shutdown(wait=not flying, cancel_futures=True)
        for claim in state.claims.values():
            claim.release()
    if stop is not None:
        raise stop
    return RecordReport(queries=len(state.queries), complete=state.complete(), answers=answers)
