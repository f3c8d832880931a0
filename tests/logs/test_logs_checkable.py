"""A run's logs are checkable without lagrseq: a script that cannot import it recomputes every
query and episode of runs made by the command line from the MCAP files and docs/logs.md alone."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from lagrseq.analysis import costs, loading
from lagrseq.logs.reader import read_log

ROOT = Path(__file__).resolve().parents[2]
CHECKER = ROOT / "tests" / "support" / "third_party_check.py"
STORE = ROOT / "recorded_llm" / "qwen2.5-coder-1.5b-cube-t0.jsonl"
MODEL = "qwen2.5-coder-1.5b-instruct-q4_k_m"

RUNS = {
    # the mock, with a step budget that cuts the third 50-step episode
    "mock": ["--set", "run.episodes=0", "--set", "run.max_steps=130"],
    # a recorded store that holds every prefix: replayed answers
    "replayed": ["--provider", f"recorded:{STORE}", "--set", f"llm.model={MODEL}", "--set", "run.episodes=5", "--on-miss", "refuse"],
    # the same store at a temperature it never recorded: every query misses
    "refused": ["--provider", f"recorded:{STORE}", "--set", f"llm.model={MODEL}", "--set", "llm.temperature=0.7",
                "--set", "run.episodes=3", "--on-miss", "refuse"],
    "fallback": ["--provider", f"recorded:{STORE}", "--set", f"llm.model={MODEL}", "--set", "llm.temperature=0.7",
                 "--set", "run.episodes=3", "--on-miss", "mock"],
}


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("checkable")
    made = {}
    for name, options in RUNS.items():
        command = [sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--trials", "1", "--quiet",
                   "--out", str(out / name), *options]
        subprocess.run(command, check=True, cwd=ROOT, capture_output=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
        (made[name],) = (out / name).rglob("trial-*.mcap")
    return made


def _check(*paths: Path) -> subprocess.CompletedProcess[str]:
    """The checker in an isolated interpreter (``-I``: no PYTHONPATH, no user site), which also
    refuses any import of lagrseq."""
    return subprocess.run(
        [sys.executable, "-I", str(CHECKER), "--store", str(STORE), *map(str, paths)],
        capture_output=True, text=True, cwd="/", timeout=120,
    )


def test_every_query_and_episode_of_cli_runs_is_recomputed_without_lagrseq(logs: dict[str, Path]) -> None:
    done = _check(*logs.values())
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["lagrseq_imported"] is False
    found = {name: summary["logs"][str(path)] for name, path in logs.items()}
    assert set(found["mock"]["outcomes"]) == {"mock"} and found["mock"]["cut_by_step_budget"] == 1
    assert set(found["replayed"]["outcomes"]) == {"replayed"}
    assert set(found["refused"]["outcomes"]) == {"refused_miss"}
    assert set(found["fallback"]["outcomes"]) == {"mock_fallback"}
    for name, path in logs.items():  # what lagrseq's readers and cost table say, the same
        queries = [q for q in read_log(path, ["/query"]).topics["/query"] if q["queried"]]
        assert found[name]["outcomes"] == dict(Counter(q["outcome"] for q in queries))
        (run,) = loading.load([path.parent]).runs
        row = costs.run_costs([run]).iloc[0]
        assert sum(int(row[o]) for o in found[name]["outcomes"]) == row.queries == found[name]["queries"]


def _rewrite(source: Path, target: Path, change: dict[str, object], drop: str | None) -> None:
    """``source`` copied to ``target`` with the first query record changed (fields set, one dropped)."""
    with source.open("rb") as handle, target.open("wb") as out:
        reader = make_reader(handle)
        writer = Writer(out)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        changed = False
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0))
            data = message.data
            if channel.topic == "/query" and not changed:
                record = {**json.loads(data), **change}
                record.pop(drop or "", None)
                data, changed = json.dumps(record).encode(), True
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        for kept in reader.iter_metadata():
            writer.add_metadata(kept.name, dict(kept.metadata))
        writer.finish()


@pytest.mark.parametrize(
    ("change", "drop", "said"),
    [
        ({}, "prompt", "missing field(s) prompt"),
        ({}, "outcome", "missing field(s) outcome"),
        ({"prompt": "another prompt"}, None, "prompt_sha256"),
        ({"answer": "['a']"}, None, "the answer differs from the store's"),
        ({"accepted": None}, None, "accepted"),
    ],
)
def test_the_checker_fails_on_a_missing_or_altered_field(
    logs: dict[str, Path], tmp_path: Path, change: dict[str, object], drop: str | None, said: str
) -> None:
    altered = tmp_path / "altered.mcap"
    _rewrite(logs["replayed"], altered, change, drop)
    done = _check(altered)
    assert done.returncode == 1 and said in done.stderr
