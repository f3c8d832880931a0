"""The replay buffer: ring overwrite, seeded sampling without replacement."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.agents.replay import Batch, ReplayBuffer


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


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 40), st.integers(1, 12), st.integers(0, 2**32 - 1), st.integers(0, 3))
def test_a_draw_copies_into_stacked_arrays_the_rows_sample_gives(n: int, capacity: int, seed: int, row: int) -> None:
    """A lockstep training call copies a trial's minibatch straight from its buffer (one copy):
    the same draws from the generator as sample, the same values in the same dtypes."""
    buffer = filled(n, capacity)
    size = len(buffer)
    batch_size = 1 + seed % size
    after_sample = np.random.default_rng(seed)
    sampled = buffer.sample(batch_size, after_sample)
    generator = np.random.default_rng(seed)
    draw = buffer.draw(batch_size, generator)
    arrays = {name: np.full((4, *value.shape), -1, dtype=value.dtype) for name, value in zip(Batch._fields, sampled)}
    draw.copy_into(arrays, row)
    for name, value in zip(Batch._fields, sampled, strict=True):
        assert np.array_equal(arrays[name][row], value)
        assert all((arrays[name][other] == -1).all() for other in range(4) if other != row)
    assert all(np.array_equal(x, y) for x, y in zip(draw.batch(), sampled, strict=True))
    assert generator.bit_generator.state == after_sample.bit_generator.state  # the same draws used
