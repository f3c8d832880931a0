"""mock:authors-gpt4, the grid profile calibrated on the authors' GPT-4 answers."""

from __future__ import annotations

import numpy as np
import pytest

from lagrseq.tasks import grid, grid_profiles
from lagrseq.tasks.arrangement import object_arrangement
from lagrseq.tasks.image import image_completion
from tests.authors_caches import grid_pairs

CASES = [
    ("image_completion_gpt4.pkl", image_completion, (10, 10)),
    ("object_arrangement_gpt4.pkl", object_arrangement, (5, 5)),
]


@pytest.mark.filterwarnings("ignore:object_arrangement_gpt4.pkl")
@pytest.mark.parametrize(("name", "make", "shape"), CASES)
def test_the_profile_is_what_the_caches_measure(name, make, shape) -> None:  # type: ignore[no-untyped-def]
    task = make()
    pairs = grid_pairs(name, shape)
    clean, dirty, counts, dirty_counts = grid_profiles.calibrate(pairs, task, grid_profiles.ACCEPT[task.name])
    table = {t: (c, d) for t, c, d in grid_profiles.AUTHORS_GPT4.tables}[task.name]
    assert table == (clean, dirty)
    assert sum(counts) + sum(dirty_counts) == len(pairs)


@pytest.mark.filterwarnings("ignore:object_arrangement_gpt4.pkl")
@pytest.mark.parametrize(("name", "make", "shape"), CASES)
def test_on_the_recorded_patterns_the_profile_is_right_about_as_often_as_gpt4(name, make, shape) -> None:  # type: ignore[no-untyped-def]
    task = make()
    pairs = grid_pairs(name, shape)
    accept = grid_profiles.ACCEPT[task.name]
    handler = grid_profiles.profile_extrapolator(task, "authors-gpt4")
    recorded = np.mean([task.evaluate(a) >= accept for _, a in pairs])
    rng = np.random.default_rng(0)
    answers = [task.parse(handler(task.prompt(k), 0.0, rng)) for k, _ in pairs]
    assert all(a.ok for a in answers)  # wrong answers are well-formed grids too
    rate = np.mean([task.evaluate(a.solution) >= accept for a in answers])
    n = len(pairs)
    assert abs(rate - recorded) <= 3 * np.sqrt(recorded * (1 - recorded) / n) + 1 / n
    # at tau = 0 one partial pattern always gets the same answer, as GPT-4's did
    key = pairs[0][0]
    assert len({handler(task.prompt(key), 0.0, rng) for _ in range(20)}) == 1
    # wrong answers are never acceptable
    wrong = [a for a in answers if task.evaluate(a.solution) < accept]
    assert wrong and all(task.evaluate(a.solution) < accept for a in wrong)


def test_features_and_bins() -> None:
    task = image_completion()
    partial = np.zeros((10, 10), dtype=np.int8)
    assert grid_profiles.features(partial, task.target) == (0.0, False)
    partial[0, 0] = 1  # on the X
    partial[0, 5] = 1  # off the X
    fraction, wrong = grid_profiles.features(partial, task.target)
    assert fraction == pytest.approx(1 / 20) and wrong
    assert [grid_profiles.fraction_bin(f) for f in (0.0, 0.25, 0.5, 0.74, 1.0)] == [0, 1, 2, 2, 3]
    with pytest.raises(ValueError, match="unknown grid mock profile"):
        grid_profiles.profile_extrapolator(task, "genius")
    assert grid.partial_grid(task.prompt(partial)).shape == (10, 10)
