"""Epsilon schedules: per episode (cube) and per step with a warm-up (grid DQNs)."""

from __future__ import annotations

import pytest

from lagrseq.agents.schedules import EpsilonSchedule


def test_paper_grid_schedule_decays_per_step() -> None:
    schedule = EpsilonSchedule("exponential", 1.0, 0.1, 0.998, 10_000, unit="step")
    assert schedule.at(0, 0) == 1.0
    assert schedule.at(0, 100) == pytest.approx(0.998**100)
    assert schedule.at(7, 1150) == pytest.approx(0.1, abs=1e-3)  # 0.998**1150 ~ 0.1
    assert schedule.at(20, 5000) == 0.1


def test_released_grid_schedule_counts_episodes_after_a_full_batch() -> None:
    schedule = EpsilonSchedule("inverse-episode", 1.0, 0.1, 0.0, 0, unit="episode", warmup=64)
    assert [schedule.at(0, s) for s in (0, 63, 64)] == [1.0, 1.0, 1.0]
    assert schedule.at(1, 500) == 0.5 and schedule.at(3, 1500) == 0.25
    assert schedule.at(9, 4500) == pytest.approx(0.1) and schedule.at(40, 9000) == 0.1
    # a warm-up longer than the first episode keeps epsilon at its start value
    assert EpsilonSchedule("inverse-episode", 1.0, 0.1, 0.0, 0, warmup=64).at(3, 40) == 1.0


def test_step_schedules_count_from_the_end_of_the_warmup() -> None:
    schedule = EpsilonSchedule("exponential", 1.0, 0.1, 0.5, 0, unit="step", warmup=10)
    assert [schedule.at(0, s) for s in (9, 10, 11, 12)] == [1.0, 1.0, 0.5, 0.25]


def test_episode_schedules_are_unchanged() -> None:
    cube = EpsilonSchedule("divide-cumulative", 1.0, 0.05, 0.0, 100)
    assert [cube.at(e, 50 * e) for e in range(5)] == pytest.approx([1.0, 0.5, 1 / 6, 0.05, 0.05])
    assert cube(10_000) == 0.05  # no loop over every index
    linear = EpsilonSchedule("linear", 1.0, 0.05, 0.0, 100)
    assert linear.at(25, 0) == pytest.approx(0.525) and linear.at(60, 0) == pytest.approx(0.05)


def test_unknown_unit_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown epsilon unit"):
        EpsilonSchedule("constant", 1.0, 1.0, 0.0, 0, unit="minute")
