"""Experience replay: a ring buffer of transitions in preallocated numpy arrays (no torch here)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Batch(NamedTuple):
    """A minibatch of transitions, one row per transition."""

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_observations: np.ndarray
    terminals: np.ndarray


class Draw:
    """The rows of a minibatch drawn from a buffer, not yet copied: a lockstep training call
    copies them straight into the arrays it stacks the trials' minibatches in
    (:meth:`copy_into`), one copy instead of two. The buffer must not change before it is
    used (a trial waits for its training call)."""

    __slots__ = ("buffer", "index")

    def __init__(self, buffer: ReplayBuffer, index: np.ndarray) -> None:
        self.buffer = buffer
        self.index = index

    def batch(self) -> Batch:
        """The minibatch as arrays of its own."""
        buffer, index = self.buffer, self.index
        return Batch(
            buffer.observations[index],
            buffer.actions[index],
            buffer.rewards[index],
            buffer.next_observations[index],
            buffer.terminals[index],
        )

    def copy_into(self, arrays: dict[str, np.ndarray], row: int) -> None:
        """Row ``row`` of each of ``arrays`` (keyed by :class:`Batch` field) = that field of
        the minibatch: the values :meth:`batch` gives."""
        buffer, index = self.buffer, self.index
        for name, array in arrays.items():
            getattr(buffer, name).take(index, 0, array[row], "clip")  # positional: the cheap call


class ReplayBuffer:
    """The last ``capacity`` transitions (the oldest is overwritten first, like a bounded deque).

    Observations are stored as float32 rows of width ``observation_size``; sampling draws a
    minibatch without replacement (as ``random.sample`` does in the released code) from the
    generator it is given, so the draws are reproducible and separate from the agent's own.
    """

    def __init__(self, capacity: int, observation_size: int) -> None:
        if capacity < 1:
            raise ValueError(f"replay capacity must be at least 1, got {capacity}")
        self.capacity = capacity
        self.observations = np.zeros((capacity, observation_size), dtype=np.float32)
        self.next_observations = np.zeros((capacity, observation_size), dtype=np.float32)
        self.actions = np.zeros(capacity, dtype=np.int64)
        self.rewards = np.zeros(capacity, dtype=np.float32)
        self.terminals = np.zeros(capacity, dtype=np.float32)
        self.size = 0
        self._next = 0

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        observation: np.ndarray,
        action: int,
        reward: float,
        next_observation: np.ndarray,
        terminal: bool,
    ) -> None:
        i = self._next
        self.observations[i] = observation
        self.actions[i] = action
        self.rewards[i] = reward
        self.next_observations[i] = next_observation
        self.terminals[i] = terminal
        self._next = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """``batch_size`` distinct stored transitions, drawn uniformly with ``rng``."""
        if batch_size > self.size:
            raise ValueError(f"cannot sample {batch_size} transitions from {self.size}")
        return self.draw(batch_size, rng).batch()

    def draw(self, batch_size: int, rng: np.random.Generator) -> Draw:
        """The rows :meth:`sample` takes (the same draws from ``rng``), not yet copied."""
        if batch_size > self.size:
            raise ValueError(f"cannot sample {batch_size} transitions from {self.size}")
        return Draw(self, rng.choice(self.size, size=batch_size, replace=False))
