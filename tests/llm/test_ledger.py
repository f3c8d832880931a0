"""The run-wide budget ledger: reservations taken by several processes at once never pass a limit."""

from __future__ import annotations

import multiprocessing
from pathlib import Path

import pytest

from lagrseq.errors import BudgetExceeded, StoreError
from lagrseq.llm import ledger
from lagrseq.llm.base import Answer, Message, Query, Usage
from lagrseq.llm.ledger import SharedBudget


def _query() -> Query:
    return Query(task="cube-stacking", model="gpt-4o-mini", messages=(Message("user", "1 2 3"),), temperature=0.0, max_tokens=10)


def _answer(cost: float | None) -> Answer:
    return Answer(text="4", source="live", model="gpt-4o-mini", usage=Usage(1, 1), cost_usd=cost)


def _spend(path: str, worker: int, tries: int, queue: multiprocessing.Queue) -> None:  # type: ignore[type-arg]
    budget = SharedBudget(path, max_cost_usd=2.0, max_queries=50)
    granted = 0
    for _ in range(tries):
        try:
            ticket = budget.reserve(_query(), 1, 0.03)
        except BudgetExceeded:
            continue
        budget.settle(ticket, [_answer(0.02)])
        granted += 1
    budget.close()
    queue.put(granted)


def test_four_processes_reserving_at_once_stop_exactly_at_the_limit(tmp_path: Path) -> None:
    path = str(tmp_path / "ledger.sqlite")
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    workers = [context.Process(target=_spend, args=(path, w, 30, queue)) for w in range(4)]
    for w in workers:
        w.start()
    granted = [queue.get(timeout=120) for _ in workers]
    for w in workers:
        w.join(timeout=60)
    # 120 tries for 50 answers: the query limit binds, exactly (the cost limit, $2, does not)
    assert sum(granted) == 50
    budget = SharedBudget(path, 2.0, 50)
    assert budget.answers == 50 and budget.held_usd == 0.0
    assert budget.spent_usd == pytest.approx(1.0)
    with pytest.raises(BudgetExceeded, match="--max-queries 50 reached.*one budget for every trial"):
        budget.reserve(_query(), 1, 0.0)


def test_the_cost_limit_counts_the_worst_case_of_the_next_request(tmp_path: Path) -> None:
    budget = SharedBudget(tmp_path / "l.sqlite", max_cost_usd=1.0, max_queries=None)
    granted = 0
    while True:
        try:
            ticket = budget.reserve(_query(), 1, 0.03)
        except BudgetExceeded as exc:
            assert "--max-cost-usd 1 reached" in str(exc)
            break
        budget.settle(ticket, [_answer(0.02)])
        granted += 1
    assert granted == 49 and budget.spent_usd <= 1.0  # a 50th could cost 0.98 + 0.03 > 1


def test_a_held_reservation_counts_at_its_worst_case_until_settled(tmp_path: Path) -> None:
    budget = SharedBudget(tmp_path / "l.sqlite", max_cost_usd=0.10, max_queries=None)
    crashed = budget.reserve(_query(), 1, 0.06)  # a worker that dies mid-request never settles
    with pytest.raises(BudgetExceeded, match=r"\$0.0600 and 1 answers held"):
        budget.reserve(_query(), 1, 0.06)
    budget.release(budget.reserve(_query(), 1, 0.04))  # a failed request costs nothing
    kept = budget.reserve(_query(), 1, 0.04)
    budget.keep(kept)  # Ctrl-C mid-request: charged at its worst case
    assert budget.spent_usd == pytest.approx(0.04) and budget.held_usd == pytest.approx(0.06)
    assert crashed != kept


def test_unpriced_answers_are_counted_and_a_network_file_system_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    budget = SharedBudget(tmp_path / "l.sqlite", max_cost_usd=None, max_queries=3)
    budget.settle(budget.reserve(_query(), 2, None), [_answer(None), _answer(0.01)])
    assert (budget.answers, budget.unpriced) == (2, 1)
    monkeypatch.setattr(ledger, "file_system_of", lambda _: "nfs4")
    with pytest.raises(StoreError, match="nfs4 file system, where SQLite's locks are unsafe"):
        SharedBudget(tmp_path / "other.sqlite", 1.0, None)
