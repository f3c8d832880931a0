"""Logs of live and recorded runs are checkable without lagrseq: the checker that cannot import
it (tests/support/third_party_check.py) re-costs every query sent to a live server from its
logged usage and the run's price table, and checks every answer replayed from the authors'
recorded GPT answers, whose usage is unknown (null, priced n/a)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from lagrseq.analysis import costs, loading
from lagrseq.logs.reader import read_log
from tests.llm.conftest import KEY_ENV, FakeOpenAI, authors_cache

ROOT = Path(__file__).resolve().parents[2]
CHECKER = ROOT / "tests" / "support" / "third_party_check.py"


def _lagrseq(*args: str | Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "lagrseq", *map(str, args)], check=True, cwd=ROOT, env=env, capture_output=True)


def _check(*args: str | Path) -> dict:
    done = subprocess.run([sys.executable, "-I", str(CHECKER), *map(str, args)], capture_output=True, text=True, cwd="/", timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["lagrseq_imported"] is False
    return summary["logs"]


def test_queries_sent_to_a_live_server_are_re_costed_without_lagrseq(tmp_path: Path, server: FakeOpenAI) -> None:
    prices = tmp_path / "prices.toml"  # prices of its own, so the checker cannot agree by chance
    prices.write_text('[models."gpt-4o-mini"]\ninput_usd_per_mtok = 3.0\noutput_usd_per_mtok = 7.0\n'
                      'source = "test"\ndate = 2026-01-01\n')
    _lagrseq("run", "cube-stacking", "--provider", "live", "--base-url", server.url, "--api-key-env", KEY_ENV,
             "--price-table", prices, "--set", "llm.model=gpt-4o-mini", "--set", "run.episodes=3", "--trials", "1",
             "--quiet", "--out", tmp_path / "runs")
    (log,) = (tmp_path / "runs").rglob("trial-*.mcap")
    found = _check(log)[str(log)]
    sent = [q for q in read_log(log, ["/query"]).topics["/query"] if q["queried"]]
    assert found["outcomes"] == {"sent": len(sent)} and len(sent) > 0
    assert found["cost_usd"] > 0 and all(q["prompt_tokens"] and q["cost_usd"] > 0 for q in sent)


def test_the_authors_answers_are_checked_and_their_unknown_usage_priced_na(tmp_path: Path) -> None:
    store, export = tmp_path / "store", tmp_path / "authors.jsonl"
    _lagrseq("cache", "import", authors_cache("cube_stacking_cache0.0.pkl"), "--task", "cube-stacking", "--model", "gpt-3.5-turbo",
             "--temperature", "0", "--store", store)
    _lagrseq("cache", "export", "--store", store, "--out", export)
    _lagrseq("run", "cube-stacking", "--provider", f"recorded:{store}", "--set", "run.episodes=5", "--trials", "1",
             "--quiet", "--out", tmp_path / "runs", "--on-miss", "refuse")
    (log,) = (tmp_path / "runs").rglob("trial-*.mcap")
    found = _check("--store", export, log)[str(log)]
    assert set(found["outcomes"]) <= {"replayed", "refused_miss"} and found["outcomes"].get("replayed", 0) > 0
    queries = [q for q in read_log(log, ["/query"]).topics["/query"] if q["outcome"] == "replayed"]
    assert all(q["prompt_tokens"] is None and q["completion_tokens"] is None for q in queries)  # unknown, never 0
    (run,) = loading.load([log.parent]).runs
    table = costs.by_run([run], lambda model, prompt, completion: 1e-6 * (prompt + completion))
    cells = dict(zip(table.columns, table.rows[0], strict=True))
    assert (cells["tokens"], cells["USD at current prices"]) == ("n/a", "n/a")
