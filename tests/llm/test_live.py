"""The live provider against a real HTTP server on 127.0.0.1: retries, failures, samples, usage."""

from __future__ import annotations

import pickle
import time

import numpy as np
import pytest

from lagrseq.errors import ProviderError
from lagrseq.llm.base import Query, sample, user_query
from lagrseq.llm.live import LiveProvider, LiveSettings, Secret, parse_retry_after, redact
from lagrseq.llm.pricing import PriceTable
from lagrseq.tasks import cube
from tests.llm.conftest import KEY_ENV, SECRET, FakeOpenAI, Reply, error_body, fast_settings

TASK = cube.CubeStacking(8)


def query(model: str = "gpt-4o-mini", temperature: float = 0.0) -> Query:
    return user_query(TASK.name, TASK.prompt((4, 5, 6)), model, temperature, 256)


def provider(fake: FakeOpenAI, **changes: object) -> LiveProvider:
    return LiveProvider(fast_settings(fake.url, **changes), rng=np.random.default_rng(0))


def test_an_answer_carries_text_usage_model_fingerprint_latency_and_cost(server: FakeOpenAI) -> None:
    with provider(server) as live:
        answer = live.complete(query())
    body = server.requests[0]
    assert body["model"] == "gpt-4o-mini" and body["max_tokens"] == 256 and body["temperature"] == 0.0
    assert "n" not in body and body["messages"][-1]["content"] == TASK.prompt((4, 5, 6))
    assert server.headers[0]["authorization"] == f"Bearer {SECRET}"
    assert TASK.parse(answer.text).ok
    assert answer.source == "live"
    assert answer.model == "gpt-4o-mini-2024-07-18"  # what the server says it used
    assert answer.system_fingerprint == "fp_test" and answer.finish_reason == "stop"
    assert answer.response_id == "chatcmpl-1"
    usage = answer.usage
    assert usage.prompt_tokens == len(TASK.prompt((4, 5, 6))) // 4 and usage.completion_tokens > 0
    price = PriceTable().lookup("gpt-4o-mini")
    assert price is not None
    expected = (usage.prompt_tokens * 0.15 + usage.completion_tokens * 0.60) / 1e6
    assert answer.cost_usd == pytest.approx(expected)
    assert answer.latency_s > 0


def test_429_with_retry_after_ms_waits_then_succeeds(server: FakeOpenAI) -> None:
    server.script.append(
        Reply(429, error_body("requests", "Rate limit reached", "rate_limit_exceeded"), {"retry-after-ms": "150"})
    )
    retries: list[str] = []
    live = LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0), on_retry=retries.append)
    started = time.perf_counter()
    answer = live.complete(query())
    assert time.perf_counter() - started >= 0.15  # the server's wait, not the 1 ms backoff
    assert len(server.requests) == 2 and TASK.parse(answer.text).ok
    assert len(retries) == 1 and "429" in retries[0] and "0.15 s" in retries[0]
    live.close()


def test_429_with_retry_after_seconds_is_honoured(server: FakeOpenAI) -> None:
    server.script.append(Reply(429, error_body("requests", "slow down"), {"retry-after": "0.1"}))
    slept: list[float] = []
    live = LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0), sleep=slept.append)
    live.complete(query())
    assert slept == [pytest.approx(0.1)]
    live.close()


def test_a_zero_retry_after_backs_off_instead_of_hammering(server: FakeOpenAI) -> None:
    server.script.append(Reply(429, error_body("requests", "slow down"), {"retry-after": "0"}))
    slept: list[float] = []
    settings = fast_settings(server.url, backoff_initial_s=0.5, backoff_max_s=1.0, jitter=0.0)
    with LiveProvider(settings, rng=np.random.default_rng(0), sleep=slept.append) as live:
        live.complete(query())
    assert slept == [0.5]


def test_503_twice_then_success(server: FakeOpenAI) -> None:
    server.script.extend([Reply(503, b"upstream overloaded"), Reply(503, error_body("server_error", "try again"))])
    with provider(server) as live:
        answer = live.complete(query())
    assert len(server.requests) == 3 and answer.source == "live"


@pytest.mark.parametrize("status", [408, 409, 500, 502])
def test_other_transient_statuses_are_retried(server: FakeOpenAI, status: int) -> None:
    server.script.append(Reply(status, error_body("server_error", "hiccup")))
    with provider(server) as live:
        live.complete(query())
    assert len(server.requests) == 2


def test_persistent_5xx_gives_up_after_max_retries(server: FakeOpenAI) -> None:
    server.script.extend(Reply(500, error_body("server_error", "down")) for _ in range(10))
    with provider(server, max_retries=2) as live, pytest.raises(ProviderError, match="gave up after 3 attempts: HTTP 500"):
        live.complete(query())
    assert len(server.requests) == 3


def test_401_fails_at_once_and_never_echoes_the_key(server: FakeOpenAI) -> None:
    echoed = f"Incorrect API key provided: {SECRET}. You can find your API key at https://platform.openai.com."
    server.script.append(Reply(401, error_body("invalid_request_error", echoed, "invalid_api_key")))
    with provider(server) as live, pytest.raises(ProviderError) as caught:
        live.complete(query())
    message = str(caught.value)
    assert len(server.requests) == 1
    assert "HTTP 401" in message and KEY_ENV in message and "\n" not in message
    assert SECRET not in message and SECRET[-12:] not in message


def test_insufficient_quota_fails_at_once(server: FakeOpenAI) -> None:
    body = error_body("insufficient_quota", "You exceeded your current quota, please check your plan and billing details.")
    server.script.append(Reply(429, body, {"retry-after": "1"}))
    with provider(server) as live, pytest.raises(ProviderError, match="no quota left"):
        live.complete(query())
    assert len(server.requests) == 1


@pytest.mark.parametrize(("status", "hint"), [(400, "rejected"), (403, "may not use model"), (404, "check --base-url"), (422, "could not process")])
def test_client_errors_are_not_retried(server: FakeOpenAI, status: int, hint: str) -> None:
    server.script.append(Reply(status, error_body("invalid_request_error", "no")))
    with provider(server) as live, pytest.raises(ProviderError, match=hint):
        live.complete(query())
    assert len(server.requests) == 1


def test_x_should_retry_overrides_the_status(server: FakeOpenAI) -> None:
    server.script.extend([Reply(500, error_body("server_error", "fatal"), {"x-should-retry": "false"})])
    with provider(server) as live, pytest.raises(ProviderError, match="HTTP 500"):
        live.complete(query())
    assert len(server.requests) == 1
    server.script.extend([Reply(400, error_body("invalid_request_error", "busy"), {"x-should-retry": "true"})])
    with provider(server) as live:
        live.complete(query())
    assert len(server.requests) == 3


def test_a_retry_after_longer_than_the_limit_fails_instead_of_sleeping(server: FakeOpenAI) -> None:
    server.script.append(Reply(429, error_body("requests", "come back tomorrow"), {"retry-after": "86400"}))
    with provider(server) as live, pytest.raises(ProviderError, match="wait 86400 s"):
        live.complete(query())
    assert len(server.requests) == 1


def test_a_read_timeout_is_retried_then_reported(server: FakeOpenAI) -> None:
    server.script.extend([Reply(delay_s=5.0), Reply(delay_s=5.0)])
    started = time.perf_counter()
    with provider(server, read_timeout_s=0.2, max_retries=1) as live, pytest.raises(ProviderError, match="0.2 s read timeout"):
        live.complete(query())
    assert time.perf_counter() - started < 2.0
    assert len(server.requests) == 2


def test_a_timeout_then_success(server: FakeOpenAI) -> None:
    server.script.append(Reply(delay_s=5.0))
    with provider(server, read_timeout_s=0.2) as live:
        assert live.complete(query()).source == "live"


def test_a_connection_refused_is_retried_then_reported() -> None:
    import socket

    with socket.socket() as sock:  # a port with nobody listening
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    live = LiveProvider(fast_settings(f"http://127.0.0.1:{port}/v1", max_retries=1), rng=np.random.default_rng(0))
    with pytest.raises(ProviderError, match="connection failed"):
        live.complete(query())
    live.close()


def test_a_body_cut_short_is_retried(server: FakeOpenAI) -> None:
    server.script.append(Reply(body=b'{"choices": [{"index": 0, "mess', extra_length=200))
    with provider(server) as live:
        assert live.complete(query()).source == "live"
    assert len(server.requests) == 2


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (b"", "body is empty"),
        (b"<html>Bad gateway</html>", "not JSON"),
        (b'{"choices": [{"index": 0, "message": {"role": "assi', "not JSON"),  # complete framing, truncated JSON
        ({"id": "x", "choices": []}, "no choices"),
        ({"choices": [{"index": 0}]}, "has no message"),
        ({"choices": [{"index": 0, "message": {"content": 42}}]}, "not text"),
    ],
)
def test_a_malformed_200_body_is_a_clear_error_at_once(server: FakeOpenAI, body: object, message: str) -> None:
    server.script.append(Reply(200, body))
    with provider(server) as live, pytest.raises(ProviderError, match=message):
        live.complete(query())
    assert len(server.requests) == 1


def test_n_samples_in_one_request_share_the_usage_exactly(server: FakeOpenAI) -> None:
    with provider(server) as live:
        answers = sample(live, query(temperature=1.0), 3)
    assert len(server.requests) == 1 and server.requests[0]["n"] == 3
    assert len(answers) == 3 and all(a.response_id == "chatcmpl-1" for a in answers)
    reported = server.completion(server.requests[0], 1)["usage"]
    assert sum(a.usage.prompt_tokens for a in answers) == reported["prompt_tokens"]
    assert sum(a.usage.completion_tokens for a in answers) == reported["completion_tokens"]
    price = PriceTable().lookup("gpt-4o-mini")
    assert price is not None
    request_cost = (reported["prompt_tokens"] * 0.15 + reported["completion_tokens"] * 0.60) / 1e6
    assert sum(a.cost_usd or 0.0 for a in answers) == pytest.approx(request_cost)


def test_servers_without_n_get_one_request_per_sample(server: FakeOpenAI) -> None:
    with provider(server, server="ollama") as live:
        answers = live.complete_n(query(), 3)
    assert len(answers) == 3 and len(server.requests) == 3
    assert all("n" not in body for body in server.requests)


def test_a_server_that_ignores_n_is_topped_up(server: FakeOpenAI) -> None:
    server.honour_n = False
    with provider(server) as live:
        answers = live.complete_n(query(), 3)
    assert len(answers) == 3 and [r.get("n", 1) for r in server.requests] == [3, 2, 1]


def test_an_unpriced_model_has_no_cost(server: FakeOpenAI) -> None:
    with provider(server) as live:
        answer = live.complete(query(model="llama3:8b"))
    assert answer.cost_usd is None and answer.usage.prompt_tokens > 0


def test_a_missing_key_is_a_clear_error(monkeypatch: pytest.MonkeyPatch, server: FakeOpenAI) -> None:
    monkeypatch.delenv(KEY_ENV)
    with pytest.raises(ProviderError, match=f"environment variable {KEY_ENV} is not set"):
        LiveProvider(fast_settings(server.url))
    with pytest.raises(ProviderError, match="OPENAI_API_KEY is not set"):
        LiveProvider(LiveSettings())  # OpenAI's API always needs one
    # a local server with the default variable unset: no Authorization header at all
    with LiveProvider(fast_settings(server.url, api_key_env="OPENAI_API_KEY")) as live:
        live.complete(query())
    assert "authorization" not in server.headers[-1]


def test_backoff_jitter_comes_from_the_generator(server: FakeOpenAI) -> None:
    def delays(seed: int) -> list[float]:
        server.script.extend(Reply(503, b"busy") for _ in range(3))
        slept: list[float] = []
        settings = fast_settings(server.url, backoff_initial_s=1.0, backoff_max_s=3.0, jitter=0.5)
        with LiveProvider(settings, rng=np.random.default_rng(seed), sleep=slept.append) as live:
            live.complete(query())
        return slept

    first, again, other = delays(7), delays(7), delays(8)
    assert first == again and first != other
    for attempt, delay in enumerate(first):
        nominal = min(2.0**attempt, 3.0)
        assert nominal * 0.5 <= delay <= nominal


def test_the_key_is_in_no_repr_str_or_pickle(server: FakeOpenAI) -> None:
    live = provider(server)
    assert SECRET not in repr(live) and KEY_ENV in repr(live)
    assert SECRET not in repr(vars(live)) and SECRET not in f"{live._key}" and SECRET not in str(live._key)
    with pytest.raises(TypeError, match="refusing to pickle"):
        pickle.dumps(live._key)
    live.close()
    live.close()  # idempotent


def test_redact_blanks_the_key_and_key_like_strings() -> None:
    secret = Secret("abc-123-very-secret")
    text = redact("got abc-123-very-secret and sk-proj-AbCdEf123456 here", secret)
    assert "abc-123-very-secret" not in text and "sk-proj-AbCdEf123456" not in text


def test_parse_retry_after() -> None:
    assert parse_retry_after({"retry-after-ms": "250", "retry-after": "9"}) == 0.25
    assert parse_retry_after({"retry-after": "2"}) == 2.0
    assert parse_retry_after({"retry-after": "Wed, 21 Oct 2015 07:28:10 GMT"}, now=1445412480.0) == 10.0
    assert parse_retry_after({"retry-after": "soon"}) is None
    assert parse_retry_after({}) is None


def test_the_answer_cap_is_the_parsers_and_a_longer_live_answer_is_cut_and_marked(server: FakeOpenAI) -> None:
    from lagrseq.llm import records
    from lagrseq.llm.live import CLIPPED
    from lagrseq.tasks import base

    assert records.MAX_ANSWER_CHARS == base.MAX_ANSWER_CHARS, "llm/ mirrors the task parsers' limit"
    long_text = "e,f,g,a,b,c,d,h " + "x" * (2 * records.MAX_ANSWER_CHARS)
    body = {
        "id": "c", "model": "gpt-4o-mini", "object": "chat.completion",
        "choices": [{"index": 0, "message": {"role": "assistant", "content": long_text}, "finish_reason": "stop"}],
        "usage": {"prompt_tokens": 10, "completion_tokens": 20, "total_tokens": 30},
    }
    server.script.append(Reply(body=body))
    notes: list[str] = []
    live = LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0), on_retry=notes.append)
    with live:
        answer = live.complete(query())
    assert len(answer.text) == records.MAX_ANSWER_CHARS and answer.finish_reason == CLIPPED
    assert long_text.startswith(answer.text)
    assert any("cut to 16000" in note for note in notes)
