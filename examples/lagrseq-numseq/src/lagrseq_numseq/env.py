"""The Gymnasium env of ``number-sequence``: write the next number of the sequence.

Action ``n`` writes the number n. The right next number is appended (reward 1 / length, plus
``bonus`` when the sequence is complete, which ends the episode); a wrong one is refused (reward
0). ``info``: ``pattern`` (the numbers written), ``action_mask`` (every number allowed), and
after each step ``log_episode``: ``wrong_numbers``, the numbers refused since the reset (a field
of the task's own in its ``/episode`` log records, declared by ``TaskSpec.episode_fields``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lagrseq_numseq.task import NumberSequence


class NumberSequenceEnv(gym.Env[np.ndarray, int]):
    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, task: NumberSequence, horizon: int = 40, bonus: float = 1.0) -> None:
        self.task = task
        self.horizon = horizon
        self.bonus = bonus
        self.action_space = spaces.Discrete(task.values)  # type: ignore[assignment]
        self.observation_space = spaces.Box(-1, task.values, shape=(task.length,), dtype=np.int64)
        self._written: list[int] = []
        self._steps = 0
        self._wrong = 0

    def _observe(self) -> np.ndarray:
        out = np.full(self.task.length, -1, dtype=np.int64)
        out[: len(self._written)] = self._written
        return out

    def _info(self) -> dict[str, Any]:
        return {"pattern": tuple(self._written), "action_mask": np.ones(self.task.values, dtype=bool)}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._written = []
        self._steps = 0
        self._wrong = 0
        return self._observe(), self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = int(action)
        if not 0 <= action < self.task.values:
            raise ValueError(f"action {action} outside Discrete({self.task.values})")
        reward = 0.0
        if len(self._written) < self.task.length and action == self.task.target[len(self._written)]:
            self._written.append(action)
            reward = 1.0 / self.task.length
        else:
            self._wrong += 1
        self._steps += 1
        terminated = self.task.is_complete(tuple(self._written))
        if terminated:
            reward += self.bonus
        truncated = not terminated and self._steps >= self.horizon
        info = self._info()
        info["log_episode"] = {"wrong_numbers": self._wrong}  # logged in the /episode record
        return self._observe(), reward, terminated, truncated, info
