"""The API key stays out of every file and stream of every command that talks to a server, with the
key in ``OPENAI_API_KEY`` (no ``--api-key-env``), against a server that echoes it in every field
and header: ``record`` (also ``--concurrency``), ``run --provider live --jobs 2`` with a budget
(its ledger file), ``run --provider recorded:S --on-miss live``, ``cache export``, ``cache list``
and ``cache parse``. A key that cannot go in a header is one line, exit status 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lagrseq import cli
from tests.llm.conftest import FakeOpenAI
from tests.support.redaction import ECHO_KEY, HARMLESS, echo_completion, echoing, leaks, written


@pytest.mark.slow
def test_no_command_writes_or_prints_a_fragment_of_the_key(
    tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    from mcap.reader import make_reader

    monkeypatch.setenv("OPENAI_API_KEY", ECHO_KEY)
    server.script.extend(echoing(echo_completion) for _ in range(2000))
    live = ["--base-url", server.url, "--max-cost-usd", "50", "--quiet"]
    store = tmp_path / "store"
    runs = ["--trials", "2", "--set", "run.episodes=2", "--set", "run.max_steps=30"]
    commands = [
        ["record", "cube-stacking", "--store", str(store), "--samples", "2", "--concurrency", "3", *live],
        ["record", "cube-stacking", "--store", str(store), "--samples", "3", *live],
        ["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--jobs", "2",
         "--out", str(tmp_path / "live-runs"), *runs, *live],
        ["run", "cube-stacking", "--method", "lagr", "--provider", f"recorded:{tmp_path / 'empty-store'}", "--on-miss", "live",
         "--out", str(tmp_path / "miss-runs"), *runs, *live],
        ["cache", "export", "--store", str(store), "--out", str(tmp_path / "export.jsonl")],
        ["cache", "list", "--store", str(store)],
        ["cache", "parse", "--task", "cube-stacking", str(store)],
    ]
    for command in commands:
        assert cli.main(command) == 0, command
    assert server.requests and all(h.get("authorization") == f"Bearer {ECHO_KEY}" for h in server.headers)

    # the answers came through (blanked), so the scan below reads what was really written
    exported = [json.loads(line) for line in (tmp_path / "export.jsonl").read_text(encoding="utf-8").splitlines()]
    assert exported and all(HARMLESS in line["sample"]["text"] for line in exported)
    assert any(path.name == "budget-ledger.sqlite" for path in tmp_path.rglob("*")), "the budget ledger was not written"
    logs = sorted(tmp_path.rglob("*.mcap"))
    assert len(logs) == 4
    for path in logs:
        with path.open("rb") as handle:
            reader = make_reader(handle)
            for _, channel, message in reader.iter_messages():
                assert leaks(message.data.decode()) == [], (path, channel.topic)
            for metadata in reader.iter_metadata():
                assert leaks(json.dumps(metadata.metadata)) == [], path
    found = {str(path): leaks(text) for path, text in written(tmp_path) if leaks(text)}
    assert found == {}, found
    captured = capfd.readouterr()
    assert leaks(captured.out + captured.err) == []


@pytest.mark.parametrize("key", ["sk-tëst-0123456789abcdef", "sk-\u202eevil-0123456789", "sk-a\tb-0123456789abcdef"])
@pytest.mark.parametrize("command", ["run", "record"])
def test_a_key_that_cannot_go_in_a_header_is_one_line_exit_2(
    tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str], key: str, command: str
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", key)
    argv = {
        "run": ["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--out", str(tmp_path / "runs"),
                "--trials", "1", "--set", "run.episodes=1"],
        "record": ["record", "cube-stacking", "--store", str(tmp_path / "store"), "--samples", "1"],
    }[command]
    assert cli.main([*argv, "--base-url", server.url, "--quiet"]) == 2
    err = capfd.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "OPENAI_API_KEY" in err, err
    assert key not in err and leaks(err, key) == []
    assert server.requests == []


@pytest.mark.parametrize(
    "failure",
    [
        "HTTP 401", "HTTP 429 quota", "HTTP 400", "a choice without a message", "a body that is not JSON",
        pytest.param("HTTP 429 then 500 then 503", marks=pytest.mark.slow),  # the default backoff: some 15 s
    ],
)
@pytest.mark.parametrize("command", ["run", "record"])
def test_a_failing_server_that_echoes_the_key_leaves_no_fragment_in_stderr_or_files(
    tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str], failure: str, command: str
) -> None:
    from tests.support.redaction import FAILURES

    monkeypatch.setenv("OPENAI_API_KEY", ECHO_KEY)
    replies = FAILURES[failure]
    server.script.extend([*replies, *(replies[-1:] * 20)])
    argv = {
        "run": ["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--out", str(tmp_path / "runs"),
                "--trials", "1", "--set", "run.episodes=1"],
        "record": ["record", "cube-stacking", "--store", str(tmp_path / "store"), "--samples", "1", "--concurrency", "2"],
    }[command]
    status = cli.main([*argv, "--base-url", server.url, "--quiet"])
    captured = capfd.readouterr()
    assert status != 0 and server.requests
    assert "Traceback" not in captured.err and leaks(captured.out + captured.err) == [], captured.err
    assert captured.err.strip().splitlines()[-1].startswith(f"lagrseq {command}: ")
    found = {str(path): leaks(text) for path, text in written(tmp_path) if leaks(text)}
    assert found == {}, found


@pytest.mark.parametrize("value", [ECHO_KEY, ECHO_KEY[8:], "", "1BAD", "MY KEY", "x" * 200])
@pytest.mark.parametrize("command", ["run", "record"])
def test_the_key_given_to_api_key_env_is_refused_without_showing_it(
    tmp_path: Path, server: FakeOpenAI, capfd: pytest.CaptureFixture[str], value: str, command: str
) -> None:
    """A careless user passes the key itself (or something that is no variable name) where the
    NAME of its variable goes: one line, exit 2, the value not repeated, nothing sent or written
    (old: "environment variable sk-proj-... is not set" printed the key)."""
    argv = {
        "run": ["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--out", str(tmp_path / "runs"),
                "--trials", "1", "--set", "run.episodes=1"],
        "record": ["record", "cube-stacking", "--store", str(tmp_path / "store"), "--samples", "1"],
    }[command]
    assert cli.main([*argv, "--base-url", server.url, "--api-key-env", value, "--quiet"]) == 2
    err = capfd.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--api-key-env" in err and "not shown" in err, err
    assert leaks(err) == [] and (len(value) < 4 or value not in err)
    assert server.requests == [] and not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    "url",
    [f"http://user:{ECHO_KEY}@127.0.0.1:9/v1", f"http://127.0.0.1:9/v1?api-key={ECHO_KEY}", f"http://127.0.0.1:9/v1#{ECHO_KEY}",
     f"http://{ECHO_KEY}@127.0.0.1:9/v1"],
    ids=["user:password@", "query", "fragment", "user@"],
)
@pytest.mark.parametrize("provider", ["live:gpt-4o-mini", "recorded:STORE"])
def test_a_base_url_carrying_a_key_is_refused_without_showing_it(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, url: str, provider: str
) -> None:
    """Credentials in --base-url would be printed in messages and written into every trial's
    metadata (old: both): one line, exit 2, the URL not repeated, no log written."""
    monkeypatch.setenv("OPENAI_API_KEY", "sk-other-0123456789abcdef")
    provider = provider.replace("STORE", str(tmp_path / "store"))
    argv = ["run", "cube-stacking", "--method", "lagr", "--provider", provider, "--on-miss", "mock", "--out", str(tmp_path / "runs"),
            "--trials", "1", "--set", "run.episodes=1", "--base-url", url, "--quiet"]
    if provider.startswith("live"):
        argv.remove("--on-miss")
        argv.remove("mock")
    assert cli.main(argv) == 2
    err = capfd.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--base-url carries credentials" in err and leaks(err) == [], err
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").rglob("*.mcap"))
