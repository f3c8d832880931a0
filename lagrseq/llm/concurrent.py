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
    inner: Provider = recorder.inner
    per_request = samples_per_request(inner)
    queries = [pinned(inner, query) for query in queries]  # keyed as sent (llama.cpp's samplers)
    keys = [query_key(query, recorder.endpoint)[0] for query in queries]
    left = [0] * len(queries)
    """Per query: its requests not yet stored (set when its key is claimed)."""
    todo: deque[int] = deque()
    for index, query in enumerate(queries):
        if recorder.wanted(recorder.store.entry(keys[index])) > 0:
            todo.append(index)
        elif on_query is not None:  # queries with nothing to ask are done at once
            on_query(query)
    later: deque[int] = deque()
    """Queries whose key another recorder was filling: tried again once ``todo`` is empty."""
    ready: deque[_Unit] = deque()
    claims: dict[int, KeyClaim] = {}
    answers = 0
    stop: BaseException | None = None
    flying: dict[cf.Future[list[Answer]], _Unit] = {}

    def next_unit() -> _Unit | None:
        """The next request to send: of a key this recorder has claimed and read again."""
        while not ready:
            if not todo:
                return None
            index = todo.popleft()
            claim = recorder.store.claim(keys[index])
            if claim is None:
                later.append(index)
                continue
            need = recorder.wanted(recorder.store.entry(keys[index]))  # what the holder before left
            if need <= 0:
                claim.release()
                if on_query is not None:
                    on_query(queries[index])
                continue
            claims[index] = claim
            left[index] = math.ceil(need / per_request)
            while need > 0:
                ready.append(_Unit(index, queries[index], min(need, per_request)))
                need -= per_request
        return ready.popleft()

    def ask(unit: _Unit) -> list[Answer]:
        return sample(inner, unit.query, unit.n)

    def store(arrived: list[tuple[_Unit, list[Answer]]]) -> int:
        """Store what arrived together in one transaction; tell the callbacks."""
        groups: dict[str, tuple[dict[str, Any], str | None, list[Sample]]] = {}
        for unit, batch in arrived:
            key, request = query_key(unit.query, recorder.endpoint)
            groups.setdefault(key, (request, unit.query.task, []))[2].extend(sample_from_answer(a, key) for a in batch)
        if groups:
            recorder.store.add_many(groups)
        for unit, batch in arrived:
            if on_answers is not None:
                key = query_key(unit.query, recorder.endpoint)[0]
                on_answers([replace(a, record_key=key) for a in batch])
            left[unit.index] -= 1
            if left[unit.index] == 0:
                claim = claims.pop(unit.index, None)
                if claim is not None:  # its answers are stored: other recorders may read the key
                    claim.release()
                if on_query is not None:
                    on_query(unit.query)
        return sum(len(batch) for _, batch in arrived)

    arrived: list[tuple[_Unit, list[Answer]]] = []
    pool = cf.ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="lagrseq-record")
    try:
        while True:
            # first send what the finished requests made room for, then store their answers
            while stop is None and len(flying) < concurrency:
                unit = next_unit()
                if unit is None:
                    break
                requests = math.ceil(unit.n / per_request)
                try:
                    unit.reserved = budget.reserve(unit.query, unit.n, prices.worst_case(unit.query, unit.n, requests))
                except BudgetExceeded as exc:
                    stop = exc
                    break
                flying[pool.submit(ask, unit)] = unit
            with _interrupt_after():
                answers += store(arrived)
                arrived = []
            if stop is None and not todo and not ready and later:
                todo.extend(later)  # keys other recorders were filling: try them again
                later.clear()
                if not flying:
                    time.sleep(poll_s)
                    continue
            if not flying:
                break
            done, _ = cf.wait(flying, timeout=poll_s, return_when=cf.FIRST_COMPLETED)
            for future in done:
                unit = flying.pop(future)
                error = future.exception()
                batch = [] if error is not None else future.result()
                budget.settle(unit.reserved, batch)
                if error is None:
                    arrived.append((unit, batch))
                elif stop is None or isinstance(stop, BudgetExceeded):  # a failure outranks a budget stop
                    stop = error
    finally:
        if arrived:  # interrupted between a request's end and its storing: keep what was paid for
            with _interrupt_after():
                store(arrived)
        # on Ctrl-C nothing new starts; requests in flight end on their own deadline
        pool.shutdown(wait=not flying, cancel_futures=True)
        for claim in claims.values():
            claim.release()
    if stop is not None:
        raise stop
    complete = 0
    for query in queries:
        entry = recorder.store.entry(query_key(query, recorder.endpoint)[0])
        complete += int(entry is not None and len(entry.samples) >= recorder.samples)
    return RecordReport(queries=len(queries), complete=complete, answers=answers)
