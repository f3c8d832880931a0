"""Reading only /episode and /query never decompresses a transition chunk."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.errors import LogError
from lagrseq.logs.reader import ReadStats, message_counts, read_topic, read_topics
from lagrseq.running import runner


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=80"])
    path = tmp_path_factory.mktemp("log") / "trial-000.mcap"
    runner.run_one(config, 0, 0, "mock", path)
    return path


def test_summary_topics_skip_every_transition_chunk(log: Path) -> None:
    stats = ReadStats()
    topics = read_topics(log, ["/episode", "/query"], stats)
    assert len(topics["/episode"]) == 80
    # a transition chunk and a summary chunk for every few episodes; only the summary chunks are read
    assert stats.chunks % 2 == 0 and 2 < stats.chunks < 40
    assert stats.chunks_decompressed == stats.chunks // 2
    assert stats.messages == len(topics["/episode"]) + len(topics["/query"])

    all_stats = ReadStats()
    transitions = read_topics(log, ["/transition"], all_stats)["/transition"]
    assert all_stats.chunks_decompressed == stats.chunks // 2
    assert all_stats.messages == len(transitions)
    assert len(transitions) == sum(e["length"] for e in topics["/episode"])


def test_read_topics_agrees_with_the_plain_reader(log: Path) -> None:
    topics = read_topics(log, ["/episode", "/query", "/transition"])
    for topic, records in topics.items():
        assert records == read_topic(log, topic)


def test_message_counts_come_from_the_summary(log: Path) -> None:
    counts = message_counts(log)
    topics = read_topics(log, ["/episode", "/query", "/transition"])
    assert counts == {topic: len(records) for topic, records in topics.items()}


def test_a_damaged_summary_chunk_is_a_one_line_error(log: Path, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    with log.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    episode_channel = next(c for c, ch in summary.channels.items() if ch.topic == "/episode")
    chunk = next(c for c in summary.chunk_indexes if episode_channel in c.message_index_offsets)
    data = bytearray(log.read_bytes())
    start = chunk.chunk_start_offset + chunk.chunk_length // 2
    for i in range(start, start + 8):
        data[i] ^= 0x55
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    with pytest.raises(LogError) as info:
        read_topics(damaged, ["/episode"])
    assert "\n" not in str(info.value) and str(damaged) in str(info.value)
