"""seq.py: the secondary agent's bandit update, its ties, and the query rewards."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lagrseq.config import TabularSecondaryConfig
from lagrseq.loop.seq import TabularSecondary, query_reward


def test_bandit_update_moves_toward_the_reward_by_the_learning_rate() -> None:
    bandit = TabularSecondary(learning_rate=0.1)
    bandit.update((1, 2), 1, 1.0)
    assert bandit.values((1, 2)).tolist() == [0.0, 0.1]
    bandit.update((1, 2), 1, -1.0)  # 0.1 + 0.1 * (-1 - 0.1)
    assert bandit.values((1, 2))[1] == pytest.approx(-0.01)
    bandit.update((1, 2), 0, 0.0)
    assert bandit.values((1, 2))[0] == 0.0
    assert bandit.values((2, 1)).tolist() == [0.0, 0.0], "rows are per state"


def test_ties_choose_not_to_query_and_greedy_follows_the_values() -> None:
    bandit = TabularSecondary(learning_rate=0.5)
    rng = np.random.default_rng(0)
    assert bandit.decide((3,), 0.0, rng) == 0, "an untried state is not queried when greedy"
    bandit.update((4,), 1, 1.0)
    assert bandit.decide((4,), 0.0, rng) == 1
    bandit.update((5,), 1, -1.0)
    assert bandit.decide((5,), 0.0, rng) == 0


def test_exploration_picks_both_arms_evenly() -> None:
    bandit = TabularSecondary(learning_rate=0.5)
    bandit.update((4,), 1, 1.0)
    rng = np.random.default_rng(3)
    picks = [bandit.decide((4,), 1.0, rng) for _ in range(4000)]
    assert 0.45 < np.mean(picks) < 0.55


def test_binary_query_reward() -> None:
    config = TabularSecondaryConfig(reward_correct=1.0, reward_wrong=-1.0)
    assert query_reward(1.0, True, config) == 1.0
    assert query_reward(0.99, False, config) == -1.0


@pytest.mark.parametrize(
    ("evaluation", "expected"),
    [
        (0.9, 0.5),  # the midpoint
        (1.0, 1 / (1 + math.exp(-2.0))),  # 0.8807970779778823
        (0.0, 1 / (1 + math.exp(18.0))),  # 1.522997951276035e-08
        (0.75, 1 / (1 + math.exp(3.0))),  # 0.04742587317756678
    ],
)
def test_logistic_query_reward_against_hand_computed_values(evaluation: float, expected: float) -> None:
    config = TabularSecondaryConfig(query_reward="logistic", logistic_steepness=20.0, logistic_midpoint=0.9)
    assert query_reward(evaluation, evaluation >= 1.0, config) == pytest.approx(expected, rel=1e-12)


def test_logistic_reward_ignores_acceptance_and_is_monotone() -> None:
    config = TabularSecondaryConfig(query_reward="logistic")
    values = [query_reward(e / 10, False, config) for e in range(11)]
    assert values == sorted(values) and values[-1] == query_reward(1.0, True, config)


def test_a_pattern_and_its_tuple_share_one_row() -> None:
    bandit = TabularSecondary(learning_rate=0.5)
    bandit.update([7, 8], 1, 1.0)  # a stack given as a list: its row is its tuple's
    assert bandit.values((7, 8)).tolist() == [0.0, 0.5]
    assert bandit.decide([7, 8], 0.0, np.random.default_rng(0)) == 1
