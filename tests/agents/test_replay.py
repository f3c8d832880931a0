"""The replay buffer: ring overwrite, seeded sampling without replacement."""

from __future__ import annotations

import numpy as np
import pytest

from lagrseq.agents.replay import ReplayBuffer


def filled(n: int, capacity: int = 5) -> ReplayBuffer:
    buffer = ReplayBuffer(capacity, 2)
    for i in range(n):
        buffer.add(np.array([i, i]), i % 2, float(i), np.array([i + 1, i + 1]), i == n - 1)
    return buffer


def test_keeps_the_last_transitions() -> None:
    buffer = filled(8)
    assert len(buffer) == 5
    assert sorted(buffer.rewards.tolist()) == [3.0, 4.0, 5.0, 6.0, 7.0]
    assert buffer.observations.dtype == np.float32


def test_samples_distinct_rows_reproducibly() -> None:
    buffer = filled(5)
    a = buffer.sample(4, np.random.default_rng(1))
    b = buffer.sample(4, np.random.default_rng(1))
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert len(set(a.rewards.tolist())) == 4
    assert np.array_equal(a.next_observations[:, 0], a.observations[:, 0] + 1)
    assert a.terminals[a.rewards == 4.0].tolist() in ([1.0], [])


def test_refuses_a_batch_larger_than_the_buffer() -> None:
    with pytest.raises(ValueError, match="cannot sample 6"):
        filled(5).sample(6, np.random.default_rng(0))
