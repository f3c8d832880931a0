"""Budget guards stop before a request that could pass a limit; nothing over budget is sent."""

from __future__ import annotations

import numpy as np
import pytest

from lagrseq.errors import BudgetExceeded
from lagrseq.llm.base import Query, user_query
from lagrseq.llm.budget import Budget, BudgetedProvider
from lagrseq.llm.live import LiveProvider
from lagrseq.llm.pricing import PriceTable
from lagrseq.tasks import cube
from tests.llm.conftest import FakeOpenAI, fast_settings

TASK = cube.CubeStacking(8)


def query(model: str = "gpt-4o-mini", max_tokens: int = 64) -> Query:
    return user_query(TASK.name, TASK.prompt((4,)), model, 0.0, max_tokens)


def guarded(server: FakeOpenAI, budget: Budget, kind: str = "openai") -> BudgetedProvider:
    live = LiveProvider(fast_settings(server.url, server=kind), rng=np.random.default_rng(0))
    return BudgetedProvider(live, budget, PriceTable())


def test_max_queries_stops_before_the_request_that_would_pass_it(server: FakeOpenAI) -> None:
    budget = Budget(max_queries=5)
    with guarded(server, budget) as provider:
        provider.complete_n(query(), 3)
        with pytest.raises(BudgetExceeded, match="--max-queries 5 reached: 3 answers so far"):
            provider.complete_n(query(), 3)
        provider.complete_n(query(), 2)
    assert budget.answers == 5 and len(server.requests) == 2


def test_max_cost_is_never_passed(server: FakeOpenAI) -> None:
    q = query()
    worst = PriceTable().worst_case(q, 1)
    assert worst is not None
    budget = Budget(max_cost_usd=worst * 3.5)
    with guarded(server, budget) as provider:
        sent = 0
        with pytest.raises(BudgetExceeded, match="could cost up to"):
            for _ in range(100):
                provider.complete(q)
                sent += 1
    assert sent == len(server.requests) >= 3  # real answers cost less than the worst case
    assert 0 < budget.spent_usd <= budget.max_cost_usd  # type: ignore[operator]
    assert budget.spent_usd + worst > budget.max_cost_usd  # type: ignore[operator]


def test_the_worst_case_pays_the_prompt_once_per_request(server: FakeOpenAI) -> None:
    q = query()
    one_request = PriceTable().worst_case(q, 4, requests=1)
    four_requests = PriceTable().worst_case(q, 4, requests=4)
    assert one_request is not None and four_requests is not None
    limit = (one_request + four_requests) / 2  # enough for n=4 in one request, not for four
    with guarded(server, Budget(max_cost_usd=limit)) as provider:
        provider.complete_n(q, 4)
    with guarded(server, Budget(max_cost_usd=limit), kind="ollama") as provider, pytest.raises(BudgetExceeded):
        provider.complete_n(q, 4)
    assert len(server.requests) == 1


def test_an_unpriced_model_cannot_be_guarded_by_cost(server: FakeOpenAI) -> None:
    with guarded(server, Budget(max_cost_usd=1.0)) as provider, pytest.raises(BudgetExceeded, match="no price in the price table"):
        provider.complete(query(model="llama3:8b"))
    assert server.requests == []
    budget = Budget(max_queries=10)  # a query limit alone is fine
    with guarded(server, budget) as provider:
        provider.complete(query(model="llama3:8b"))
    assert budget.unpriced == 1 and budget.spent_usd == 0.0
