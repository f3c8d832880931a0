"""The sink encodes finished episodes many at a time: the same file as encoding each at its end,
a Ctrl-C in the middle of a batch still keeps every finished episode, and a record that cannot
be encoded is dropped with a LogError while the rest of the log is written."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from lagrseq.errors import LogError
from lagrseq.logs.events import EpisodeEvent, NotAsked, QueryEvent, Transition
from lagrseq.logs.reader import read_info, read_topics
from lagrseq.logs.recover import recover
from lagrseq.logs.sink import McapSink


class EachAtItsEnd(McapSink):
    """The reference: every episode's transitions encoded as the episode ends."""

    def _held_bytes(self) -> float:
        return math.inf if self._held_steps else 0


def _write(sink: McapSink, lengths: list[int], query_every: int, stop: tuple[int, int] | None = None) -> None:
    """Episodes of the given lengths: a transition a step, a query (asked, with its text) or a
    decision not to query every ``query_every`` steps, then the /episode record. ``stop``:
    (episode, step) where a KeyboardInterrupt comes."""
    global_step = 0
    for episode, length in enumerate(lengths):
        for step in range(length):
            if stop == (episode, step):
                raise KeyboardInterrupt
            if step % query_every == 0:
                if (episode + step) % 3:
                    sink.write(NotAsked(0, episode, step, global_step, (step % 5,)))
                else:
                    sink.write(QueryEvent(0, episode, step, global_step, (step % 5,), 1, queried=True,
                                          answer=f"['a', 'b'] {episode}.{step}", evaluation=0.5, query_reward=-1.0,
                                          prompt="Stack the cubes. " * (1 + step % 4)))
            sink.write(Transition(0, episode, step, global_step, tuple(range(step % 6)), step % 4,
                                  float(step % 3) - 0.5, False, step == length - 1, step % 7 == 0))
            global_step += 1
        sink.write(EpisodeEvent(0, episode, float(length), length, global_step=global_step))


@settings(max_examples=40, deadline=None)
@given(
    lengths=st.lists(st.integers(1, 60), min_size=1, max_size=30),
    query_every=st.integers(1, 20),
    chunk_bytes=st.sampled_from([0, 300, 3000, 20000, 128 * 1024]),
)
def test_episodes_encoded_many_at_a_time_give_the_file_of_each_encoded_at_its_end(
    tmp_path_factory: pytest.TempPathFactory, lengths: list[int], query_every: int, chunk_bytes: int
) -> None:
    folder = tmp_path_factory.mktemp("batches")
    files = []
    for kind in (McapSink, EachAtItsEnd):
        path = folder / f"{kind.__name__}.mcap"
        with kind(path, {"config": "{}"}, chunk_bytes=chunk_bytes) as sink:
            _write(sink, lengths, query_every)
        files.append(path.read_bytes())
    assert files[0] == files[1]


@pytest.mark.parametrize("step", ["_encode_columns", "_encode_messages"])
def test_a_ctrl_c_in_the_middle_of_a_batch_keeps_every_finished_episode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                         step: str) -> None:
    """The interrupt comes while finished episodes are being encoded, their transitions (some
    already in the open chunk) or their queries and summaries (in the held chunk): what the
    batch added is taken out again, and every finished episode is written once."""
    calls: list[int] = []
    original = getattr(McapSink, step)

    def interrupted(self: McapSink, items: list[Any]) -> None:
        calls.append(len(items))
        original(self, items)
        if len(calls) == (6 if step == "_encode_columns" else 2):  # part of a batch is in: interrupt
            raise KeyboardInterrupt

    monkeypatch.setattr(McapSink, step, interrupted)
    path = tmp_path / "trial-000.mcap"
    with pytest.raises(KeyboardInterrupt), McapSink(path, {"config": "{}"}, chunk_bytes=6000) as sink:
        _write(sink, [30] * 20, query_every=7)
    result = recover(path.with_name(path.name + ".partial"))
    topics = read_topics(result.path, ["/episode", "/transition", "/query"])
    finished = [episode["episode"] for episode in topics["/episode"]]
    assert finished == list(range(len(finished))) and len(finished) >= 4
    steps = [(row["episode"], row["step"]) for row in topics["/transition"]]
    assert steps == [(episode, step) for episode in finished for step in range(30)], "each step once, in order"
    decisions = [(row["episode"], row["step"]) for row in topics["/query"]]
    assert decisions == [(episode, step) for episode in finished for step in range(0, 30, 7)], "each decision once"


class Unencodable:
    """A value JSON has no form for (what a faulty task could put in a state)."""


def test_an_episode_that_cannot_be_encoded_is_dropped_and_the_log_says_failed(tmp_path: Path) -> None:
    path = tmp_path / "trial-000.mcap"
    with pytest.raises(LogError, match="not JSON-serialisable .*Transition"), \
            McapSink(path, {"config": "{}"}, chunk_bytes=128 * 1024) as sink:
        for episode in range(4):
            for step in range(20):
                state = (Unencodable(),) if episode == 2 and step == 5 else (step,)
                sink.write(Transition(0, episode, step, episode * 20 + step, state, 0, 1.0, False, False, False))
            sink.write(EpisodeEvent(0, episode, 20.0, 20, global_step=(episode + 1) * 20))
    status = read_info(path).status
    assert status["status"] == "failed" and "not JSON-serialisable" in status["error"]
    topics = read_topics(path, ["/episode", "/transition"])
    assert [row["episode"] for row in topics["/episode"]] == [0, 1, 2, 3]
    assert sorted({row["episode"] for row in topics["/transition"]}) == [0, 1, 3], "episode 2's transitions dropped"
    with path.open("rb") as handle:
        records = {m.name: m.metadata for m in make_reader(handle).iter_metadata()}["lagrseq.records"]
    assert records["/transition"] == "60", "the counts are of what was written"


def test_a_query_that_cannot_be_encoded_is_dropped_and_the_log_says_failed(tmp_path: Path) -> None:
    path = tmp_path / "trial-000.mcap"
    with pytest.raises(LogError, match="not JSON-serialisable .*QueryEvent"), \
            McapSink(path, {"config": "{}"}) as sink:
        for episode in range(3):
            answer = "a lone \ud800 surrogate" if episode == 1 else "['a']"
            sink.write(QueryEvent(0, episode, 0, episode * 10, (0,), 1, queried=True, answer=answer))
            for step in range(10):
                sink.write(Transition(0, episode, step, episode * 10 + step, (step,), 0, 1.0, False, False, False))
            sink.write(EpisodeEvent(0, episode, 10.0, 10, queries=1, global_step=(episode + 1) * 10))
    assert read_info(path).status["status"] == "failed"
    topics = read_topics(path, ["/episode", "/query", "/transition"])
    assert [row["episode"] for row in topics["/query"]] == [0, 2]
    assert len(topics["/transition"]) == 30 and len(topics["/episode"]) == 3


def test_what_the_last_episode_left_without_its_episode_record_is_written(tmp_path: Path) -> None:
    """A trial that fails mid-episode: that episode's steps, decisions and queries so far are in
    the log with the finished episodes, after them."""
    path = tmp_path / "trial-000.mcap"
    with McapSink(path, {"config": "{}"}, chunk_bytes=3000) as sink:
        _write(sink, [25] * 6, query_every=4)
        for step in range(7):
            if step % 4 == 0:
                sink.write(QueryEvent(0, 6, step, 150 + step, (0,), 1, queried=True, answer="['a']"))
            sink.write(Transition(0, 6, step, 150 + step, (step,), 0, 1.0, False, False, False))
        sink.finish("failed", "RuntimeError: the env broke")
    topics = read_topics(path, ["/episode", "/transition", "/query"])
    assert len(topics["/episode"]) == 6 and len(topics["/transition"]) == 6 * 25 + 7
    assert [row["step"] for row in topics["/query"] if row["episode"] == 6] == [0, 4]
    assert read_info(path).status["status"] == "failed"
