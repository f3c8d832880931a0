"""IQM, stratified bootstrap, probability of improvement and performance profiles against
hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lagrseq.analysis import stats


def test_iqm_cuts_a_quarter_from_each_end() -> None:
    assert stats.iqm([1, 2, 3, 4, 5, 6, 7, 8]) == 4.5  # mean of 3, 4, 5, 6
    assert stats.iqm([10, 1, 2, 3]) == 2.5  # sorted 1 2 3 10: mean of 2, 3
    assert stats.iqm([5, 100, -100, 6, 7]) == 6.0  # n = 5 cuts 1 each side: mean of 5, 6, 7
    assert stats.iqm([3.0]) == 3.0 and math.isnan(stats.iqm([]))


def test_stratified_bootstrap_resamples_within_each_stratum() -> None:
    # every within-stratum resample of [0, 0, 0] and [10, 10, 10] has mean 5: the interval is a point,
    # while a bootstrap over the pooled six scores would spread
    low, high = stats.stratified_bootstrap_ci([[0, 0, 0], [10, 10, 10]], lambda gs: float(np.concatenate(gs).mean()), np.random.default_rng(1), 500)
    assert (low, high) == (5.0, 5.0)
    pooled = stats.bootstrap_ci([0, 0, 0, 10, 10, 10], np.random.default_rng(1), 500)
    assert pooled[0] < 5.0 < pooled[1]
    assert all(math.isnan(v) for v in stats.stratified_bootstrap_ci([[1.0]], np.mean, np.random.default_rng(0)))


def test_iqm_interval_is_seeded_and_brackets_the_iqm() -> None:
    scores = [[1, 2, 3, 4, 5, 6, 7, 8], [2, 4, 6, 8]]
    first = stats.iqm_ci(scores, stats.generator("iqm"), 2000)
    again = stats.iqm_ci(scores, stats.generator("iqm"), 2000)
    assert first == again
    value, low, high = first
    # sorted 1 2 2 3 4 4 5 6 6 7 8 8: 3 cut from each end leaves 3 4 4 5 6 6
    assert value == pytest.approx(28 / 6)
    assert low <= value <= high


def test_probability_of_improvement_counts_ties_half() -> None:
    # pairs of [1, 2] against [0, 2]: 1>0, 1<2, 2>0, 2=2 -> (1 + 0 + 1 + 0.5) / 4
    assert stats.probability_of_improvement([[1, 2]], [[0, 2]]) == 0.625
    # two strata average: 0.625 and P([5] > [5]) = 0.5
    assert stats.probability_of_improvement([[1, 2], [5]], [[0, 2], [5]]) == pytest.approx(0.5625)
    value, low, high = stats.probability_of_improvement_ci([[3, 4, 5]], [[0, 1, 2]], np.random.default_rng(0), 300)
    assert (value, low, high) == (1.0, 1.0, 1.0)  # every resample of X beats every resample of Y
    with pytest.raises(ValueError):
        stats.probability_of_improvement([[1]], [[1], [2]])


def test_performance_profile_is_the_fraction_above_each_threshold() -> None:
    assert stats.performance_profile([1, 2, 3, 4], [0, 2, 4]).tolist() == [1.0, 0.5, 0.0]
    profile, low, high = stats.performance_profile_ci([[1, 2], [3, 4]], [0, 2.5, 4], np.random.default_rng(0), 400)
    assert profile.tolist() == [1.0, 0.5, 0.0]
    # above 0 and above 4 no resample differs; above 2.5 exactly stratum two counts (always half)
    assert low.tolist() == [1.0, 0.5, 0.0] and high.tolist() == [1.0, 0.5, 0.0]


def test_vectorised_intervals_match_the_generic_stratified_bootstrap() -> None:
    strata = [[3.0, 1.0, 4.0, 1.0, 5.0], [9.0, 2.0, 6.0]]
    _, low, high = stats.iqm_ci(strata, np.random.default_rng(3), 800)
    generic = stats.stratified_bootstrap_ci(strata, lambda gs: stats.iqm(np.concatenate(gs)), np.random.default_rng(3), 800)
    assert (low, high) == pytest.approx(generic)
    x, y = [[1.0, 4.0, 2.0, 8.0]], [[3.0, 3.0, 5.0]]
    _, low, high = stats.probability_of_improvement_ci(x, y, np.random.default_rng(4), 600)
    # pairs: 1<3,1<3,1<5, 4>3,4>3,4<5, 2<3,2<3,2<5, 8>3,8>3,8>5 -> 5 of 12
    assert stats.probability_of_improvement(x, y) == pytest.approx(5 / 12)
    assert low <= 5 / 12 <= high and 0.0 <= low < high <= 1.0
