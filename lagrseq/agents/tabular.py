"""Tabular Q-learning with one row per state key (a hash map: no permutation ranking)."""

from __future__ import annotations

from collections.abc import Hashable

import numpy as np


def epsilon_greedy(
    values: np.ndarray,
    epsilon: float,
    rng: np.random.Generator,
    mask: np.ndarray | None = None,
    invalid: str = "mask",
) -> int:
    """Pick an action: random with probability epsilon, else the first maximum.

    ``mask`` marks valid actions. ``invalid="mask"`` picks only among valid actions;
    ``invalid="resample"`` (released cube code) picks among all actions and, if the pick is
    invalid, redraws uniformly from all actions until it is valid, which equals a uniform draw
    among the valid ones.
    """
    n = values.shape[0]
    if mask is None or invalid == "resample" or mask.all():
        action = int(rng.integers(n)) if rng.random() < epsilon else int(values.argmax())
        if mask is not None and not mask[action]:
            valid = mask.nonzero()[0]  # np.flatnonzero without its wrappers: masks are 1-D
            action = int(valid[rng.integers(valid.size)])
        return action
    valid = mask.nonzero()[0]
    if rng.random() < epsilon:
        return int(valid[rng.integers(valid.size)])
    return int(valid[values[valid].argmax()])


class TabularQ:
    """Q-learning: Q[s,a] += lr * (r + discount * max_a' Q[s',a'] * (1 - terminal) - Q[s,a]).

    Rows are created on first use and start at 0; keys are any hashable state identifiers, so every
    distinct state has its own row unless the caller's key function merges states on purpose.
    """

    def __init__(self, n_actions: int, learning_rate: float, discount: float) -> None:
        self.n_actions = n_actions
        self.learning_rate = learning_rate
        self.discount = discount
        self.table: dict[Hashable, np.ndarray] = {}

    def values(self, key: Hashable) -> np.ndarray:
        row = self.table.get(key)
        if row is None:
            row = self.table[key] = np.zeros(self.n_actions)
        return row

    def act(
        self,
        key: Hashable,
        epsilon: float,
        rng: np.random.Generator,
        mask: np.ndarray | None = None,
        invalid: str = "mask",
    ) -> int:
        return epsilon_greedy(self.values(key), epsilon, rng, mask, invalid)

    def update(
        self, key: Hashable, action: int, reward: float, next_key: Hashable, terminal: bool
    ) -> float:
        """One Q-learning step; returns the TD error."""
        row = self.values(key)
        target = reward
        if not terminal:
            following = self.table.get(next_key)
            if following is not None:
                target += self.discount * float(following.max())
        error = target - float(row[action])
        row[action] += self.learning_rate * error
        return error
