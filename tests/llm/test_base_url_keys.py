"""A key anywhere in --base-url (the probe's shape: ``http://HOST/sk-.../v1``, as some gateways take
it; also in the host, after ``;``, percent-encoded, unprefixed) is refused in one line that does not
repeat it, before anything prints or writes it: no log, no store, no key in any stream or file."""

from __future__ import annotations

import pickle
import string
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq import cli
from lagrseq.llm.servers import base_url_problem
from tests.support.redaction import ECHO_KEY, leaks, written

SHAPES = {
    "path (the probe's)": f"http://127.0.0.1:9/{ECHO_KEY}/v1",
    "last segment": f"http://127.0.0.1:9/v1/{ECHO_KEY}",
    "host label": f"http://{ECHO_KEY.lower()[:60]}.example.com/v1",
    "path parameter": f"http://127.0.0.1:9/v1;api-key={ECHO_KEY[8:]}",
    "percent-encoded": "http://127.0.0.1:9/%73k-" + ECHO_KEY[3:] + "/v1",
    "no prefix": f"http://127.0.0.1:9/gw/{ECHO_KEY[8:]}/v1",
}


@pytest.mark.parametrize("url", SHAPES.values(), ids=SHAPES.keys())
@pytest.mark.parametrize("command", ["run-live", "run-recorded", "record", "cache-import"])
def test_a_key_in_the_base_url_is_refused_unseen(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, url: str, command: str
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", "sk-other-0123456789abcdef")
    small = ["--trials", "1", "--set", "run.episodes=1", "--quiet"]
    export = tmp_path / "answers.pkl"
    export.write_bytes(pickle.dumps([], protocol=4))
    argv = {
        "run-live": ["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--out", str(tmp_path / "runs"), *small],
        "run-recorded": ["run", "cube-stacking", "--method", "lagr", "--provider", f"recorded:{tmp_path / 'store'}", "--on-miss", "live",
                         "--out", str(tmp_path / "runs"), *small],
        "record": ["record", "cube-stacking", "--store", str(tmp_path / "store"), "--samples", "1", "--quiet"],
        "cache-import": ["cache", "import", str(export), "--store", str(tmp_path / "store"), "--task", "cube-stacking",
                         "--model", "gpt-4o-mini", "--temperature", "0"],
    }[command]
    assert cli.main([*argv, "--base-url", url]) == 2
    out, err = capfd.readouterr()
    assert len(err.strip().splitlines()) == 1 and "--base-url carries" in err, err
    assert leaks(err + out) == [] and leaks(err + out, ECHO_KEY.lower()) == []
    found = {str(path): leaks(text) for path, text in written(tmp_path) if leaks(text)}
    assert found == {}, found
    assert not list(tmp_path.rglob("*.mcap*")) and not (tmp_path / "store").exists()


TOKEN = string.ascii_letters + string.digits


@settings(max_examples=200, deadline=None)
@given(
    prefix=st.sampled_from(["sk-", "sk-proj-", "key_", "api-key=", "token:", "Bearer-"]),
    secret=st.text(TOKEN, min_size=8, max_size=80).filter(lambda s: any(c.isdigit() for c in s)),
    before=st.lists(st.sampled_from(["v1", "api", "openai", "gw", "deployments", "gpt-4o-mini"]), max_size=3),
    after=st.lists(st.sampled_from(["v1", "openai", "chat"]), max_size=2),
)
def test_any_prefixed_key_anywhere_in_the_path_is_refused(prefix: str, secret: str, before: list[str], after: list[str]) -> None:
    url = "https://gateway.example.com/" + "/".join([*before, prefix + secret, *after])
    problem = base_url_problem(url)
    assert problem is not None and secret not in problem


@pytest.mark.parametrize(
    "url",
    ["https://api.openai.com/v1", "http://127.0.0.1:8080/v1", "http://localhost:11434/v1", "https://openrouter.ai/api/v1",
     "https://my.azure.com/openai/deployments/gpt-4o-mini-2024-07-18", "http://h/skip-connection-layer/v1",
     "https://gateway.ai.cloudflare.com/v1/0123456789abcdef0123456789abcdef/my-gateway/openai", "local"],
)
def test_ordinary_api_roots_pass(url: str) -> None:
    assert base_url_problem(url) is None
