"""Log format 2: a decision not to ask is written without its default fields, and readers give
the same records for old (format 1) and new logs; both replay."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from mcap.reader import make_reader

from lagrseq import config as cfg
from lagrseq.analysis import loading
from lagrseq.analysis.replay import replay
from lagrseq.logs.reader import QUERY_DEFAULTS, iter_messages, read_info, read_topics
from lagrseq.logs.schemas import QUERY
from lagrseq.logs.sink import LOG_FORMAT
from lagrseq.running.runner import run_one

GOLDEN = Path(__file__).resolve().parents[2] / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"


@pytest.fixture(scope="module")
def new_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=4"])
    directory = tmp_path_factory.mktemp("runs") / "new"
    return run_one(config, 0, 0, "mock", directory / "trial-000.mcap").path


def _raw_queries(path: Path) -> list[dict[str, object]]:
    """The /query messages as the plain mcap library and json.loads see them (no filling)."""
    with path.open("rb") as handle:
        return [json.loads(m.data) for _, c, m in make_reader(handle).iter_messages(topics=["/query"])]


def test_new_logs_leave_defaults_out_and_say_their_format(new_log: Path) -> None:
    assert read_info(new_log).run["log_format"] == LOG_FORMAT == "2"
    raw = _raw_queries(new_log)
    skipped = [r for r in raw if r["decision"] == 0]
    sent = [r for r in raw if r["decision"] == 1]
    assert skipped and sent, "the 4-episode trial both asks and does not"
    for record in skipped:
        assert list(record) == QUERY["required"], record  # six fields, no nulls
    for record in sent:
        assert record["queried"] is True and None not in record.values()
        assert set(QUERY["required"]) <= record.keys()


def test_readers_fill_the_defaults_back(new_log: Path) -> None:
    raw = _raw_queries(new_log)
    for reader_records in (
        [r for t, r in iter_messages(new_log, ["/query"]) if t == "/query"],
        read_topics(new_log, ["/query"])["/query"],
    ):
        assert len(reader_records) == len(raw)
        for record, plain in zip(reader_records, raw, strict=True):
            assert set(QUERY["properties"]) == record.keys()
            assert record == {**QUERY_DEFAULTS, **plain}
        skipped = next(r for r in reader_records if r["decision"] == 0)
        assert skipped["queried"] is False and skipped["query_reward"] == 0.0
        assert all(skipped[name] is None for name in ("answer", "provider", "cost_usd", "system_fingerprint"))


def test_an_old_format_log_reads_as_it_was_written() -> None:
    """The golden log is format 1 (every field written, before ``finish_reason`` and others
    existed): nothing is added to its records."""
    assert "log_format" not in read_info(GOLDEN).run
    records = [r for t, r in iter_messages(GOLDEN, ["/query"]) if t == "/query"]
    assert records == _raw_queries(GOLDEN)


def test_old_and_new_logs_replay_together(new_log: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    shutil.copytree(new_log.parent, runs / "new")
    (runs / "old").mkdir()
    shutil.copy(GOLDEN, runs / "old" / "trial-000.mcap")
    logs = loading.load([runs])
    assert logs.files == 2 and not logs.warnings
    for run in logs.runs:
        assert len(run.episodes) == 4
        assert list(run.queries.columns) == list(loading.QUERY_COLUMNS)
        assert set(run.queries["decision"]) == {0, 1}
        assert run.queries.loc[run.queries["decision"] == 0, "provider"].isna().all()
    report = replay([runs], tmp_path / "report")
    assert (tmp_path / "report" / "index.html").is_file() and report.logs.files == 2
