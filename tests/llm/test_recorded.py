"""The recording wrapper: vcrpy modes, top-up to K samples, nothing lost on interruption."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lagrseq.errors import RecordMiss
from lagrseq.llm.base import Answer, Message, Query, Usage
from lagrseq.llm.mock import MockProvider
from lagrseq.llm.recorded import RecordedProvider, RecordingProvider, record_queries
from lagrseq.llm.store import RecordStore, query_key

ENDPOINT = "api.openai.com"


def query(prompt: str = "complete ['e','f']") -> Query:
    return Query("cube-stacking", "gpt-3.5-turbo", (Message("user", prompt),), 1.0, 256)


class Counting:
    """A provider that numbers its answers, so each one is distinguishable, and counts calls."""

    name = "counting"

    def __init__(self, per_request: int = 1, fail_at: int | None = None) -> None:
        self.calls = 0
        self.answers = 0
        self.per_request = per_request
        self.fail_at = fail_at

    @property
    def max_samples_per_request(self) -> int:
        return self.per_request

    def complete(self, query: Query) -> Answer:
        return self.complete_n(query, 1)[0]

    def complete_n(self, query: Query, n: int) -> list[Answer]:
        self.calls += 1
        if self.fail_at is not None and self.calls >= self.fail_at:
            raise KeyboardInterrupt
        out = []
        for _ in range(n):
            self.answers += 1
            out.append(Answer(f"answer {self.answers}", "live", "gpt-3.5-turbo-0125", Usage(100, 10), cost_usd=0.001))
        return out

    def close(self) -> None:
        return None

    def __enter__(self) -> Counting:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def stored(directory: Path, q: Query) -> list[str]:
    with RecordStore(directory, create=False) as store:
        entry = store.entry(query_key(q, ENDPOINT)[0])
    return [] if entry is None else [s.text for s in entry.samples]


def test_new_tops_every_key_up_to_k_and_then_asks_nothing(tmp_path: Path) -> None:
    inner = Counting(per_request=4)
    with RecordingProvider(RecordStore(tmp_path / "s"), inner, ENDPOINT, "new", samples=10) as recorder:
        report = record_queries(recorder, [query(), query("complete ['e']")])
    assert report.answers == 20 and report.complete == 2 and inner.calls == 6  # 4 + 4 + 2 per key
    assert len(stored(tmp_path / "s", query())) == 10
    again = Counting()
    with RecordingProvider(RecordStore(tmp_path / "s"), again, ENDPOINT, "new", samples=10) as recorder:
        record_queries(recorder, [query(), query("complete ['e']")])
        recorder.complete(query())
    assert again.calls == 0
    more = Counting()
    with RecordingProvider(RecordStore(tmp_path / "s"), more, ENDPOINT, "new", samples=12) as recorder:
        record_queries(recorder, [query()])
    assert more.answers == 2 and len(stored(tmp_path / "s", query())) == 12


def test_once_records_only_into_an_empty_store(tmp_path: Path) -> None:
    with RecordingProvider(RecordStore(tmp_path / "s"), Counting(), ENDPOINT, "once", samples=2) as recorder:
        recorder.complete(query())
    inner = Counting()
    with RecordingProvider(RecordStore(tmp_path / "s"), inner, ENDPOINT, "once", samples=2) as recorder:
        assert recorder.complete(query()).source == "recorded"
        with pytest.raises(RecordMiss, match="record mode once"):
            recorder.complete(query("complete ['e']"))
    assert inner.calls == 0


def test_none_never_asks(tmp_path: Path) -> None:
    inner = Counting()
    with RecordingProvider(RecordStore(tmp_path / "s"), inner, ENDPOINT, "none", samples=3) as recorder, pytest.raises(RecordMiss, match="no recorded answer"):
        recorder.complete(query())
    assert inner.calls == 0


def test_all_appends_fresh_answers_every_time_and_returns_one(tmp_path: Path) -> None:
    inner = Counting(per_request=8)
    with RecordingProvider(RecordStore(tmp_path / "s"), inner, ENDPOINT, "all", samples=3) as recorder:
        first = recorder.complete(query())
        second = recorder.complete(query())
    assert (first.text, second.text) == ("answer 1", "answer 4") and first.source == "live"
    assert stored(tmp_path / "s", query()) == [f"answer {i}" for i in range(1, 7)]


def test_an_answer_is_chosen_among_all_recorded_samples_so_a_rerun_gets_the_same(tmp_path: Path) -> None:
    with RecordingProvider(RecordStore(tmp_path / "s"), Counting(), ENDPOINT, "new", samples=5, run_seed=3) as recorder:
        live = [recorder.complete(query()) for _ in range(4)]
    # the first query bought all five samples, so the one it was served was paid for just now
    assert [a.source for a in live] == ["live", "recorded", "recorded", "recorded"]
    assert live[0].cost_usd == 0.001 and all(a.cost_usd == 0.0 for a in live[1:])
    with RecordedProvider(RecordStore(tmp_path / "s", create=False), ENDPOINT, 3) as replay:
        again = [replay.complete(query()) for _ in range(4)]
    assert [a.text for a in again] == [a.text for a in live]
    assert [a.sample_index for a in again] == [a.sample_index for a in live]


def test_an_interrupted_recording_keeps_every_answer_already_received(tmp_path: Path) -> None:
    inner = Counting(per_request=1, fail_at=4)  # the 4th request is interrupted
    with RecordingProvider(RecordStore(tmp_path / "s"), inner, ENDPOINT, "new", samples=5) as recorder, pytest.raises(KeyboardInterrupt):
        record_queries(recorder, [query()])
    assert stored(tmp_path / "s", query()) == ["answer 1", "answer 2", "answer 3"]
    resumed = Counting()
    with RecordingProvider(RecordStore(tmp_path / "s"), resumed, ENDPOINT, "new", samples=5) as recorder:
        record_queries(recorder, [query()])
    assert resumed.answers == 2 and len(stored(tmp_path / "s", query())) == 5


def test_a_recorded_run_can_fall_back_to_the_mock_without_storing(tmp_path: Path) -> None:
    mock = MockProvider(lambda prompt, t, rng: "['a']", np.random.default_rng(0))
    with RecordedProvider(RecordStore(tmp_path / "s"), ENDPOINT, 0, fallback=mock) as provider:
        answer = provider.complete(query())
    assert answer.source == "mock" and answer.text == "['a']"
    assert stored(tmp_path / "s", query()) == []


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="record mode"):
        RecordingProvider(None, Counting(), ENDPOINT, "sometimes")  # type: ignore[arg-type]
