"""The key never reaches the terminal, a log, a store or an error line, in any form
a server or a user can turn it into: a header value, a --base-url holding it (or 8 characters of
it), an echo with a zero-width space every 4 characters. Real HTTP on 127.0.0.1, real MCAP files,
real stores, the real command line."""

from __future__ import annotations

import json
import string
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lagrseq import cli, keys
from lagrseq.errors import LagrseqError
from lagrseq.keys import MARK, MIN_FRAGMENT, Redactor
from lagrseq.llm.base import user_query
from lagrseq.llm.live import LiveProvider
from lagrseq.logs.sink import McapSink
from lagrseq.tasks import cube
from tests.llm.conftest import KEY_ENV, FakeOpenAI, Reply, fast_settings
from tests.support.redaction import visible, windows, written

ROOT = Path(__file__).resolve().parents[2]
KEY = "sk-proj-" + "".join(np.random.default_rng(37).choice(list(string.ascii_letters + string.digits), 48))
BARE_KEY = "".join(np.random.default_rng(38).choice(list(string.ascii_lowercase + string.digits), 36))
"""A key that does not start with sk- (a gateway's: 36 lower-case characters), so no key-like
pattern catches it."""
ZWSP = "\u200b"


def leaks(text: str, key: str = KEY) -> list[str]:
    """Fragments of ``key`` (8 characters or more, any case, invisible characters skipped) in ``text``."""
    low = visible(text).lower()
    return sorted(w for w in windows(key) if w in low)


def spaced(key: str, every: int = 4, mark: str = ZWSP) -> str:
    """``key`` with ``mark`` after every ``every`` characters."""
    return mark.join(key[i : i + every] for i in range(0, len(key), every))


# ------------------------------------------------------------------------------ the redactor
@pytest.mark.parametrize("mark", [ZWSP, "\u200c", "\u2060", "\ufeff", "\u00ad", "\u202e", " ", "\n", "\t", "\u00a0", "\ufe0f", "\U000e0041"])
def test_invisible_characters_inside_the_key_do_not_hide_it(mark: str) -> None:
    redactor = Redactor(KEY)
    for echo in (spaced(KEY, 4, mark), spaced(KEY[3:], 1, mark), spaced(KEY[-20:].upper(), 3, mark)):
        out = redactor.text(f"answer: [{echo}] kept")
        assert out == f"answer: [{MARK}] kept", (mark, out)


def test_pieces_shorter_than_eight_characters_and_transformed_keys_are_not_matched() -> None:
    """What docs/security.md says is not matched, checked so the page stays true."""
    import base64

    redactor = Redactor(KEY)
    pieces = [KEY[i : i + MIN_FRAGMENT - 1] for i in range(0, len(KEY), MIN_FRAGMENT - 1)]
    split = " | ".join(pieces)  # visible separators: no window of 8 of the key
    assert redactor.text(split) == split
    encoded = base64.b64encode(KEY.encode()).decode()
    assert redactor.text(encoded) == encoded


def test_the_invisible_scan_stays_linear_on_long_text_and_a_long_key() -> None:
    key = "sk-proj-" + "".join(np.random.default_rng(2).choice(list(string.ascii_letters + string.digits), 400))
    redactor = Redactor(key)
    every_char_distinct = "".join(chr(c) for c in range(0x4E00, 0x4E00 + 20_000)) * 10  # 200,000 CJK characters
    cases = {
        "the key with a zero-width space every 4": spaced(key, 4) * (200_000 // len(key)),
        "zero-width spaces alone": ZWSP * 400_000,
        "distinct non-ASCII characters": every_char_distinct,
        "fragments between spaces": (" ".join(key[:MIN_FRAGMENT]) + " x ") * 20_000,
    }
    for name, text in cases.items():
        started = time.perf_counter()
        redactor.text(text)
        assert time.perf_counter() - started < 2.0, name  # generous: a quadratic scan takes minutes


def test_the_process_guard_reads_the_default_and_the_watched_variables(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", BARE_KEY)
    monkeypatch.setenv("LAGRSEQ_TEST_OTHER_KEY", KEY)
    assert keys.scrub(f"x {BARE_KEY[5:20]} y") == f"x {MARK} y"
    assert keys.scrub(KEY) == KEY  # not watched yet
    keys.watch("LAGRSEQ_TEST_OTHER_KEY")
    assert keys.scrub(f"<{spaced(KEY[8:])}>") == f"<{MARK}>"
    assert keys.scrub_value({"a": [KEY, 1, None], KEY[:12]: (KEY[-9:],)}) == {"a": [MARK, 1, None], MARK: (MARK,)}
    monkeypatch.setenv("OPENAI_API_KEY", "ollama")  # a short key is no secret: ordinary words are kept
    assert keys.scrub("http://ollama:11434/v1") == "http://ollama:11434/v1"


# ------------------------------------------------------------------------------ (a) a header that echoes the key
def test_a_content_encoding_header_holding_the_key_is_not_printed(server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(KEY_ENV, KEY)
    for value in (lambda k: k, lambda k: spaced(k.upper(), 4, " "), lambda k: f"br, {k[3:]}"):  # a header is latin-1: spaces inside
        server.script.clear()
        server.script.append(Reply(200, b"{}", lambda k, value=value: {"Content-Encoding": value(k)}))
        with LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0)) as live, pytest.raises(LagrseqError) as caught:
            live.complete(user_query("cube-stacking", cube.CubeStacking(8).prompt((4, 5, 6)), "gpt-4o-mini", 0.0, 64))
        message = str(caught.value)
        assert "the response is encoded as" in message and "\n" not in message
        assert leaks(message) == [], message


def test_a_content_encoding_header_holding_the_key_is_not_printed_by_the_command_line(
    server: FakeOpenAI, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv(KEY_ENV, KEY)
    server.script.extend(Reply(200, b"{}", lambda k: {"Content-Encoding": k}) for _ in range(4))
    status = cli.main(["record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "0", "--samples", "1",
                       "--store", str(tmp_path / "store"), "--base-url", server.url, "--api-key-env", KEY_ENV, "--quiet"])
    captured = capfd.readouterr()
    assert status == 2 and "encoded as" in captured.err
    assert leaks(captured.out + captured.err) == [], captured.err
    assert {p: leaks(t) for p, t in written(tmp_path) if leaks(t)} == {}


# ------------------------------------------------------------------------------ (b) --base-url holding the key
def _command(key: str, *argv: str, env_name: str = "OPENAI_API_KEY") -> subprocess.CompletedProcess[str]:
    """The real program, in a fresh process, with ``key`` in ``env_name``."""
    import os

    env = {k: v for k, v in os.environ.items() if not k.endswith("_PROXY") and not k.endswith("_proxy") and k != "OPENAI_API_KEY"}
    env[env_name] = key
    return subprocess.run([sys.executable, "-m", "lagrseq", *argv], capture_output=True, text=True, env=env, cwd=ROOT, timeout=120, check=False)


@pytest.mark.parametrize(
    ("url", "why"),
    [
        (BARE_KEY, "the key itself, arguments swapped"),
        (f"http://127.0.0.1:99999/{BARE_KEY}", "the key behind a bad port"),
        (f"ftp://gateway.example/{BARE_KEY[-20:]}", "the last 20 characters behind a bad scheme"),
        (f"https://gateway.example/v1/{BARE_KEY[4:16].upper()}", "12 characters of it, upper-cased"),
        (f"https://{BARE_KEY[:10]}.gateway.example/v1", "10 characters of it as a host label"),
    ],
)
def test_a_base_url_holding_the_key_is_refused_without_repeating_it(tmp_path: Path, url: str, why: str) -> None:
    done = _command(BARE_KEY, "record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "0", "--samples", "1",
                    "--store", str(tmp_path / "store"), "--base-url", url)
    assert done.returncode == 2, (why, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "--base-url" in lines[0], (why, done.stderr)
    assert leaks(done.stdout + done.stderr, BARE_KEY) == [], (why, done.stderr)
    assert not (tmp_path / "store").exists()


def test_a_base_url_holding_the_key_of_another_variable_is_refused_in_run(tmp_path: Path) -> None:
    done = _command(KEY, "run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--api-key-env", "MY_GATEWAY_KEY",
                    "--base-url", f"http://127.0.0.1:9/{KEY[3:]}", "--trials", "1", "--out", str(tmp_path / "runs"), env_name="MY_GATEWAY_KEY")
    assert done.returncode == 2 and "holds the API key" in done.stderr, done.stderr
    assert leaks(done.stdout + done.stderr) == []
    assert not list(tmp_path.rglob("*.mcap*"))


def test_url_errors_never_repeat_the_url(tmp_path: Path) -> None:
    """A bad port or scheme in a URL that holds no key: the line still does not repeat it."""
    for url in ("http://127.0.0.1:99999/v1/secretive-path", "gopher://127.0.0.1/v1/secretive-path", "http://[::1/v1/secretive-path"):
        done = _command(BARE_KEY, "record", "cube-stacking", "--model", "m", "--temperature", "0", "--samples", "1",
                        "--store", str(tmp_path / "store"), "--base-url", url)
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert "secretive-path" not in done.stderr, done.stderr


def test_an_error_line_naming_a_path_with_the_key_blanks_it(tmp_path: Path) -> None:
    """The command line's last line of defence: any error text is scrubbed before it is printed."""
    done = _command(KEY, "run", "cube-stacking", "--config", str(tmp_path / f"{KEY[3:]}.toml"), "--trials", "1", "--out", str(tmp_path / "runs"))
    assert done.returncode == 2 and MARK in done.stderr, done.stderr
    assert leaks(done.stdout + done.stderr) == []


# ------------------------------------------------------------------------------ (c) an echo with zero-width spaces
def zero_width_echo(key: str) -> dict[str, Any]:
    hidden = spaced(key)
    return {
        "id": "chatcmpl-1",
        "object": "chat.completion",
        "created": 1700000000,
        "model": "gpt-4o-mini-" + spaced(key[3:].upper(), 3, "\u2060"),
        "choices": [{"index": 0, "message": {"role": "assistant", "content": f"KEPT [4, 5, 6, 7] {hidden} and {spaced(key[-20:], 2, chr(0xFEFF))}"}, "finish_reason": "stop"}],
        "usage": {"prompt_tokens": 10, "completion_tokens": 5, "total_tokens": 15},
    }


def test_a_server_echoing_the_key_with_zero_width_spaces_gets_it_into_no_store_log_or_line(
    server: FakeOpenAI, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    from mcap.reader import make_reader

    monkeypatch.setenv(KEY_ENV, KEY)
    server.script.extend(Reply(200, zero_width_echo) for _ in range(200))
    common = ["--base-url", server.url, "--api-key-env", KEY_ENV, "--quiet"]
    store = tmp_path / "store"
    assert cli.main(["record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "0", "--samples", "1", "--store", str(store), *common]) == 0
    assert cli.main(["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--trials", "1",
                     "--set", "run.episodes=3", "--out", str(tmp_path / "runs"), *common]) == 0
    assert cli.main(["cache", "export", "--store", str(store), "--out", str(tmp_path / "export.jsonl")]) == 0
    assert server.requests
    texts = []
    for path in sorted(tmp_path.rglob("*.mcap")):
        with path.open("rb") as handle:
            reader = make_reader(handle)
            for _, channel, message in reader.iter_messages():
                record = json.loads(message.data)
                text = json.dumps(record, ensure_ascii=False)
                assert leaks(text) == [], channel.topic
                texts.append(text)
            for metadata in reader.iter_metadata():
                assert leaks(json.dumps(metadata.metadata, ensure_ascii=False)) == []
    assert any("KEPT" in t and MARK in t for t in texts)
    exported = (tmp_path / "export.jsonl").read_text(encoding="utf-8")
    assert "KEPT" in exported and MARK in exported and leaks(exported) == []
    found = {str(p): leaks(t) for p, t in written(tmp_path) if leaks(t)}
    assert found == {}, found
    captured = capfd.readouterr()
    assert leaks(captured.out + captured.err) == []


def test_the_log_blanks_a_guarded_key_in_its_metadata_and_records(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Whatever reaches the sink (a config value, a record of a tool's own topic) is scrubbed."""
    from mcap.reader import make_reader

    from lagrseq.logs.events import QUERY_TOPIC, QueryEvent

    monkeypatch.setenv("OPENAI_API_KEY", BARE_KEY)
    path = tmp_path / "trial-001.mcap"
    with McapSink(path, {"config": json.dumps({"llm": {"model": BARE_KEY[2:30]}})}) as sink:
        sink.write(QueryEvent(0, 0, 0, 0, [1], 1, True, answer=spaced(BARE_KEY), model="m"))
        sink.write_record(QUERY_TOPIC, {"trial": 0, "note": BARE_KEY.lower()}, 1)
        sink.finish("failed", error=f"server said {BARE_KEY[-12:]}")
    data = path.read_bytes()
    assert path.is_file() and not path.is_symlink()
    with path.open("rb") as handle:
        reader = make_reader(handle)
        seen = [json.dumps(json.loads(m.data), ensure_ascii=False) for _, _, m in reader.iter_messages()]
        seen += [json.dumps(m.metadata, ensure_ascii=False) for m in reader.iter_metadata()]
    assert len(seen) >= 4 and all(leaks(t, BARE_KEY) == [] for t in seen), seen
    assert sum(MARK in t for t in seen) >= 4
    assert leaks(data.decode("latin-1"), BARE_KEY) == []


def test_a_key_set_while_a_log_is_open_is_blanked_from_the_next_episodes_queries(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The sink reads the guarded keys as it encodes queries (once for each chunk it writes):
    a key that turns up between episodes is blanked from every later query record."""
    from mcap.reader import make_reader

    from lagrseq.logs.events import EpisodeEvent, QueryEvent

    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    path = tmp_path / "trial-000.mcap"
    with McapSink(path, {"config": "{}"}) as sink:
        sink.write(QueryEvent(0, 0, 0, 0, [1], 1, True, answer="no key yet", model="m"))
        sink.write(EpisodeEvent(0, 0, 0.0, 1, global_step=1))
        monkeypatch.setenv("OPENAI_API_KEY", BARE_KEY)
        for episode in (1, 2):
            sink.write(QueryEvent(0, episode, 0, episode, [1], 1, True, answer=f"echo {spaced(BARE_KEY)}", model=BARE_KEY[:20]))
            sink.write(QueryEvent(0, episode, 1, episode, [1], 1, True, answer=f"again {BARE_KEY.upper()}", model="m"))
            sink.write(EpisodeEvent(0, episode, 0.0, 2, global_step=episode + 1))
    with path.open("rb") as handle:
        records = [json.loads(m.data) for _, channel, m in make_reader(handle).iter_messages() if channel.topic == "/query"]
    assert [r["answer"] for r in records] == ["no key yet"] + [f"echo {MARK}", f"again {MARK}"] * 2
    assert all(leaks(json.dumps(r, ensure_ascii=False), BARE_KEY) == [] for r in records)


def test_a_usage_error_repeating_a_value_that_is_the_key_blanks_it(tmp_path: Path) -> None:
    """Swapped arguments caught by argparse itself (an invalid choice, a number expected)."""
    for argv in (["record", "cube-stacking", "--model", "m", "--store", str(tmp_path / "s"), "--server", BARE_KEY],
                 ["run", "cube-stacking", "--trials", BARE_KEY, "--out", str(tmp_path / "runs")]):
        done = _command(BARE_KEY, *argv)
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert MARK in done.stderr and leaks(done.stdout + done.stderr, BARE_KEY) == [], done.stderr


def test_a_model_name_holding_the_key_is_refused_before_it_is_sent_or_stored(server: FakeOpenAI, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from lagrseq.llm.store import RecordStore, key_of_request
    from tests.support.redaction import query

    monkeypatch.setenv(KEY_ENV, KEY)
    with LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0)) as live, pytest.raises(LagrseqError, match="model name") as caught:
        live.complete(query(model=KEY[3:]))
    assert leaks(str(caught.value)) == [] and server.requests == []
    status = cli.main(["record", "cube-stacking", "--model", KEY.upper(), "--temperature", "0", "--samples", "1",
                       "--store", str(tmp_path / "store"), "--base-url", server.url, "--api-key-env", KEY_ENV, "--quiet"])
    assert status == 2 and server.requests == []
    # a store refuses a request holding a guarded key, whoever writes it (an import of a hostile JSONL)
    keys.watch(KEY_ENV)
    with RecordStore(tmp_path / "store2") as store, pytest.raises(LagrseqError, match="holds the API key"):
        request = {"key_version": 1, "endpoint": "127.0.0.1", "model": f"m-{KEY[-12:]}", "messages": [], "temperature": 0.0}
        store.add_many({key_of_request(request): (request, None, [])}, checked=True)
    assert {p: leaks(t) for p, t in written(tmp_path) if leaks(t)} == {}
