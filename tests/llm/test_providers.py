"""One interface, every implementation: mock, recorded and live providers answer the same query
the same way as far as the caller can tell, and close cleanly."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from lagrseq import config as cfg
from lagrseq.llm.base import Answer, Provider, Usage
from lagrseq.llm.live import LiveProvider
from lagrseq.llm.mock import MockProvider
from lagrseq.llm.recorded import RecordedProvider, RecordingProvider
from lagrseq.llm.store import RecordStore
from lagrseq.loop.lagr import consult
from lagrseq.running import recording
from lagrseq.tasks import cube
from tests.llm.conftest import FakeOpenAI, fast_settings

CONFIG = cfg.load("cube-stacking", "lagr", "upstream")
TASK = cube.CubeStacking(8)
KINDS = ["mock", "recorded", "live", "recording"]


@pytest.fixture(params=KINDS)
def provider(request: pytest.FixtureRequest, tmp_path: Path, server: FakeOpenAI) -> Iterator[tuple[str, Provider]]:
    kind = request.param
    rng = np.random.default_rng(0)
    live = LiveProvider(fast_settings(server.url), rng=rng)
    if kind == "mock":
        made: Provider = MockProvider(cube.extrapolate, rng)
    elif kind == "live":
        made = live
    else:
        store = RecordStore(tmp_path / "store")
        recorder = RecordingProvider(store, live, live.endpoint, "new", samples=2)
        if kind == "recording":
            made = recorder
        else:  # recorded: fill the store through the recorder first, then replay it alone
            for prefix in TASK.prefixes():
                recorder.top_up(recording.queries_for(CONFIG, [prefix])[0])
            made = RecordedProvider(RecordStore(tmp_path / "store", create=False), live.endpoint, 0)
            store.close()
    yield kind, made
    made.close()
    live.close()


def test_every_provider_answers_a_task_prompt_with_parseable_text(provider: tuple[str, Provider]) -> None:
    kind, made = provider
    with made:
        for prefix in TASK.prefixes():
            result = consult(TASK, made, CONFIG.llm, 1.0, prefix)
            answer = result.answer
            assert isinstance(answer, Answer) and result.parsed.ok, (kind, answer.text)
            assert answer.source == {"mock": "mock", "recorded": "recorded"}.get(kind, answer.source)
            assert answer.source in ("mock", "recorded", "live")
            assert isinstance(answer.usage, Usage) and answer.usage.prompt_tokens > 0
            assert answer.cost_usd is None or answer.cost_usd >= 0
            assert answer.model
            assert (answer.record_key is not None) == (kind in ("recorded", "recording"))
    made.close()  # idempotent


def test_every_provider_gives_the_same_answers_as_the_extrapolator(provider: tuple[str, Provider]) -> None:
    """The test server answers with the rule-based extrapolator too, so all four agree."""
    _, made = provider
    with made:
        texts = [consult(TASK, made, CONFIG.llm, 1.0, p).parsed.solution for p in TASK.prefixes()]
    expected = [TASK.parse(cube.extrapolate(TASK.prompt(p), 0.0, np.random.default_rng(0))).solution for p in TASK.prefixes()]
    assert texts == expected
