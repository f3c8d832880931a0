"""The frontier protocol (issue 20): refusals for store misses, matched-rate random, non-inferiority
against always, the tuning split on held-out seeds."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import cli
from lagrseq.logs.reader import read_info, read_topic
from tests.llm.conftest import authors_cache


def _cube_store(tmp_path: Path) -> Path:
    store = tmp_path / "store"
    path = authors_cache("cube_stacking_cache0.0.pkl")
    assert cli.main(["cache", "import", str(path), "--task", "cube-stacking", "--model", "gpt-3.5-turbo",
                     "--temperature", "0", "--store", str(store)]) == 0
    return store


def test_a_refused_miss_costs_a_query_is_logged_and_is_never_accepted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = _cube_store(tmp_path)
    common = ["run", "cube-stacking", "--method", "lagr", "--provider", f"recorded:{store}", "--on-miss", "refuse",
              "--trials", "1", "--out", str(tmp_path / "runs"), "--quiet", "--set", "run.episodes=6"]
    capsys.readouterr()
    assert cli.main([*common, "--set", "task.stack_size=5"]) == 0  # 5 cubes: no key is in the store
    printed = capsys.readouterr().out
    assert cli.main(common) == 0  # 8 cubes: every prefix is recorded
    by_size: dict[int, list[dict[str, object]]] = {}
    episodes: dict[int, list[dict[str, object]]] = {}
    for log in sorted((tmp_path / "runs").rglob("*.mcap")):
        size = read_info(log).config["task"]["stack_size"]
        by_size[size] = [q for q in read_topic(log, "/query") if q["queried"]]
        episodes[size] = read_topic(log, "/episode")
    refused = by_size[5]
    assert refused, "the always policy asks on the 5-cube task"
    for q in refused:  # logged as a miss: an empty answer, a wrong answer, never accepted
        assert q["source"] == "miss" and q["answer"] == "" and q["accepted"] is False and q["evaluation"] == 0.0
        assert q["finish_reason"] == "refused" and "refused" in str(q["parse_error"])
        assert q["query_reward"] < 0  # the binary query reward of a wrong answer
    # each refusal is a query: the episodes count them, and nothing was ever accepted
    assert sum(int(e["queries"]) for e in episodes[5]) == len(refused)  # type: ignore[call-overload]
    assert sum(int(e["accepted"]) for e in episodes[5]) == 0  # type: ignore[call-overload]
    assert f"{len(refused)} refused (--on-miss refuse: never accepted) (100.0% missed the store)" in printed
    # where the store holds the answers, nothing is refused and answers are accepted
    assert {q["source"] for q in by_size[8]} == {"recorded"} and any(q["accepted"] for q in by_size[8])


def test_refusal_is_no_answer_even_when_its_text_would_parse(tmp_path: Path) -> None:
    """The loop rejects a ``miss`` answer by its source, not by its text."""
    from lagrseq import config as cfg
    from lagrseq.lagr import consult
    from lagrseq.llm.base import Answer, Query
    from lagrseq.tasks.cube import CubeStacking

    task = CubeStacking(8)
    config = cfg.load("cube-stacking", "lagr", "paper")

    class Parrot:
        name = "parrot"

        def complete(self, query: Query) -> Answer:  # the right answer, but marked as a refusal
            return Answer(text="['a','b','c','d','e','f','g','h']", source="miss", model=query.model)

        def close(self) -> None:
            return None

        def __enter__(self) -> Parrot:
            return self

        def __exit__(self, *exc: object) -> None:
            return None

    result = consult(task, Parrot(), config.llm, config.lagr.threshold, (0,))
    assert result.accepted is False and result.evaluation == 0.0 and not result.parsed.ok
