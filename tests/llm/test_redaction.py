"""The API key never reaches a file, an exception or a callback, even from a server that echoes it
whole, in part, upper-cased or split over two fields, in every field a response has."""

from __future__ import annotations

import gzip
import json
import string
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.errors import ConfigError, LagrseqError
from lagrseq.keys import MARK, MIN_FRAGMENT, Redactor
from lagrseq.llm.base import Answer
from lagrseq.llm.budget import Budget, BudgetedProvider
from lagrseq.llm.live import LiveProvider
from lagrseq.llm.pricing import PriceTable
from lagrseq.llm.recorded import RecordingProvider
from lagrseq.llm.store import RecordStore, export_jsonl
from tests.llm.conftest import KEY_ENV, SECRET, FakeOpenAI, Reply, error_body, fast_settings
from tests.support.redaction import (
    ECHO_KEY,
    FAILURES,
    HARMLESS,
    echo_completion,
    echoing,
    leaks,
    query,
    visible,
    windows,
    written,
)


# ------------------------------------------------------------------------------ the redactor
def test_the_redactor_blanks_the_key_its_fragments_and_any_case() -> None:
    redactor = Redactor(SECRET)
    for echo in (SECRET, SECRET[3:], SECRET[-20:], SECRET[:MIN_FRAGMENT], SECRET.upper(), SECRET[5:30].lower()):
        # brackets around the echo: whitespace is skipped in matching, so a word beside it that
        # continues the key (the "e" of "before " and "st-..." make "est-", in "test-") joins the mark
        out = redactor.text(f"before [{echo}] after")
        assert out == f"before [{MARK}] after", (echo, out)
    assert redactor.text(f"before {SECRET[5:30]} after") == f"befor{MARK} after"
    # a fragment shorter than MIN_FRAGMENT is not recognisable and is left alone
    assert redactor.text(f"x{SECRET[:MIN_FRAGMENT - 1]}y") == f"x{SECRET[:MIN_FRAGMENT - 1]}y"
    # overlapping and adjacent fragments become one mark; text around them is kept exactly
    assert redactor.text(f"é{SECRET[:20]}{SECRET[10:30]}ü") == f"é{MARK}ü"
    ordinary = "['e', 'f', 'g'] and 1 0 0 1\n0 1 1 0, naïve ☃ \ud800"
    assert redactor.text(ordinary) == ordinary


def test_a_short_key_is_redacted_only_whole_and_in_its_own_case() -> None:
    redactor = Redactor("EMPTY")
    assert redactor.text("xEMPTYy empty EMPT") == f"x{MARK}y empty EMPT"
    assert Redactor("").text("anything") == "anything"


def test_the_redactor_never_shows_or_pickles_itself() -> None:
    import pickle

    redactor = Redactor(SECRET)
    assert SECRET not in repr(redactor) and not leaks(repr(redactor), SECRET)
    with pytest.raises(TypeError, match="refusing to pickle"):
        pickle.dumps(redactor)


KEY_ALPHABET = string.ascii_letters + string.digits + "-_"
TEXT_ALPHABET = string.ascii_letters + string.digits + "-_ ,.[]{}\"'\n\té☃"


@st.composite
def key_and_text(draw: st.DrawFn) -> tuple[str, str]:
    key = draw(st.text(KEY_ALPHABET, min_size=1, max_size=80))
    parts = []
    for _ in range(draw(st.integers(0, 6))):
        if draw(st.booleans()):
            start = draw(st.integers(0, len(key)))
            stop = draw(st.integers(start, len(key)))
            piece = key[start:stop]
            parts.append(piece.upper() if draw(st.booleans()) else piece)
        else:
            parts.append(draw(st.text(TEXT_ALPHABET, max_size=30)))
    return key, "".join(parts)


@settings(max_examples=150, deadline=None)
@given(key_and_text())
def test_no_fragment_of_the_key_survives_and_other_text_is_kept(case: tuple[str, str]) -> None:
    key, text = case
    out = Redactor(key).text(text)
    outside = out.replace(MARK, "\u00a4")  # nothing that spans a mark is text that came in
    if len(key) >= MIN_FRAGMENT:  # no fragment, in any case, whitespace skipped
        assert not any(g in visible(outside).lower() for g in windows(key))
        if not any(g in visible(text).lower() for g in windows(key)):
            assert out == text
    else:  # a short key: whole, in its own case
        assert key not in outside
        if key not in text:
            assert out == text


def test_the_redactor_takes_linear_time_on_adversarial_text() -> None:
    key = "sk-proj-" + "".join(np.random.default_rng(1).choice(list(KEY_ALPHABET), 156))
    redactor = Redactor(key)
    cases = {
        "the key over and over": key * (100_000 // len(key)),
        "fragments and separators": (key[:MIN_FRAGMENT] + " ") * (100_000 // (MIN_FRAGMENT + 1)),
        "near misses": (key[: MIN_FRAGMENT - 1] + "!") * (100_000 // MIN_FRAGMENT),
        "ordinary text": "[1, 0, 1, 0] " * (100_000 // 13),
    }
    for name, text in cases.items():
        started = time.perf_counter()
        redactor.text(text)
        assert time.perf_counter() - started < 0.5, name
    big = key * (4 * 1024 * 1024 // len(key))  # a whole 4 MiB body made of the key
    started = time.perf_counter()
    assert redactor.text(big) == MARK
    assert time.perf_counter() - started < 5.0


# ------------------------------------------------------------------------------ a server that echoes the key


def test_a_server_echoing_the_key_everywhere_leaks_nothing(
    server: FakeOpenAI, tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(KEY_ENV, ECHO_KEY)
    said: list[str] = []

    def tell(message: str) -> None:
        said.append(message)
        print(message, file=sys.stderr)

    settings = fast_settings(server.url, max_retries=2)
    answers: list[Answer] = []
    errors: list[str] = []

    # 1. the live provider itself: answers with the key in every field, and every kind of failure
    server.script.extend([echoing(echo_completion), echoing(echo_completion, retry=True)])
    with LiveProvider(settings, rng=np.random.default_rng(0), on_retry=tell) as live:
        answers += [live.complete(query()), live.complete(query())]
        for name, replies in FAILURES.items():
            server.script.clear()
            server.script.extend(replies)
            server.script.extend(replies[-1:] * 3)  # a retried failure keeps failing
            with pytest.raises(LagrseqError) as caught:
                live.complete(query())
            assert "\n" not in str(caught.value), name
            errors.append(f"{name}: {caught.value} {caught.value!r} {caught.value.args}")
    assert len(errors) == len(FAILURES)

    # 2. recording: the echoed answers go through the budget guard into a real store, then JSONL
    store_dir = tmp_path / "store"
    server.script.clear()
    server.script.extend(echoing(echo_completion) for _ in range(3))
    prices = PriceTable()
    inner = BudgetedProvider(LiveProvider(settings, rng=np.random.default_rng(1), on_retry=tell), Budget(max_queries=10), prices)
    with RecordingProvider(RecordStore(store_dir), inner, "127.0.0.1", mode="new", samples=3) as recorder:
        answers.append(recorder.complete(query()))
    with RecordStore(store_dir, create=False) as store, (tmp_path / "export.jsonl").open("w", encoding="utf-8") as out:
        report = export_jsonl(store, out)
    assert report.lines == 3

    # 3. what the callbacks were told went to stderr; the answers and errors are written out too
    (tmp_path / "answers.txt").write_text("\n".join(repr(a) for a in answers), encoding="utf-8")
    (tmp_path / "errors.txt").write_text("\n".join(errors), encoding="utf-8")
    captured = capfd.readouterr()
    assert said and captured.err.strip()

    # the key was really sent, and really echoed
    assert all(h.get("authorization") == f"Bearer {ECHO_KEY}" for h in server.headers)
    assert all(a.text.startswith(HARMLESS) and MARK in a.text for a in answers)

    found = {}
    seen_harmless = seen_mark = False
    for path, text in written(tmp_path):
        seen_harmless |= HARMLESS in text and path.parent == store_dir
        seen_mark |= MARK in text
        if leaks(text):
            found[str(path.relative_to(tmp_path))] = leaks(text)
    assert seen_harmless and seen_mark  # the scan reads what the store holds (decompressed)
    assert not found, found
    for text in [captured.out, captured.err, *said, *errors, *(repr(a) for a in answers)]:
        assert not leaks(text), text


def test_a_retry_message_never_carries_the_key(server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(KEY_ENV, ECHO_KEY)
    server.script.append(echoing(lambda k: error_body("requests", f"rate limited: {k[-20:]}", k), 429))
    said: list[str] = []
    with LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0), on_retry=said.append) as live:
        live.complete(query())
    assert len(said) == 1 and "HTTP 429" in said[0] and MARK in said[0] and not leaks(said[0])


def test_a_gzip_error_body_is_redacted_too(server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(KEY_ENV, ECHO_KEY)
    server.script.append(Reply(400, lambda k: gzip.compress(json.dumps(error_body("x", k)).encode()), {"Content-Encoding": "gzip"}))
    with LiveProvider(fast_settings(server.url), rng=np.random.default_rng(0)) as live, pytest.raises(LagrseqError) as caught:
        live.complete(query())
    assert "HTTP 400" in str(caught.value) and MARK in str(caught.value) and not leaks(str(caught.value))


@pytest.mark.parametrize(("value", "what"), [("sk-tëst-0123456789", "not ASCII"), ("sk-a\nb-0123456789", "control"), ("sk-a b-0123456789", "space")])
def test_a_key_that_cannot_go_in_a_header_is_one_line_naming_the_variable(
    monkeypatch: pytest.MonkeyPatch, server: FakeOpenAI, value: str, what: str
) -> None:
    monkeypatch.setenv(KEY_ENV, value)
    with pytest.raises(ConfigError) as caught:
        LiveProvider(fast_settings(server.url))
    message = str(caught.value)
    assert KEY_ENV in message and what in message and "\n" not in message
    assert not leaks(message, value) and value.strip() not in message
    assert server.requests == []


def test_a_live_run_and_a_recorded_run_log_no_key_fragment_to_mcap_or_stderr(
    tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """The whole path: ``lagrseq run --provider live`` (and ``recorded:`` with ``--on-miss live``)
    against a server that echoes the key in every field writes MCAP logs, a store and stderr
    with no fragment of it; /query.answer and /query.model come through, blanked."""
    from mcap.reader import make_reader

    from lagrseq import cli

    monkeypatch.setenv(KEY_ENV, ECHO_KEY)
    server.script.extend(echoing(echo_completion) for _ in range(400))
    common = ["--base-url", server.url, "--api-key-env", KEY_ENV, "--trials", "1", "--set", "run.episodes=3", "--quiet"]
    assert cli.main(["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--out", str(tmp_path / "runs"), *common]) == 0
    store = tmp_path / "store"
    assert cli.main(["run", "cube-stacking", "--method", "lagr", "--provider", f"recorded:{store}", "--on-miss", "live",
                     "--out", str(tmp_path / "runs2"), *common]) == 0
    logs = sorted(tmp_path.rglob("*.mcap"))
    assert len(logs) == 2 and server.requests
    answers = []
    for path in logs:  # the chunks are compressed: read every message and metadata record back
        with path.open("rb") as handle:
            reader = make_reader(handle)
            for _, channel, message in reader.iter_messages():
                assert leaks(message.data.decode()) == [], (path, channel.topic)
                record = json.loads(message.data)
                if channel.topic == "/query" and record["queried"]:
                    answers.append(record)
            for metadata in reader.iter_metadata():
                assert leaks(json.dumps(metadata.metadata)) == []
    assert answers and all(HARMLESS in a["answer"] and MARK in a["answer"] for a in answers)
    assert all(MARK in (a["model"] or "") for a in answers)
    found = {str(path): leaks(text) for path, text in written(tmp_path) if leaks(text)}
    assert found == {}, found
    captured = capfd.readouterr()
    assert leaks(captured.out + captured.err) == []
