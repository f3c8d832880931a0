"""`lagrseq record --concurrency N` against the scripted server on 127.0.0.1: N requests in flight,
every answer stored, one shared backoff on 429, and a budget that counts the requests in flight."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from lagrseq import cli
from lagrseq.llm.budget import Budget
from lagrseq.llm.live import SharedBackoff
from lagrseq.llm.store import RecordStore
from tests.llm.conftest import KEY_ENV, FakeOpenAI, Reply


class Arrivals(list):  # type: ignore[type-arg]
    """``FakeOpenAI.requests`` that also notes when each request arrived and how many were open."""

    def __init__(self) -> None:
        super().__init__()
        self.times: list[float] = []

    def append(self, item: Any) -> None:
        self.times.append(time.monotonic())
        super().append(item)


def record(server: FakeOpenAI, store: Path, *extra: str) -> int:
    return cli.main([
        "record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "1", "--store", str(store),
        "--base-url", server.url, "--api-key-env", KEY_ENV, "--server", "ollama", "--quiet", *extra,
    ])


def stored(store: Path) -> int:
    with RecordStore(store, create=False) as opened:
        return sum(len(e.samples) for e in opened.entries())


def test_concurrent_recording_keeps_n_requests_in_flight_and_stores_every_answer(tmp_path: Path, server: FakeOpenAI) -> None:
    open_now = 0
    most = 0
    lock = threading.Lock()
    answer = server.responder

    def slow(prompt: str, temperature: float) -> str:  # each request holds for 0.1 s: they overlap
        nonlocal open_now, most
        with lock:
            open_now += 1
            most = max(most, open_now)
        time.sleep(0.1)
        with lock:
            open_now -= 1
        return answer(prompt, temperature)

    server.responder = slow
    assert record(server, tmp_path / "s", "--samples", "3", "--concurrency", "4") == 0
    assert len(server.requests) == 24 and stored(tmp_path / "s") == 24  # 8 prefixes x 3, one request each
    assert most == 4  # never more than N, and N reached
    assert record(server, tmp_path / "s", "--samples", "3", "--concurrency", "4") == 0
    assert len(server.requests) == 24  # a rerun asks nothing


def test_the_budget_counts_requests_in_flight(tmp_path: Path, server: FakeOpenAI, capsys: pytest.CaptureFixture[str]) -> None:
    server.script.extend(Reply(delay_s=0.05) for _ in range(100))
    code = record(server, tmp_path / "s", "--samples", "3", "--concurrency", "4", "--max-queries", "5")
    assert code == 2 and "--max-queries 5 reached" in capsys.readouterr().err
    # 4 in flight at once, yet exactly 5 sent: the 6th was refused while answers were still due
    assert len(server.requests) == 5 and stored(tmp_path / "s") == 5


def test_budget_reservations_are_checked_against_spent_plus_in_flight() -> None:
    from lagrseq.llm.base import user_query

    query = user_query("cube-stacking", "p", "gpt-4o-mini", 0.0, 10)
    budget = Budget(max_cost_usd=1.0, max_queries=10)
    held = [budget.reserve(query, 1, 0.3) for _ in range(3)]
    with pytest.raises(Exception, match="in flight"):
        budget.reserve(query, 1, 0.3)  # 0.9 in flight + 0.3 could pass 1.0
    budget.settle(held[0], [])  # a request that ended without answers frees its reservation
    assert budget.in_flight_answers == 2 and budget.in_flight_usd == pytest.approx(0.6)
    budget.reserve(query, 1, 0.3)
    budget.release(held[1])  # the same through release (the shared ledger's protocol)
    assert budget.in_flight_answers == 2 and budget.answers == 0


def test_a_429_pauses_every_request_in_flight(tmp_path: Path, server: FakeOpenAI, capsys: pytest.CaptureFixture[str]) -> None:
    arrivals = Arrivals()
    server.requests = arrivals
    wait_s = 0.6
    # The first request is told 429 (retry after 0.6 s) at once, the next three are answered 0.3 s
    # later. With one shared backoff those three threads send nothing more until 0.6 s after the
    # 429; each on its own would send again at about 0.3 s.
    server.script.append(Reply(status=429, body={"error": {"message": "slow down", "type": "rate_limit"}}, headers={"retry-after-ms": str(int(wait_s * 1000))}))
    server.script.extend(Reply(delay_s=0.3) for _ in range(3))
    assert record(server, tmp_path / "s", "--samples", "2", "--concurrency", "4") == 0
    captured = capsys.readouterr()
    assert "every request in flight waits" in captured.out + captured.err
    assert stored(tmp_path / "s") == 16 and len(arrivals) == 17
    # The first request to arrive got the 429 (the script is served in arrival order). Requests
    # already sent when the client received it may still arrive just after it (0.15 s allowed for
    # a loaded machine); after that, nothing may arrive until the pause is over.
    told = arrivals.times[0]
    during = [t for t in arrivals.times if told + 0.15 < t < told + wait_s - 0.05]
    assert during == []


def test_shared_backoff_waits_until_the_longest_hold() -> None:
    now = [0.0]
    slept: list[float] = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        now[0] += seconds

    backoff = SharedBackoff(sleep=sleep, clock=lambda: now[0])
    backoff.wait()
    assert slept == []
    backoff.hold(2.0)
    backoff.hold(0.5)  # a shorter hold does not shorten the pause
    backoff.wait()
    assert sum(slept) == pytest.approx(2.0) and backoff.holds == 2


def test_one_ctrl_c_stops_a_concurrent_recording_at_once_keeping_every_answer_received(tmp_path: Path, server: FakeOpenAI) -> None:
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) with 4 requests in flight:
    exit status 130 with one line, the answers that came back are in the store, and a second
    run asks only for the rest."""
    import os
    import signal
    import subprocess
    import sys

    answered = 0
    lock = threading.Lock()
    answer = server.responder

    def slow(prompt: str, temperature: float) -> str:
        nonlocal answered
        time.sleep(0.2)
        with lock:
            answered += 1
        return answer(prompt, temperature)

    server.responder = slow
    root = Path(__file__).resolve().parents[2]
    store = tmp_path / "s"
    args = [sys.executable, "-m", "lagrseq", "record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "1",
            "--store", str(store), "--base-url", server.url, "--api-key-env", KEY_ENV, "--server", "ollama", "--quiet",
            "--samples", "3", "--concurrency", "4"]
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", KEY_ENV: "sk-test-interrupt-0123456789"}
    process = subprocess.Popen(
        args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 60
        while answered < 8 and time.monotonic() < deadline:
            time.sleep(0.01)
        os.killpg(process.pid, signal.SIGINT)
        _, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, err
    assert err.strip().startswith("lagrseq record: interrupted; answers recorded so far are kept") and "\n" not in err.strip()
    kept = stored(store)
    assert answered - 4 <= kept <= answered  # at most the 4 in flight are lost
    again = 0

    def counted(prompt: str, temperature: float) -> str:
        nonlocal again
        with lock:
            again += 1
        return answer(prompt, temperature)

    server.responder = counted
    assert record(server, store, "--samples", "3", "--concurrency", "4") == 0
    assert again == stored(store) - kept, "the second run asks only for what the first did not keep"


def test_a_ctrl_c_while_answers_are_stored_waits_for_the_transaction(
    tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGINT arriving as a batch of answers is written: the batch is committed first, then the
    recording stops (130). Cut inside the transaction, the connection stayed in it and the
    store's next write retried its BEGIN for ever (a hang after Ctrl-C)."""
    import os
    import signal

    real = RecordStore.add_many
    batches: list[int] = []

    def interrupted(self: RecordStore, groups: Any, checked: bool = False) -> int:
        if not batches:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C as the first batch starts to be written
        batches.append(sum(len(group[2]) for group in groups.values()))
        return real(self, groups, checked)

    monkeypatch.setattr(RecordStore, "add_many", interrupted)
    handler = signal.getsignal(signal.SIGINT)
    try:
        code = record(server, tmp_path / "s", "--samples", "3", "--concurrency", "4")
    finally:
        signal.signal(signal.SIGINT, handler)  # main() leaves "exit at the next Ctrl-C" installed
    monkeypatch.undo()
    assert code == 130
    assert batches and stored(tmp_path / "s") == sum(batches) > 0, "the batch being written when Ctrl-C came is kept"
