"""Statistics: exact values on small inputs, seeded bootstraps, curves over ragged trials."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lagrseq.analysis import stats
from tests.support.summaries import summarize


def test_mean_std_se_use_the_sample_standard_deviation() -> None:
    mean, std, se = stats.mean_std_se([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    assert std == pytest.approx(math.sqrt(5 / 3))
    assert se == pytest.approx(math.sqrt(5 / 3) / 2)
    single = stats.mean_std_se([7.0])
    assert single[0] == 7.0 and math.isnan(single[1]) and math.isnan(single[2])
    assert all(math.isnan(v) for v in stats.mean_std_se([]))


def test_bootstrap_is_reproducible_from_its_key_and_seed() -> None:
    values = np.array([126.0, 130.0, 133.0, 128.0, 131.0, 140.0, 122.0, 129.0, 135.0, 127.0])
    first = stats.bootstrap_ci(values, stats.generator("table2/0/LaGR-SEQ"))
    again = stats.bootstrap_ci(values, stats.generator("table2/0/LaGR-SEQ"))
    other = stats.bootstrap_ci(values, stats.generator("another statistic"))
    assert first == again
    assert first != other
    assert first[0] < values.mean() < first[1]
    assert stats.bootstrap_ci(values, stats.generator("k"), resamples=10)[0] >= values.min()


def test_bootstrap_interval_has_about_the_normal_width() -> None:
    rng = np.random.default_rng(3)
    values = rng.normal(10.0, 2.0, size=400)
    low, high = stats.bootstrap_ci(values, stats.generator("width"))
    _, _, se = stats.mean_std_se(values)
    assert (high - low) == pytest.approx(2 * 1.96 * se, rel=0.1)


def test_bootstrap_of_constant_values_and_of_one_value() -> None:
    assert stats.bootstrap_ci([5.0, 5.0, 5.0], stats.generator("c")) == (5.0, 5.0)
    low, high = stats.bootstrap_ci([5.0], stats.generator("one"))
    assert math.isnan(low) and math.isnan(high)


def test_summarize_collects_everything() -> None:
    s = summarize([2.0, 4.0], stats.generator("s"))
    assert (s.n, s.mean, s.std) == (2, 3.0, pytest.approx(math.sqrt(2)))
    assert s.se == pytest.approx(1.0)
    assert 2.0 <= s.ci_low <= s.ci_high <= 4.0


def test_curve_handles_trials_of_different_lengths() -> None:
    matrix = np.array([[1.0, 2.0, 3.0], [3.0, 4.0, np.nan]])
    c = stats.curve(np.array([1, 2, 3]), matrix)
    assert c.mean.tolist() == [2.0, 3.0, 3.0]
    assert c.n.tolist() == [2, 2, 1]
    assert c.std[:2] == pytest.approx([math.sqrt(2), math.sqrt(2)])
    assert math.isnan(c.std[2]) and math.isnan(c.se[2])
    with pytest.raises(ValueError, match="does not fit"):
        stats.curve(np.array([1, 2]), matrix)


def test_moving_average_uses_fewer_values_at_the_start() -> None:
    assert stats.moving_average(np.array([1.0, 2.0, 3.0, 4.0]), 2).tolist() == [1.0, 1.5, 2.5, 3.5]
    assert stats.moving_average(np.array([1.0, 2.0]), 1).tolist() == [1.0, 2.0]


def test_step_curve_is_the_mean_of_the_last_episodes_finished_by_each_step() -> None:
    end_steps = np.array([100, 250, 300])
    returns = np.array([1.0, 3.0, 5.0])
    grid = np.array([50, 100, 200, 250, 299, 300, 1000])
    out = stats.step_curve(end_steps, returns, grid, window=2)
    assert out[0] == stats.BEFORE_FIRST_EPISODE == 0.0  # no episode finished yet: counts 0, not NaN
    assert out[1:].tolist() == [1.0, 1.0, 2.0, 2.0, 4.0, 4.0]
    assert math.isnan(stats.step_curve(end_steps, returns, grid, window=2, before=math.nan)[0])


def test_only_a_last_episode_cut_off_by_the_budget_is_unfinished() -> None:
    steps, unsolved = np.array([50, 100, 200]), np.array([False, False, False])
    assert stats.finished_episodes(steps, unsolved, 200).tolist() == [True, True, False]
    assert stats.finished_episodes(steps, np.array([False, False, True]), 200).tolist() == [True] * 3  # solved at the budget
    assert stats.finished_episodes(steps, unsolved, 0).tolist() == [True] * 3  # no budget
    assert stats.finished_episodes(steps, unsolved, 300).tolist() == [True] * 3  # ended before the budget
    lengths = np.array([50, 50, 100])
    assert stats.finished_episodes(steps, unsolved, 200, lengths, horizon=100).tolist() == [True] * 3  # its full horizon
    assert stats.finished_episodes(steps, unsolved, 200, lengths, horizon=150).tolist() == [True, True, False]


def test_paired_ratios_pair_by_trial_index() -> None:
    ratios = stats.paired_ratios({0: 10.0, 1: 12.0, 2: 9.0}, {1: 6.0, 0: 5.0})
    assert ratios.tolist() == [2.0, 2.0]


def test_paired_ratios_leave_out_a_trial_whose_denominator_is_zero() -> None:
    ratios = stats.paired_ratios({0: 10.0, 1: 12.0, 2: 9.0}, {0: 5.0, 1: 0.0, 2: 3.0})
    assert ratios.tolist() == [2.0, 3.0]
    assert stats.paired_ratios({0: 1.0}, {0: 0.0}).size == 0
