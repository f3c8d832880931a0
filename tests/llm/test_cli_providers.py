"""Providers end to end: `lagrseq run` with recorded, mock-profile and live providers, `lagrseq
record`, `lagrseq cache import|export|list`; the authors' cache reproduces the released code."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from lagrseq import cli
from lagrseq import config as cfg
from lagrseq.llm.store import RecordStore
from lagrseq.logs.reader import find_logs, iter_messages, read_info, read_topic
from lagrseq.running import recording, runner, wiring
from tests.llm.conftest import KEY_ENV, SECRET, FakeOpenAI, Reply, authors_cache

ROOT = Path(__file__).resolve().parents[2]

def DEFAULT_SIGINT() -> None:  # noqa: N802 (used like a constant)
    """In the child: Ctrl-C's default action, so Python raises KeyboardInterrupt there even when
    this test run itself was started as a background job (whose SIGINT is ignored and inherited)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)



def run_cli(*args: str | Path) -> int:
    return cli.main([str(a) for a in args])


def import_tau0(store: Path, model: str = "gpt-3.5-turbo") -> None:
    path = authors_cache("cube_stacking_cache0.0.pkl")
    code = run_cli("cache", "import", path, "--task", "cube-stacking", "--model", model, "--temperature", "0", "--store", store)
    assert code == 0


def queries_per_trial(directory: Path) -> list[int]:
    return [sum(r["queries"] for r in read_topic(path, "/episode")) for path in find_logs([directory])]


def run(method: str, provider: str, out: Path, trials: int, *extra: str, **options: object) -> list[int]:
    config = cfg.load("cube-stacking", method, "upstream", None, list(extra))
    directory = out / method / runner.provider_slug(provider)
    results = runner.run_trials(
        config, trials, 0, provider, directory, provider_options=wiring.provider_options(provider, options)
    )
    return [r.queries for r in results]


# ------------------------------------------------------------------------------ the done criterion
def test_the_tau0_cache_gives_the_released_codes_query_counts(tmp_path: Path) -> None:
    """SPEC 8: the released code on cache0.0 makes 132.9 +- 2.11 (LaGR-SEQ) and 289.4 +- 0.65 (LaGR)
    queries per run over 10 trials; the paper's Table 2 says 126 +- 2.94 and 284 +- 0.94."""
    import_tau0(tmp_path / "store")
    spec = f"recorded:{tmp_path / 'store'}"

    def queries(method: str) -> np.ndarray:  # 10 trials, seed 0, not logged (only the counts matter)
        config = cfg.load("cube-stacking", method, "upstream")
        return np.array([runner.run_one(config, t, 0, spec, tmp_path / "x.mcap", log=False).queries for t in range(10)])

    seq, lagr = queries("lagr-seq"), queries("lagr")
    assert 126 <= seq.mean() <= 140, seq
    assert 284 <= lagr.mean() <= 295, lagr
    assert seq.mean() < lagr.mean() / 2  # SEQ halves the queries, as in the paper


def test_the_calibrated_profile_runs_like_the_recorded_cache(tmp_path: Path) -> None:
    import_tau0(tmp_path / "store")
    for method in ("lagr-seq", "lagr"):
        recorded = run(method, f"recorded:{tmp_path / 'store'}", tmp_path, 3, "run.episodes=30")
        profile = run(method, "mock:authors-t0", tmp_path, 3, "run.episodes=30")
        assert recorded == profile  # right and wrong at the same prefixes, same random streams


# ------------------------------------------------------------------------------ recorded runs
def test_a_strict_miss_stops_the_run_with_one_line_naming_the_nearest_keys(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import_tau0(tmp_path / "store", model="gpt-4")  # the preset asks gpt-3.5-turbo
    code = run_cli("run", "cube-stacking", "--provider", f"recorded:{tmp_path / 'store'}", "--trials", "1", "--out", tmp_path / "runs", "--quiet")
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert "task cube-stacking, model gpt-3.5-turbo, temperature 0.0" in err
    assert "nearest recorded keys:" in err and "model 'gpt-4' instead of 'gpt-3.5-turbo'" in err


def test_on_miss_mock_answers_what_the_store_lacks(tmp_path: Path) -> None:
    import_tau0(tmp_path / "store")
    spec = f"recorded:{tmp_path / 'store'}"
    run("lagr", spec, tmp_path, 1, "run.episodes=5", "task.stack_size=5", on_miss="mock")
    sources = {r["source"] for p in find_logs([tmp_path]) for r in read_topic(p, "/query") if r["queried"]}
    assert sources == {"mock"}


def test_a_missing_store_and_bad_provider_specs_are_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for spec, message in [
        (f"recorded:{tmp_path / 'none'}", "no recorded store at"),
        ("recorded:", "needs a store"),
        ("mock:genius", "unknown mock profile 'genius'"),
        ("oracle", "unknown provider 'oracle'"),
    ]:
        assert run_cli("run", "cube-stacking", "--provider", spec, "--trials", "1", "--out", tmp_path, "--quiet") == 2
        assert message in capsys.readouterr().err
    assert run_cli("run", "cube-stacking", "--on-miss", "live", "--trials", "1", "--out", tmp_path, "--quiet") == 2
    assert "applies to --provider recorded:STORE only" in capsys.readouterr().err
    # every provider flag is read by the kinds whose options hold it, refused with any other
    prices = tmp_path / "prices.toml"
    prices.write_text('[models."m"]\ninput_usd_per_mtok = 1.0\noutput_usd_per_mtok = 2.0\nsource = "test"\ndate = 2026-01-01\n')
    for flags, message in [
        (["--n-ctx", "4096"], "--n-ctx applies to --provider local only, not mock"),
        (["--provider", "local", "--base-url", "http://127.0.0.1:9/v1"], "--base-url applies to --provider recorded:STORE or live only, not local"),
        (["--provider", "live", "--threads", "2"], "--threads applies to --provider local only, not live"),
        (["--price-table", str(prices)], "--price-table applies to --provider recorded:STORE or live only, not mock"),
    ]:
        assert run_cli("run", "cube-stacking", *flags, "--trials", "1", "--out", tmp_path, "--quiet") == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err


# ------------------------------------------------------------------------------ live runs
def live_args(server: FakeOpenAI) -> list[str]:
    return ["--base-url", server.url, "--api-key-env", KEY_ENV]


def test_a_live_run_logs_usage_and_cost_and_on_miss_live_records_once(tmp_path: Path, server: FakeOpenAI) -> None:
    out = tmp_path / "runs"
    code = run_cli("run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", *live_args(server), "--trials", "1", "--set", "run.episodes=4", "--out", out, "--quiet")
    assert code == 0
    (log,) = find_logs([out])
    queried = [r for r in read_topic(log, "/query") if r["queried"]]
    assert queried and len(server.requests) == len(queried)
    assert all(r["source"] == "live" and r["model"] == "gpt-4o-mini-2024-07-18" for r in queried)
    assert all(r["prompt_tokens"] > 0 and r["completion_tokens"] > 0 and r["cost_usd"] > 0 for r in queried)
    assert all(r["finish_reason"] == "stop" and r["system_fingerprint"] == "fp_test" and r["latency_s"] > 0 for r in queried)
    assert read_info(log).config["llm"]["model"] == "gpt-4o-mini"  # live:MODEL is what the log says
    options = json.loads(read_info(log).run["provider_options"])
    assert options["api_key_env"] == KEY_ENV and options["base_url"] == server.url

    store = tmp_path / "store"
    recorded = ["--provider", f"recorded:{store}", "--on-miss", "live", *live_args(server), "--set", "llm.model=gpt-4o-mini"]
    common = ["run", "cube-stacking", "--method", "lagr", "--trials", "2", "--set", "run.episodes=4", "--quiet"]
    assert run_cli(*common, *recorded, "--out", tmp_path / "first") == 0
    asked = len(server.requests)
    assert run_cli(*common, *recorded, "--out", tmp_path / "second") == 0
    assert len(server.requests) == asked  # everything the first run bought was recorded

    def answers(directory: Path) -> list[list[str | None]]:
        return [[r["answer"] for r in read_topic(p, "/query") if r["queried"]] for p in find_logs([directory])]

    assert answers(tmp_path / "first") == answers(tmp_path / "second")
    first_sources = {r["source"] for p in find_logs([tmp_path / "first"]) for r in read_topic(p, "/query") if r["queried"]}
    assert first_sources == {"live", "recorded"}


def test_a_live_run_over_budget_stops_before_the_request(tmp_path: Path, server: FakeOpenAI, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_cli("run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", *live_args(server), "--max-queries", "3", "--trials", "1", "--out", tmp_path, "--quiet")
    assert code == 2 and "--max-queries 3 reached" in capsys.readouterr().err
    assert len(server.requests) == 3


# ------------------------------------------------------------------------------ lagrseq record
def record_args(server: FakeOpenAI, store: Path, *extra: str) -> list[str]:
    return ["record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "1", "--store", str(store), *live_args(server), "--quiet", *extra]


def test_record_tops_up_every_prefix_and_a_rerun_asks_nothing(tmp_path: Path, server: FakeOpenAI, capsys: pytest.CaptureFixture[str]) -> None:
    assert run_cli(*record_args(server, tmp_path / "s", "--samples", "3")) == 0
    assert len(server.requests) == 8 and all(r["n"] == 3 for r in server.requests)  # one request per prefix
    assert "8/8 prompts hold at least 3 answers" in capsys.readouterr().out
    with RecordStore(tmp_path / "s", create=False) as store:
        entries = list(store.entries())
    assert len(entries) == 8 and all(len(e.samples) == 3 for e in entries)
    assert all(s.cost_usd and s.usage and s.usage.prompt_tokens for e in entries for s in e.samples)
    assert run_cli(*record_args(server, tmp_path / "s", "--samples", "3")) == 0
    assert len(server.requests) == 8
    assert run_cli(*record_args(server, tmp_path / "s", "--samples", "4", "--server", "ollama")) == 0
    assert len(server.requests) == 16  # one more answer for each prefix, one request each
    # the recorded answers are exactly what a run sends: a strict recorded run never misses
    spec = f"recorded:{tmp_path / 's'}"
    run("lagr", spec, tmp_path / "runs", 1, "run.episodes=10", "llm.model=gpt-4o-mini", "llm.temperature=1.0", base_url=server.url)


def test_record_stops_before_passing_max_queries_and_keeps_what_it_got(tmp_path: Path, server: FakeOpenAI, capsys: pytest.CaptureFixture[str]) -> None:
    code = run_cli(*record_args(server, tmp_path / "s", "--samples", "3", "--max-queries", "7"))
    captured = capsys.readouterr()
    assert code == 2 and "--max-queries 7 reached: 6 answers so far" in captured.err
    assert "2/8 prompts hold at least 3 answers" in captured.out and len(server.requests) == 2
    assert run_cli(*record_args(server, tmp_path / "s", "--samples", "3", "--mode", "none")) == 2
    assert "6 of 8 prompts have fewer than 3 answers" in capsys.readouterr().err


def test_record_stops_before_passing_max_cost(tmp_path: Path, server: FakeOpenAI, capsys: pytest.CaptureFixture[str]) -> None:
    from dataclasses import replace

    from lagrseq.llm.base import Usage
    from lagrseq.llm.pricing import PriceTable

    config = cfg.load("cube-stacking", "lagr", "upstream", None, [])
    config = replace(config, llm=replace(config.llm, model="gpt-4o-mini", temperature=1.0))
    queries = recording.queries_for(config, recording.record_patterns(config))
    prices = PriceTable()
    worst = [prices.worst_case(q, 1) or 0.0 for q in queries]
    actual = [  # what the test server bills: prompt chars / 4, answer chars / 4
        prices.cost(Usage(len(q.prompt) // 4, len(server.responder(q.prompt, 1.0)) // 4), "gpt-4o-mini") or 0.0
        for q in queries
    ]
    limit = max(worst) + min(actual) / 2  # room for the first request's worst case, not the second's
    code = run_cli(*record_args(server, tmp_path / "s", "--samples", "1", "--max-cost-usd", repr(limit)))
    captured = capsys.readouterr()
    assert code == 2 and "reached" in captured.err and "(not sent)" in captured.err
    assert len(server.requests) == 1
    spent = float(captured.out.split("spent $")[1].split()[0])
    assert spent == pytest.approx(actual[0], abs=1e-4) and spent <= limit


def test_record_from_the_states_of_logged_runs(tmp_path: Path, server: FakeOpenAI) -> None:
    run("lagr-seq", "mock", tmp_path / "runs", 1, "run.episodes=3")
    states = {json.dumps(r["state"]) for p in find_logs([tmp_path / "runs"]) for r in read_topic(p, "/query")}
    code = run_cli(*record_args(server, tmp_path / "s", "--samples", "1", "--from-runs", str(tmp_path / "runs")))
    assert code == 0 and len(server.requests) == len(states) > 0
    with pytest.raises(Exception, match="a run of task"):
        recording.record_patterns(cfg.load("cube-stacking", "lagr", "upstream", None, ["task.stack_size=5"]), [tmp_path / "runs"])


def test_an_interrupted_record_loses_nothing(tmp_path: Path, server: FakeOpenAI) -> None:
    server.script.extend(Reply(delay_s=0.15) for _ in range(100))
    store = tmp_path / "s"
    args = [sys.executable, "-m", "lagrseq", *record_args(server, store, "--samples", "3", "--server", "ollama")]
    env = {**os.environ, "PYTHONPATH": str(ROOT), KEY_ENV: SECRET}
    process = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=DEFAULT_SIGINT)

    def answers_stored() -> int:
        if not (store / "cache.db").exists():
            return 0
        with RecordStore(store, create=False) as s:
            return sum(len(e.samples) for e in s.entries())

    deadline = time.monotonic() + 20
    while answers_stored() < 4 and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=20)
    assert process.returncode == 130 and "answers recorded so far are kept" in err
    kept = answers_stored()
    assert kept >= 4 and kept >= len(server.requests) - 1  # at most the request in flight is lost
    asked = len(server.requests)
    server.script.clear()
    assert run_cli(*record_args(server, store, "--samples", "3", "--server", "ollama")) == 0
    assert len(server.requests) - asked == 24 - kept  # only what was missing is asked again
    assert answers_stored() == 24


# ------------------------------------------------------------------------------ the key never lands on disk
def test_the_api_key_is_in_no_file_written(tmp_path: Path, server: FakeOpenAI) -> None:
    server.script.append(Reply(401, {"error": {"message": f"Incorrect API key provided: {SECRET}", "type": "invalid_request_error", "code": "invalid_api_key"}}))
    assert run_cli(*record_args(server, tmp_path / "bad", "--samples", "1")) == 2  # the error names no key
    assert run_cli(*record_args(server, tmp_path / "store", "--samples", "2")) == 0
    assert run_cli("run", "cube-stacking", "--provider", "live:gpt-4o-mini", *live_args(server), "--trials", "1", "--set", "run.episodes=3", "--out", tmp_path / "runs", "--quiet") == 0
    assert run_cli("run", "cube-stacking", "--provider", f"recorded:{tmp_path / 'store'}", "--on-miss", "live", *live_args(server), "--set", "llm.model=gpt-4o-mini", "--trials", "1", "--set", "run.episodes=3", "--out", tmp_path / "runs2", "--quiet") == 0
    assert run_cli("cache", "export", "--store", tmp_path / "store", "--out", tmp_path / "export.jsonl") == 0
    needles = [SECRET.encode(), SECRET[-16:].encode()]
    files = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert any(p.suffix == ".mcap" for p in files) and any(p.name == "cache.db" for p in files)
    for path in files:
        data = path.read_bytes()
        assert not any(n in data for n in needles), path
        if path.suffix == ".mcap":  # compressed: check every decoded message and the metadata
            text = json.dumps([r for _, r in iter_messages(path)]) + json.dumps(read_info(path).run)
            assert SECRET not in text and SECRET[-16:] not in text, path
        if path.name == "cache.db":  # values are zlib-compressed JSON
            with sqlite3.connect(path) as db:
                for (value,) in db.execute("SELECT value FROM Cache WHERE value IS NOT NULL"):
                    assert SECRET.encode() not in zlib.decompress(value), path


# ------------------------------------------------------------------------------ lagrseq cache
def test_cache_import_export_list_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import_tau0(tmp_path / "a")
    assert "81 answers added under 8 keys" in capsys.readouterr().out
    import_tau0(tmp_path / "a")
    assert "0 answers added under 8 keys, 81 already in" in capsys.readouterr().out
    assert run_cli("cache", "export", "--store", tmp_path / "a", "--out", tmp_path / "a.jsonl") == 0
    assert run_cli("cache", "import", tmp_path / "a.jsonl", "--store", tmp_path / "b") == 0
    assert run_cli("cache", "export", "--store", tmp_path / "b", "--out", tmp_path / "b.jsonl") == 0
    assert (tmp_path / "a.jsonl").read_bytes() == (tmp_path / "b.jsonl").read_bytes()
    assert len((tmp_path / "a.jsonl").read_text().splitlines()) == 81
    capsys.readouterr()
    assert run_cli("cache", "list", "--store", tmp_path / "b") == 0
    listing = capsys.readouterr().out.splitlines()
    assert len(listing) == 8 and all("gpt-3.5-turbo  t=0.0  api.openai.com" in line for line in listing)


def test_cache_import_of_a_pickle_needs_model_and_temperature(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = authors_cache("cube_stacking_cache0.0.pkl")
    assert run_cli("cache", "import", path, "--task", "cube-stacking", "--store", tmp_path / "s") == 2
    assert "needs --model, --temperature" in capsys.readouterr().err
    assert run_cli("cache", "import", tmp_path / "nothing.pkl", "--store", tmp_path / "s") == 2


def test_the_11_cube_cache_imports_for_the_11_cube_task(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = authors_cache("cube_stacking_cache0.pkl")
    code = run_cli("cache", "import", path, "--task", "cube-stacking", "--set", "task.stack_size=11", "--model", "gpt-3.5-turbo", "--temperature", "0", "--store", tmp_path / "s")
    assert code == 0 and "111 answers added under 12 keys" in capsys.readouterr().out
    seq = run("lagr-seq", f"recorded:{tmp_path / 's'}", tmp_path, 2, "task.stack_size=11", "run.episodes=20")
    assert all(q > 0 for q in seq)
