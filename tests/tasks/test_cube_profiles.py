"""Calibrated mock profiles of cube stacking and the task's pattern coercion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lagrseq.logs.reader import read_topic
from lagrseq.tasks import cube

AUTHORS_CACHES = Path(__file__).resolve().parents[3] / "shared" / "data" / "authors_caches"


def cache_pairs(name: str) -> list[tuple[object, object]]:
    path = AUTHORS_CACHES / name
    if not path.is_file():
        pytest.skip(f"authors' cache {name} not found at {AUTHORS_CACHES} (the shared/ folder beside the repository)")
    from lagrseq.llm.authors_cache import read_pairs

    return read_pairs(path)


@pytest.mark.parametrize(("stack_size", "name"), [(8, "cube_stacking_cache0.0.pkl"), (11, "cube_stacking_cache0.pkl")])
def test_the_authors_t0_profile_is_what_the_caches_measure(stack_size: int, name: str) -> None:
    measured = cube.calibrate_accuracy(cache_pairs(name), cube.CubeStacking(stack_size))
    assert dict(cube.AUTHORS_T0.accuracy)[stack_size] == measured


@pytest.mark.parametrize(("stack_size", "name"), [(8, "cube_stacking_cache0.0.pkl"), (11, "cube_stacking_cache0.pkl")])
def test_the_profile_is_right_exactly_where_the_recorded_answers_are(stack_size: int, name: str) -> None:
    task = cube.CubeStacking(stack_size)
    handler = cube.profile_extrapolator(task, "authors-t0")
    rng = np.random.default_rng(0)
    rates = []
    for prefix in task.prefixes():
        answers = [task.parse(handler(task.prompt(prefix), 0.0, rng)) for _ in range(200)]
        assert all(a.ok for a in answers)  # wrong answers are still well-formed orders
        rates.append(np.mean([task.is_complete(a.solution) for a in answers]))
    measured = cube.calibrate_accuracy(cache_pairs(name), task)
    assert np.allclose(rates, measured, atol=0.1)


def test_wrong_answers_look_like_the_recorded_ones() -> None:
    task = cube.CubeStacking(8)
    handler = cube.profile_extrapolator(task, "authors-t0")
    rng = np.random.default_rng(0)
    one = task.parse(handler(task.prompt((4,)), 0.0, rng)).solution
    assert task.render(one) == "efghabcd"  # GPT's recorded answer to the 1-cube prefix
    full = task.parse(handler(task.prompt(task.target), 0.0, rng)).solution
    assert full != task.target and sorted(full) == list(range(8))


def test_oracle_and_ideal_profiles() -> None:
    task = cube.CubeStacking(5)
    oracle = cube.profile_extrapolator(task, "oracle")
    rng = np.random.default_rng(0)
    assert all(task.is_complete(task.parse(oracle(task.prompt(p), 1.0, rng)).solution) for p in task.prefixes())
    assert cube.profile_extrapolator(task, "ideal") is cube.extrapolate
    with pytest.raises(ValueError, match="unknown mock profile 'genius'"):
        cube.profile_extrapolator(task, "genius")


def test_stack_sizes_without_data_use_the_nearest_table_by_fraction() -> None:
    assert [cube.AUTHORS_T0.probability(n, 5) for n in range(1, 6)] == [0.0, 1.0, 1.0, 1.0, 0.0]
    assert cube.AUTHORS_T0.probability(7, 11) == 0.3


def test_coerce_pattern_accepts_cube_ids_and_says_what_is_wrong() -> None:
    task = cube.CubeStacking(8)
    assert task.coerce_pattern([4, 5]) == (4, 5) and task.coerce_pattern(np.array([4])) == (4,)
    for value, message in [
        ([4, 8], "cube id 8 is not one of the 8 cubes"),
        ([4, 4], "appears twice"),
        (np.zeros((5, 5)), "shape"),
        ("efg", "expected a list"),
        ([4.0], "integers"),
    ]:
        with pytest.raises(ValueError, match=message):
            task.coerce_pattern(value)
    assert task.prefixes()[-1] == task.target and len(task.prefixes()) == 8


@pytest.mark.parametrize("task", ["cube-stacking", "object-arrangement"])
def test_the_refusing_profile_is_never_accepted_on_any_task(task: str, tmp_path: Path) -> None:
    """mock:refuses: a never-right model for every task (what SEQ does when asking never pays, and
    the states to record a real never-right model's answers for): every answer is refused by the
    parser, nothing is accepted, and SEQ asks less than LaGR."""
    from lagrseq import config as cfg
    from lagrseq.running import wiring
    from lagrseq.running.runner import run_one

    if task != "cube-stacking":
        pytest.importorskip("torch")
    assert "refuses" in wiring.mock_profiles()
    length = "run.episodes=30" if task == "cube-stacking" else "run.max_steps=300"
    asked = {}
    for method in ("lagr", "lagr-seq"):
        config = cfg.load(task, method, "upstream", None, [length])
        made = wiring.make_task(config)
        answer = wiring.extrapolator(config, "refuses")("any prompt", 0.0, np.random.default_rng(0))
        assert made.parse(answer).solution is None
        result = run_one(config, 0, 0, "mock:refuses", tmp_path / f"{method}.mcap")
        queries = [q for q in read_topic(tmp_path / f"{method}.mcap", "/query") if q.get("queried")]
        assert queries and not any(q["accepted"] for q in queries)
        asked[method] = result.queries
    assert 0 < asked["lagr-seq"] < asked["lagr"]
