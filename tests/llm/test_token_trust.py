"""Token counts from a server are believed only as far as the request allows: completion tokens up
to ``n * max_tokens``, prompt tokens up to the prompt's own bound; a count that is missing,
negative or not a whole number is the worst case. The budget guard and the spent amount agree."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from lagrseq.errors import BudgetExceeded
from lagrseq.llm.base import Query, Usage, user_query
from lagrseq.llm.budget import Budget, BudgetedProvider
from lagrseq.llm.live import LiveProvider, believed_usage
from lagrseq.llm.pricing import PriceTable, prompt_token_bound
from lagrseq.tasks import cube
from tests.llm.conftest import FakeOpenAI, Reply, fast_settings

TASK = cube.CubeStacking(8)
MAX_TOKENS = 64


def query(max_tokens: int = MAX_TOKENS) -> Query:
    return user_query(TASK.name, TASK.prompt((4, 5)), "gpt-4o-mini", 0.0, max_tokens)


def completion(usage: Any, choices: int = 1) -> dict[str, Any]:
    body: dict[str, Any] = {
        "id": "chatcmpl-x",
        "model": "gpt-4o-mini-2024-07-18",
        "choices": [{"index": i, "message": {"role": "assistant", "content": "['e', 'f']"}, "finish_reason": "stop"} for i in range(choices)],
    }
    if usage is not ...:
        body["usage"] = usage
    return body


def test_honest_counts_are_believed() -> None:
    usage, notes = believed_usage({"prompt_tokens": 40, "completion_tokens": 12, "prompt_tokens_details": {"cached_tokens": 8}}, query(), 1)
    assert usage == Usage(40, 12, 8) and notes == []
    assert believed_usage({"prompt_tokens": 40.0, "completion_tokens": 0}, query(), 1)[0] == Usage(40, 0, 0)


def test_counts_beyond_what_the_request_can_use_are_capped() -> None:
    q = query()
    usage, notes = believed_usage({"prompt_tokens": 10**12, "completion_tokens": 10**12, "prompt_tokens_details": {"cached_tokens": 10**12}}, q, 3)
    assert usage == Usage(prompt_token_bound(q), 3 * MAX_TOKENS, prompt_token_bound(q))
    kinds = {kind for kind, _ in notes}
    assert kinds == {"capped-prompt_tokens", "capped-completion_tokens", "capped-cached_tokens"}
    assert all("1000000000000" in note for _, note in notes)


@pytest.mark.parametrize("bad", [-5, 1.5, float("nan"), float("inf"), "12", None, True, [3], {"n": 1}])
def test_an_invalid_count_is_the_worst_case_with_a_note(bad: Any) -> None:
    q = query()
    usage, notes = believed_usage({"prompt_tokens": bad, "completion_tokens": bad}, q, 2)
    assert usage == Usage(prompt_token_bound(q), 2 * MAX_TOKENS, 0)
    assert [kind for kind, _ in notes] == ["invalid-prompt_tokens", "invalid-completion_tokens"]
    assert all("worst case" in note and "\n" not in note for _, note in notes)


def test_no_usage_at_all_is_the_worst_case() -> None:
    q = query()
    for raw in (None, "lots", [1, 2]):
        usage, notes = believed_usage(raw, q, 1)
        assert usage == Usage(prompt_token_bound(q), MAX_TOKENS, 0)
        assert [kind for kind, _ in notes] == ["no-usage"]


def test_a_server_claiming_a_trillion_tokens_is_charged_no_more_than_the_worst_case(server: FakeOpenAI) -> None:
    q = query()
    prices = PriceTable()
    worst = prices.worst_case(q, 1)
    assert worst is not None
    server.script.extend(Reply(body=completion({"prompt_tokens": 10**12, "completion_tokens": 10**12})) for _ in range(3))
    warnings: list[str] = []
    budget = Budget(max_cost_usd=worst * 2.5)
    live = LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0), on_warning=warnings.append)
    with BudgetedProvider(live, budget, prices) as guarded:
        first = guarded.complete(q)
        assert first.cost_usd == pytest.approx(worst)
        assert first.usage == Usage(prompt_token_bound(q), MAX_TOKENS, 0)
        guarded.complete(q)
        with pytest.raises(BudgetExceeded, match="could cost up to"):
            guarded.complete(q)  # 2 x worst spent; a third could pass 2.5 x worst
    assert len(server.requests) == 2 and budget.spent_usd == pytest.approx(2 * worst)
    # told once per kind, not once per answer
    assert len(warnings) == 2 and all("more than the request can have used" in w for w in warnings)
    assert any("prompt_tokens = 1000000000000" in w for w in warnings)


def test_a_server_reporting_negative_or_no_tokens_is_charged_the_worst_case(server: FakeOpenAI) -> None:
    q = query()
    prices = PriceTable()
    worst = prices.worst_case(q, 1)
    server.script.extend(
        [
            Reply(body=completion({"prompt_tokens": -5, "completion_tokens": "lots"})),
            Reply(body=completion(...)),  # no usage object
        ]
    )
    warnings: list[str] = []
    with LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0), on_retry=warnings.append) as live:
        answers = [live.complete(q), live.complete(q)]
    assert [a.cost_usd for a in answers] == [pytest.approx(worst), pytest.approx(worst)]
    assert len(warnings) == 3  # invalid prompt, invalid completion, no usage; each said once
    assert any("prompt_tokens = -5" in w for w in warnings) and any("completion_tokens = a str" in w for w in warnings)
    assert any("reported no usage" in w for w in warnings)


def test_n_samples_share_a_capped_request_evenly(server: FakeOpenAI) -> None:
    q = query()
    server.script.append(Reply(body=completion({"prompt_tokens": 10**9, "completion_tokens": 10**9}, choices=3)))
    with LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0)) as live:
        answers = live.complete_n(q, 3)
    assert sum(a.usage.completion_tokens for a in answers) == 3 * MAX_TOKENS
    assert sum(a.usage.prompt_tokens for a in answers) == prompt_token_bound(q)  # the prompt is paid once
    worst = PriceTable().worst_case(q, 3, requests=1)
    assert sum(a.cost_usd or 0.0 for a in answers) == pytest.approx(worst)
