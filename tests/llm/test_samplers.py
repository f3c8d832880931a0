"""llama.cpp's samplers pinned to OpenAI's meaning of temperature (top_k 0, min_p 0, repeat_penalty
1, top_p 1) and kept in the record key only where pinned, so every key recorded before stays what it
was; Fig. 4's probe draws a store's recorded answers without replacement. The stand-in server's
side (it receives the pinned samplers) is tests/test_screen.py's live screen."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lagrseq import config as cfg
from lagrseq.llm.base import Answer, Message, Query, pinned, samplers_of, with_samplers
from lagrseq.llm.live import LiveProvider, LiveSettings
from lagrseq.llm.recorded import RecordedProvider, RecordingProvider
from lagrseq.llm.records import problems
from lagrseq.llm.servers import LLAMA_CPP_SAMPLERS, SERVER_KINDS
from lagrseq.llm.store import (
    RecordStore,
    SampleChooser,
    draw_order,
    pick_index,
    query_key,
    request_of,
    sample_from_answer,
)

ROOT = Path(__file__).resolve().parents[2]
PINNED = {"top_k": 0, "min_p": 0.0, "repeat_penalty": 1.0}


def query(temperature: float = 0.5) -> Query:
    return Query("cube-stacking", "qwen", (Message("user", "complete ['e','f']"),), temperature, 256)


def live(server: str) -> LiveProvider:
    return LiveProvider(LiveSettings(base_url="http://127.0.0.1:9/v1", server=server), rng=np.random.default_rng(0), environ={})


def test_only_llama_cpp_pins_its_samplers_and_sends_them() -> None:
    assert dict(SERVER_KINDS["llama.cpp"].samplers) == PINNED
    llama, openai = live("llama.cpp"), live("openai")
    try:
        body = llama.body(llama.pin(query()), 1)
        assert {name: body[name] for name in ("temperature", "top_p", *PINNED)} == {"temperature": 0.5, "top_p": 1.0, **PINNED}
        # OpenAI's API knows no top_k, min_p or repeat_penalty: nothing is pinned, nothing sent
        plain = openai.body(openai.pin(query()), 1)
        assert not set(PINNED) & set(plain)
    finally:
        llama.close()
        openai.close()


def test_a_query_that_sets_a_sampler_keeps_it() -> None:
    mine = with_samplers(with_samplers(query(), [("top_k", 5)]), LLAMA_CPP_SAMPLERS)
    assert samplers_of(mine) == {"top_k": 5, "min_p": 0.0, "repeat_penalty": 1.0}


def test_keys_without_samplers_are_the_keys_of_before() -> None:
    plain = request_of(query(), "local")
    assert set(plain) == {"key_version", "endpoint", "model", "messages", "temperature", "top_p", "max_tokens", "stop", "seed"}
    pinned_request = request_of(with_samplers(query(), LLAMA_CPP_SAMPLERS), "local")
    assert {name: pinned_request[name] for name in PINNED} == PINNED
    assert query_key(query(), "local")[0] != query_key(with_samplers(query(), LLAMA_CPP_SAMPLERS), "local")[0]
    # the record schema accepts both, and refuses a sampler out of its range
    assert problems(pinned_request, _request_schema()) == []
    assert problems({**pinned_request, "min_p": 2.0}, _request_schema())


def _request_schema() -> dict[str, object]:
    from lagrseq.llm.records import REQUEST_SCHEMA

    return REQUEST_SCHEMA


class Fixed:
    """A provider of llama.cpp's kind that numbers its answers."""

    name = "fixed"

    def __init__(self) -> None:
        self.asked: list[Query] = []

    def pin(self, q: Query) -> Query:
        return with_samplers(q, LLAMA_CPP_SAMPLERS)

    def complete(self, q: Query) -> Answer:
        self.asked.append(q)
        return Answer(f"answer {len(self.asked)}", "live", "qwen")

    def close(self) -> None:
        return None


def test_a_recorder_keys_what_it_sends_and_a_replay_of_the_plain_query_finds_it(tmp_path: Path) -> None:
    inner = Fixed()
    with RecordingProvider(RecordStore(tmp_path / "store"), inner, "local", "new", 2) as recorder:  # type: ignore[arg-type]
        answer = recorder.complete(query())
    assert samplers_of(inner.asked[0]) == PINNED and answer.record_key == query_key(pinned(inner, query()), "local")[0]
    with RecordStore(tmp_path / "store", create=False) as store:
        (entry,) = list(store.entries())
        assert {name: entry.request[name] for name in PINNED} == PINNED
    # a run asks without samplers (OpenAI's meaning, the same request): the pinned answers serve it
    with RecordedProvider(RecordStore(tmp_path / "store", create=False), "local", 0) as replay:
        assert replay.complete(query()).text in {"answer 1", "answer 2"}


def test_a_plain_record_is_still_found_first(tmp_path: Path) -> None:
    store = RecordStore(tmp_path / "store")
    key, request = query_key(query(), "local")
    store.add(key, request, "cube-stacking", [sample_from_answer(Answer("plain", "live", "qwen"), key)])
    pinned_key, pinned_request = query_key(with_samplers(query(), LLAMA_CPP_SAMPLERS), "local")
    store.add(pinned_key, pinned_request, "cube-stacking", [sample_from_answer(Answer("pinned", "live", "qwen"), pinned_key)])
    with RecordedProvider(store, "local", 0) as replay:
        assert replay.complete(query()).text == "plain"
        assert replay.complete(with_samplers(query(), LLAMA_CPP_SAMPLERS)).text == "pinned"


def test_without_replacement_every_sample_once_before_any_repeats() -> None:
    key = "ab" * 32
    chooser = SampleChooser(7, without_replacement=True)
    first = [chooser.choose(key, 10) for _ in range(10)]
    assert sorted(first) == list(range(10)) and first == draw_order(7, key, 10)
    # the 11th occurrence draws with replacement, as a trial would
    assert chooser.choose(key, 10) == pick_index(7, key, 10, 10)
    # with replacement (a trial): the same draws as always
    plain = SampleChooser(7)
    assert [plain.choose(key, 10) for _ in range(3)] == [pick_index(7, key, i, 10) for i in range(3)]


def test_the_probe_shows_the_recorded_counts_of_qwen_at_tau_half(tmp_path: Path) -> None:
    """Fig. 4's line of Qwen2.5-Coder-1.5B at tau = 0.5 (10 answers recorded per prefix, 10 asked):
    each prefix's right answers are exactly the recorded ones (5/10 at 4 of 8 cubes, 8/10 at 5 of 8),
    not a resample with replacement."""
    from lagrseq.analysis.loading import load
    from lagrseq.running import wiring
    from lagrseq.study import probe, screen

    path = ROOT / "recorded_llm" / "qwen2.5-coder-1.5b-cube-t0.5.jsonl"
    spec = f"recorded:{path}"
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["llm.temperature=0.5", "llm.model=qwen2.5-coder-1.5b-instruct-q4_k_m"])
    options = wiring.provider_options(spec, {"on_miss": "refuse"})
    probe.run_accuracy_probe(config, 10, 0, spec, tmp_path / "probe.mcap", provider_options=options)
    (run,) = load([tmp_path]).runs
    queries = run.queries
    assert (queries["source"] == "recorded").all() and len(queries) == 80
    right = queries.groupby("prefix_length")["accepted"].apply(lambda a: int(a.fillna(False).astype(bool).sum())).to_dict()
    (recorded,) = screen.screens_from([path], [config])
    assert right == {b: k for b, (_, k) in recorded.cells.items()}
    assert right[4] == 5 and right[5] == 8
    from lagrseq.logs.reader import read_info

    assert "without replacement" in read_info(tmp_path / "probe.mcap").run["recorded_draws"]
    assert json.loads(read_info(tmp_path / "probe.mcap").run["provider_options"])["on_miss"] == "refuse"
