"""Tabular Q-learning, epsilon-greedy selection and exploration schedules."""

from __future__ import annotations

import numpy as np
import pytest

from lagrseq.agents.schedules import EpsilonSchedule
from lagrseq.agents.tabular import TabularQ, epsilon_greedy


def test_q_update_is_the_textbook_rule() -> None:
    agent = TabularQ(3, learning_rate=0.1, discount=0.95)
    agent.values("s2")[:] = [0.0, 2.0, 1.0]
    error = agent.update("s1", 1, 1.0, "s2", terminal=False)
    assert error == pytest.approx(1.0 + 0.95 * 2.0)
    assert agent.values("s1")[1] == pytest.approx(0.1 * (1.0 + 1.9))
    agent.update("s1", 0, 1.0, "s2", terminal=True)  # no bootstrap at a terminal
    assert agent.values("s1")[0] == pytest.approx(0.1)
    agent.update("s3", 0, 0.0, "unseen", terminal=False)  # an unseen next state is worth 0
    assert agent.values("s3")[0] == 0.0 and "unseen" not in agent.table


def test_greedy_ties_take_the_first_action() -> None:
    rng = np.random.default_rng(0)
    assert epsilon_greedy(np.zeros(4), 0.0, rng) == 0


def test_mask_picks_only_valid_actions() -> None:
    rng = np.random.default_rng(0)
    values = np.array([5.0, 1.0, 2.0])
    mask = np.array([0, 1, 1], dtype=np.int8)
    assert epsilon_greedy(values, 0.0, rng, mask, "mask") == 2
    picks = {epsilon_greedy(values, 1.0, rng, mask, "mask") for _ in range(200)}
    assert picks == {1, 2}


def test_resample_redraws_an_invalid_greedy_pick_uniformly() -> None:
    rng = np.random.default_rng(1)
    values = np.array([5.0, 1.0, 2.0, 0.0])
    mask = np.array([0, 1, 1, 1], dtype=np.int8)
    picks = [epsilon_greedy(values, 0.0, rng, mask, "resample") for _ in range(3000)]
    counts = np.bincount(picks, minlength=4)
    assert counts[0] == 0
    assert np.allclose(counts[1:] / 3000, 1 / 3, atol=0.04)  # not the greedy-among-valid 2


def test_divide_cumulative_schedule_of_the_released_cube_code() -> None:
    schedule = EpsilonSchedule("divide-cumulative", 1.0, 0.05, 0.0, 100)
    assert [round(schedule(i), 4) for i in range(5)] == [1.0, 0.5, 0.1667, 0.05, 0.05]


def test_other_schedules() -> None:
    linear = EpsilonSchedule("linear", 1.0, 0.05, 0.0, 100)
    assert linear(0) == 1.0 and linear(25) == pytest.approx(0.525) and linear(50) == pytest.approx(0.05)
    assert EpsilonSchedule("linear", 1.0, 0.1, 10, 100)(5) == pytest.approx(0.55)
    assert EpsilonSchedule("exponential", 1.0, 0.1, 0.5, 10)(2) == 0.25
    assert EpsilonSchedule("inverse-episode", 1.0, 0.1, 0.0, 10)(1) == 0.5
    assert EpsilonSchedule("inverse-episode", 1.0, 0.1, 0.0, 10)(50) == 0.1
    assert EpsilonSchedule("constant", 1.0, 0.1, 0.0, 10)(50) == 1.0
    with pytest.raises(ValueError, match="unknown epsilon schedule"):
        EpsilonSchedule("cosine", 1.0, 0.1, 0.0, 10)
