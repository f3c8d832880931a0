"""Log formats: format 3 (an episode's transitions and its decisions not to ask as one columnar
record each) reads as exactly the records format 2 wrote one message each; format 2 (a decision
not to ask without its default fields) and format 1 (every field) read as they always did; all
three replay together."""

from __future__ import annotations

import functools
import json
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from lagrseq import config as cfg
from lagrseq.analysis import loading
from lagrseq.analysis.replay import replay
from lagrseq.logs.events import EpisodeEvent, QueryEvent, Transition, View
from lagrseq.logs.reader import (
    QUERY_DEFAULTS,
    iter_messages,
    message_counts,
    read_info,
    read_log,
    read_rows,
    read_topics,
)
from lagrseq.logs.recover import recover
from lagrseq.logs.schemas import NO_QUERIES, QUERY, TRANSITIONS
from lagrseq.logs.sink import LOG_FORMAT, McapSink
from lagrseq.running import runner

GOLDEN = Path(__file__).resolve().parents[2] / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"
TOPICS = ["/transition", "/query", "/episode"]


def _run(directory: Path, log_format: str, trial: int = 0, episodes: int = 4) -> Path:
    """Trial ``trial`` of the cube LaGR-SEQ run (seed 0, mock), logged in ``log_format``."""
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=[f"run.episodes={episodes}"])
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(runner, "McapSink", functools.partial(McapSink, log_format=log_format))
        return runner.run_one(config, trial, 0, "mock", directory / f"trial-{trial:03d}.mcap").path


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The same trial (20 episodes) in format 2 and in format 3."""
    root = tmp_path_factory.mktemp("runs")
    return {fmt: _run(root / f"format-{fmt}", fmt, episodes=20) for fmt in ("2", "3")}


def _raw(path: Path, topic: str) -> list[dict[str, object]]:
    """The messages of ``topic`` as the plain mcap library and json.loads see them."""
    with path.open("rb") as handle:
        return [json.loads(m.data) for _, _, m in make_reader(handle).iter_messages(topics=[topic])]


def test_format_3_writes_an_episode_as_one_record_of_columns(logs: dict[str, Path]) -> None:
    path = logs["3"]
    assert read_info(path).run["log_format"] == "3" and LOG_FORMAT == "4"
    with path.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    assert {c.topic for c in summary.channels.values()} == {"/transitions", "/query", "/no_query", "/episode"}
    episodes = _raw(path, "/episode")
    transitions = _raw(path, "/transitions")
    assert len(transitions) == len(episodes) == 20
    for record, episode in zip(transitions, episodes, strict=True):
        assert list(record) == TRANSITIONS["required"]  # no placement: the cube places nothing
        assert (record["trial"], record["episode"]) == (0, episode["episode"])
        assert {len(record[name]) for name in TRANSITIONS["required"][2:]} == {episode["length"]}
        first = episode["global_step"] - episode["length"]
        assert record["global_step"] == list(range(first, episode["global_step"]))
        assert record["step"] == list(range(episode["length"]))
    not_asked = _raw(path, "/no_query")
    assert not_asked and all(list(r) == NO_QUERIES["required"] for r in not_asked)
    assert len({r["episode"] for r in not_asked}) == len(not_asked), "one record per episode"
    sent = _raw(path, "/query")
    assert sent and all(r["decision"] == 1 and r["queried"] is True for r in sent), "queries sent stay one record each"
    with path.open("rb") as handle:
        metadata = {m.name: m.metadata for m in make_reader(handle).iter_metadata()}
    decisions = len(sent) + sum(len(r["step"]) for r in not_asked)
    assert metadata["lagrseq.records"] == {"/transition": str(20 * 50), "/query": str(decisions), "/episode": "20"}


def test_format_3_reads_as_exactly_what_format_2_wrote(logs: dict[str, Path]) -> None:
    two, three = logs["2"], logs["3"]
    assert read_info(two).run["log_format"] == "2"
    assert list(iter_messages(three)) == list(iter_messages(two)), "every topic, in log-time order"
    for topic in TOPICS:
        assert list(iter_messages(three, [topic])) == list(iter_messages(two, [topic]))
    old, new = read_log(two, TOPICS), read_log(three, TOPICS)
    assert new.topics == old.topics and new.counts == old.counts
    assert read_topics(three, ["/query", "/episode"]) == read_topics(two, ["/query", "/episode"])
    assert message_counts(three) == message_counts(two) == {t: len(r) for t, r in old.topics.items()}
    assert 0 < len(old.topics["/query"]) < 1000 and {q["decision"] for q in old.topics["/query"]} == {0, 1}
    # both formats write each query with its prompt text (about 1.2 KB a cube query), the same bytes
    assert three.stat().st_size < two.stat().st_size * 0.55


def test_format_2_leaves_defaults_out_and_readers_fill_them_back(logs: dict[str, Path]) -> None:
    raw = _raw(logs["2"], "/query")
    skipped = [r for r in raw if r["decision"] == 0]
    assert skipped and all(list(r) == QUERY["required"] for r in skipped), "six fields, no nulls"
    for reader_records in (
        [r for _, r in iter_messages(logs["2"], ["/query"])],
        read_topics(logs["2"], ["/query"])["/query"],
    ):
        assert len(reader_records) == len(raw)
        for record, plain in zip(reader_records, raw, strict=True):
            assert set(QUERY["properties"]) == record.keys()
            assert record == {**QUERY_DEFAULTS, **plain}


def test_an_old_format_log_reads_as_it_was_written() -> None:
    """The golden log is format 1 (every field written, before ``finish_reason`` and others
    existed): nothing is added to its records."""
    assert "log_format" not in read_info(GOLDEN).run
    for topic in TOPICS:
        assert [r for _, r in iter_messages(GOLDEN, [topic])] == _raw(GOLDEN, topic)
        assert read_topics(GOLDEN, [topic])[topic] == _raw(GOLDEN, topic)


def test_a_cut_format_3_log_is_recovered_with_its_counts(tmp_path: Path) -> None:
    complete = _run(tmp_path / "full", "3", episodes=300)
    partial = tmp_path / "trial-000.mcap.partial"
    partial.write_bytes(complete.read_bytes()[: complete.stat().st_size // 2])
    result = recover(partial)
    data = read_log(result.path, TOPICS)
    kept = data.topics["/episode"]
    assert 0 < len(kept) < 300
    assert data.counts == {topic: len(records) for topic, records in data.topics.items()}
    assert len(data.topics["/transition"]) == sum(e["length"] for e in kept), "whole episodes only"
    full = read_log(complete, TOPICS).topics
    for topic in TOPICS:
        assert data.topics[topic] == full[topic][: len(data.topics[topic])]


def test_counts_without_the_records_metadata_are_counted_from_the_records(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A format-3 log whose ``lagrseq.records`` metadata is missing (or says nonsense) still gives
    the right counts: its columnar records are read and counted."""
    expected = read_log(_run(tmp_path / "a", "3"), TOPICS)
    for said in ({}, {"/transition": "many", "/query": "-1"}):
        monkeypatch.setattr(McapSink, "records", lambda self, said=said: said)
        path = _run(tmp_path / f"b{len(said)}", "3")
        assert message_counts(path) == expected.counts


def test_old_and_new_logs_replay_together(logs: dict[str, Path], tmp_path: Path) -> None:
    """Format 1 (the golden log), format 2 and format 3 logs in one replay: trial 0 of the run in
    format 2 and trial 1 in format 3 make one run."""
    runs = tmp_path / "runs"
    mixed = runs / "mixed"
    mixed.mkdir(parents=True)
    shutil.copy(logs["2"], mixed / "trial-000.mcap")
    _run(mixed, "3", trial=1, episodes=20)
    (runs / "old").mkdir()
    shutil.copy(GOLDEN, runs / "old" / "trial-000.mcap")
    loaded = loading.load([runs])
    assert loaded.files == 3 and not loaded.warnings
    by_trials = {run.trials: run for run in loaded.runs}
    assert set(by_trials) == {(0,), (0, 1)}
    mixed_run = by_trials[(0, 1)]
    assert len(mixed_run.episodes) == 40 and mixed_run.transitions == 2 * 20 * 50
    for run in loaded.runs:
        assert list(run.queries.columns) == list(loading.QUERY_COLUMNS)
        assert set(run.queries["decision"]) == {0, 1}
        assert run.queries.loc[run.queries["decision"] == 0, "provider"].isna().all()
    report = replay([runs], tmp_path / "report")
    assert (tmp_path / "report" / "index.html").is_file() and report.logs.files == 3


# ------------------------------------------------------------------------------------------
# Any episodes: what the sink is given reads back the same from format 2 and format 3
# ------------------------------------------------------------------------------------------
_state = st.lists(st.integers(0, 7), max_size=8).map(tuple)
_placement = st.none() | st.fixed_dictionaries({"row": st.integers(0, 4), "ok": st.booleans()})
_step = st.tuples(
    _state, st.integers(0, 40), st.floats(-1e6, 1e6, allow_nan=False), st.booleans(),
    st.sampled_from(["none", "not asked", "asked"]), _placement, st.booleans(),
)
_episodes = st.lists(st.lists(_step, min_size=1, max_size=30), min_size=1, max_size=6)


def _write(sink: McapSink, episodes: list[list[tuple[object, ...]]], views: bool) -> None:
    global_step = 0
    for number, steps in enumerate(episodes):
        for index, (state, action, reward, guided, decision, placement, view) in enumerate(steps):
            if decision != "none":
                event = QueryEvent(0, number, index, global_step, state, int(decision == "asked"))
                if decision == "asked":
                    event = QueryEvent(0, number, index, global_step, state, 1, queried=True, answer=f"a{global_step}", query_reward=0.5)
                sink.write(event)
            last = index == len(steps) - 1
            sink.write(Transition(0, number, index, global_step, state, action, reward, last, False, guided, placement))  # type: ignore[arg-type]
            if views and view:
                sink.write(View("/view/image", {"step": global_step}, global_step))
            global_step += 1
        sink.write(EpisodeEvent(0, number, 1.0, len(steps), global_step=global_step))
        sink.flush()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(episodes=_episodes, chunk_bytes=st.sampled_from([0, 300, 64 * 1024]))
def test_any_episodes_read_the_same_in_format_2_and_format_3(tmp_path: Path, episodes: list[list[tuple[object, ...]]], chunk_bytes: int) -> None:
    from lagrseq.logs.foxglove import view_topics

    paths = {}
    for fmt in ("2", "3"):
        path = tmp_path / f"{fmt}-{chunk_bytes}.mcap"
        path.unlink(missing_ok=True)
        with McapSink(path, {"config": "{}"}, extra_topics=view_topics(image=True), chunk_bytes=chunk_bytes, log_format=fmt) as sink:
            _write(sink, episodes, views=True)
        paths[fmt] = path
    assert list(iter_messages(paths["3"])) == list(iter_messages(paths["2"]))
    everything = [*TOPICS, "/view/image"]
    old, new = read_log(paths["2"], everything), read_log(paths["3"], everything)
    assert new.topics == old.topics and new.counts == old.counts
    placements = [r for r in new.topics["/transition"] if "placement" in r]
    assert all(r["placement"] is not None for r in placements)


def test_a_sink_writes_formats_2_to_4_only(tmp_path: Path) -> None:
    from lagrseq.errors import LogError

    with pytest.raises(LogError, match="log format '5' cannot be written; expected one of 2, 3, 4"):
        McapSink(tmp_path / "t.mcap", {"config": "{}"}, log_format="5")


@pytest.mark.parametrize(
    ("topic", "record", "said"),
    [
        ("/transitions", {"trial": 0, "episode": 0, "step": [0, 1], "global_step": [0], "state": [[], []], "action": [1, 2],
                          "reward": [0.0, 1.0], "terminated": [False, True], "truncated": [False, False], "guided": [False, False]},
         "does not hold columns of one length"),
        ("/transitions", {"trial": 0, "episode": 0, "step": [0], "global_step": ["0"], "state": [[]], "action": [1],
                          "reward": [0.0], "terminated": [True], "truncated": [False], "guided": [False]},
         "has a global_step that is not an integer"),
        ("/no_query", {"trial": 0, "episode": 0, "step": [0], "global_step": [0]}, "lacks its 'state' field"),
        ("/no_query", {"trial": 0, "step": [0], "global_step": [0], "state": [[]]}, "lacks its trial or episode field"),
    ],
)
def test_a_columnar_record_that_does_not_fit_is_a_one_line_damage_error(tmp_path: Path, topic: str, record: dict[str, object], said: str) -> None:
    from lagrseq.errors import LogError

    path = tmp_path / "t.mcap"
    with McapSink(path, {"config": "{}"}) as sink:
        sink.write_record(topic, record, 0)
        sink.flush()
    wanted = "/transition" if topic == "/transitions" else "/query"
    for read in (lambda: read_topics(path, [wanted]), lambda: list(iter_messages(path)), lambda: read_rows(path, {wanted: ("global_step",)})):
        with pytest.raises(LogError, match=said) as info:
            read()
        assert "\n" not in str(info.value) and str(path) in str(info.value)
    assert read_info(path).complete, "the file itself is whole: only that record is refused"
