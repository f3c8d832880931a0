"""``read_rows`` (what replay reads): every record of a topic straight into the tuple of the columns
asked for. It must give exactly what ``read_log``'s records give as rows (and so the same pandas
frames), on logs of every format and on any records, unusual and damaged ones included: then it
reads the chunk the way ``read_log`` does and fails with the same one line."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lagrseq import config as cfg
from lagrseq.analysis import loading
from lagrseq.errors import LogError
from lagrseq.logs import reader
from lagrseq.logs.columns import QUERY_DEFAULTS
from lagrseq.logs.reader import ReadStats, read_log, read_rows
from lagrseq.logs.sink import McapSink
from lagrseq.running import runner

GOLDEN = Path(__file__).resolve().parents[2] / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"
COLUMNS = {"/episode": loading.EPISODE_COLUMNS, "/query": loading.QUERY_COLUMNS}


def _rows_of_records(path: Path, columns: dict[str, tuple[str, ...]], missing: Any = np.nan) -> tuple[dict[str, int], dict[str, str]]:
    """``read_log``'s counts and records as rows of ``columns`` (by ``repr``: 1, 1.0 and True differ)."""
    data = read_log(path, list(columns))
    rows = {topic: repr([tuple(r.get(c, missing) for c in names) for r in data.topics[topic]]) for topic, names in columns.items()}
    return data.counts, rows


def _same(path: Path, columns: dict[str, tuple[str, ...]]) -> None:
    """``read_rows`` and ``read_log`` agree on ``path``: the same rows, or the same error."""
    try:
        expected: Any = _rows_of_records(path, columns)
    except LogError as exc:
        with pytest.raises(LogError) as info:
            read_rows(path, columns, missing=np.nan)
        assert str(info.value) == str(exc)
        return
    got = read_rows(path, columns, missing=np.nan)
    assert (got.counts, {t: repr(r) for t, r in got.rows.items()}) == expected


@pytest.fixture(scope="module")
def trial_logs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """A cube LaGR-SEQ trial in log formats 2 and 3 (format 1: the golden log)."""
    import functools

    root = tmp_path_factory.mktemp("rows")
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=12"])
    paths = [GOLDEN]
    for fmt in ("2", "3"):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(runner, "McapSink", functools.partial(McapSink, log_format=fmt))
            paths.append(runner.run_one(config, 0, 0, "mock", root / fmt / "trial-000.mcap").path)
    return paths


def test_rows_are_read_logs_records_in_every_format(trial_logs: list[Path]) -> None:
    for path in trial_logs:
        rows = read_rows(path, COLUMNS, missing=np.nan)
        assert rows.rows["/query"] and rows.rows["/episode"]
        _same(path, COLUMNS)
        _same(path, {"/query": ("global_step", "decision", "no such field"), "/transition": ("step", "reward", "placement")})


def test_a_trials_frames_are_those_of_its_records(trial_logs: list[Path]) -> None:
    """What replay's tables are made of: the frames, with every column's type and every value's."""
    for path in trial_logs:
        trial = loading._read_trial(path, path.parent, ReadStats())
        records = read_log(path, ["/episode", "/query"]).topics
        for frame, topic in ((trial.episodes, "/episode"), (trial.queries, "/query")):
            old = pd.DataFrame.from_records(records[topic], columns=list(COLUMNS[topic]))
            pd.testing.assert_frame_equal(frame, old, check_exact=True)
            for column in frame.columns:
                assert [type(v) for v in frame[column]] == [type(v) for v in old[column]]


def test_what_was_read_is_counted_alike(trial_logs: list[Path]) -> None:
    for path in trial_logs:
        a, b = ReadStats(), ReadStats()
        read_log(path, list(COLUMNS), a)
        read_rows(path, COLUMNS, b)
        assert a == b and a.messages > 0


_value = st.one_of(st.none(), st.booleans(), st.integers(-3, 3), st.floats(-2, 2, allow_nan=False), st.sampled_from(["gpt", "mock", ""]))
_optional = st.sampled_from([*QUERY_DEFAULTS, "prefix_length", "fraction", "unknown"])


@st.composite
def _query(draw: st.DrawFn, episode: int, step: int) -> Any:
    if draw(st.integers(0, 30)) == 0:
        return draw(st.sampled_from([[1, 2], 3, "text", None]))  # not a JSON object
    record: dict[str, Any] = {"trial": 0, "episode": episode, "step": step, "global_step": step, "state": [[0, 1]], "decision": draw(st.integers(0, 1))}
    for name in draw(st.lists(st.sampled_from(list(record)), max_size=2)) if draw(st.integers(0, 8)) == 0 else []:
        record.pop(name, None)  # a record without a field the readers need
    if draw(st.booleans()):
        record["global_step"] = draw(st.sampled_from([step, step + 1, "7", 2.0]))  # told twice, or not an integer
    for name in draw(st.lists(_optional, max_size=len(QUERY_DEFAULTS) + 3)):
        record[name] = draw(_value)
    return record


@st.composite
def _chunks(draw: st.DrawFn) -> list[list[tuple[str, Any]]]:
    chunks = []
    for episode in range(draw(st.integers(1, 4))):
        records: list[tuple[str, Any]] = []
        steps = draw(st.integers(0, 6))
        asked = draw(st.sets(st.integers(0, max(steps - 1, 0)), max_size=steps))
        for step in range(steps):
            if step in asked:
                records.append(("/query", draw(_query(episode, step))))
        others = [s for s in range(steps) if s not in asked]
        if others and draw(st.booleans()):
            no_query: dict[str, Any] = {"trial": 0, "episode": episode, "step": others, "global_step": list(others), "state": [[0]] * len(others)}
            if draw(st.integers(0, 8)) == 0:
                no_query[draw(st.sampled_from(["state", "trial"]))] = draw(st.sampled_from([[[0]], 5]))
            records.insert(draw(st.integers(0, len(records))), ("/no_query", no_query))
        summary: dict[str, Any] = {"trial": 0, "episode": episode, "return": draw(_value), "length": steps, "global_step": steps}
        if draw(st.booleans()):
            summary[draw(st.sampled_from(["solved", "placements", "epsilon"]))] = draw(_value)
        records.append(("/episode", summary))
        chunks.append(records)
    return chunks


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(chunks=_chunks(), fmt=st.sampled_from(["1", "2", "3"]))
def test_any_records_read_the_same(tmp_path: Path, chunks: list[list[tuple[str, Any]]], fmt: str) -> None:
    """Probe queries, unknown fields, missing fields, records that are not objects, a step told
    twice, damaged columns: whatever ``read_log`` makes of a chunk, ``read_rows`` makes too."""
    path = tmp_path / f"t-{fmt}.mcap"
    path.unlink(missing_ok=True)
    with McapSink(path, {"config": "{}"}, log_format="2" if fmt == "1" else fmt) as sink:
        for records in chunks:
            for topic, record in records:
                if fmt != "3" and topic == "/no_query":
                    continue
                sink.write_record(topic, record, 0)
            sink.flush()
    with pytest.MonkeyPatch.context() as patch:
        if fmt == "1":  # every field written, none put back
            patch.setattr(reader, "_fills_defaults", lambda metadata: False)
        _same(path, COLUMNS)


def test_missing_is_what_a_lacking_field_reads_as(trial_logs: list[Path]) -> None:
    rows = read_rows(trial_logs[2], {"/query": ("decision", "prefix_length")}).rows["/query"]
    assert rows and all(math.isnan(length) for _, length in rows)
    rows = read_rows(trial_logs[2], {"/query": ("decision", "prefix_length")}, missing=None).rows["/query"]
    assert all(length is None for _, length in rows)
