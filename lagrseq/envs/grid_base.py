"""What the two grid environments share: the grid, the cursor and the observation vector."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lagrseq.tasks.grid import GridTask


class GridEnv(gym.Env[np.ndarray, int]):
    """A rows x cols 0/1 grid worked on one cell (the cursor) at a time; subclasses say which cell
    comes next and what action 1 does there.

    Observation: ``[row, col, grid[row, col]] + grid.flatten()`` as float32, the released code's
    state (SPEC 2.1, 3.1); coordinates are raw cell indices (an agent may normalise them with the
    observation space's bounds).
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        task: GridTask,
        bonus: float,
        render_mode: str | None,
        guided_goal_threshold: float | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} not in {self.metadata['render_modes']}")
        self.task = task
        self.bonus = bonus
        self.guided_goal_threshold = (
            task.goal_threshold if guided_goal_threshold is None else guided_goal_threshold
        )
        self._steered = False  # the coming step is pi_LLM's, on a cell it chose (see steer)
        self.render_mode = render_mode
        self.rows, self.cols = task.rows, task.cols
        high = np.ones(3 + task.cells, dtype=np.float32)
        high[0], high[1] = self.rows - 1, self.cols - 1
        self.observation_space = spaces.Box(np.zeros_like(high), high, dtype=np.float32)
        self.action_space = spaces.Discrete(2)  # type: ignore[assignment]  # gymnasium: Space[int64]
        self._grid = np.zeros((self.rows, self.cols), dtype=np.int8)
        self._cursor = (0, 0)
        self._observation = np.zeros(3 + task.cells, dtype=np.float32)
        self._target = task.target
        self._cells = task.cells

    # ------------------------------------------------------------------ helpers
    def _matches(self) -> int:
        return int(np.count_nonzero(self._grid == self._target))

    def _goal(self, matches: int) -> bool:
        """Whether E reaches the goal; a steered step (pi_LLM's own) uses its own threshold.
        Clears the steering: call once per step."""
        threshold = self.guided_goal_threshold if self._steered else self.task.goal_threshold
        self._steered = False
        return matches / self._cells >= threshold

    def _clear(self, seed: int | None) -> None:
        """The start of every episode: seed the env's generator (first call), empty the grid."""
        super().reset(seed=seed)
        self._grid[:] = 0
        self._steered = False

    def _observe(self) -> np.ndarray:
        obs = self._observation
        row, col = self._cursor
        obs[0], obs[1], obs[2] = row, col, self._grid[row, col]
        obs[3:] = self._grid.ravel()
        return obs.copy()

    def _info(self, matches: int | None = None) -> dict[str, Any]:
        matches = self._matches() if matches is None else matches
        return {
            "pattern": self._grid.copy(),
            "cursor": self._cursor,
            "evaluation": matches / self._cells,
        }

    def _check(self, action: int) -> int:
        action = int(action)
        if action not in (0, 1):
            raise ValueError(f"action {action} outside Discrete(2)")
        return action

    # ------------------------------------------------------------------ pi_LLM support
    def steer(self, cell: tuple[int, int]) -> tuple[np.ndarray, dict[str, Any]]:
        """Make the next step pi_LLM's, as the released code takes it (``LLMgreedy``, SPEC 2.3):
        it acts on ``cell`` instead of the scanned or drawn one, and its bonus is judged with
        ``guided_goal_threshold`` (released image code: E > 0.95, while the primary's steps need
        the exact image). Returns the observation and info at ``cell``; which cell comes after
        is unchanged."""
        row, col = int(cell[0]), int(cell[1])
        if not (0 <= row < self.rows and 0 <= col < self.cols):
            raise ValueError(f"cell {cell} outside the {self.rows}x{self.cols} grid")
        self._cursor = (row, col)
        self._steered = True
        return self._observe(), self._info()

    def render(self) -> str | None:
        if self.render_mode == "ansi":
            return self.task.render(self._grid) + f"\ncursor {self._cursor}\n"
        return None
