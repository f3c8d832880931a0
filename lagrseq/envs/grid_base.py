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

    Actions (``Discrete(2 + 2 * cells)``): 0 and 1 act on the cursor's cell (the primary agent's
    actions, :attr:`agent_action_space`); ``2 + 2 * k + a`` acts ``a`` on cell ``k`` (row-major)
    instead: pi_LLM's action naming the cell it chose, as the released code's ``LLMgreedy`` takes
    it (SPEC 2.3), its bonus judged with ``guided_goal_threshold`` (:meth:`cell_action` writes
    one). Which cell comes after is the same either way.
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
        self._steered = False  # the current step is pi_LLM's, on a cell it named (see _check)
        self.render_mode = render_mode
        self.rows, self.cols = task.rows, task.cols
        high = np.ones(3 + task.cells, dtype=np.float32)
        high[0], high[1] = self.rows - 1, self.cols - 1
        self.observation_space = spaces.Box(np.zeros_like(high), high, dtype=np.float32)
        self.action_space = spaces.Discrete(2 + 2 * task.cells)  # type: ignore[assignment]  # gymnasium: Space[int64]
        self.agent_action_space = spaces.Discrete(2)
        """The actions at the cursor (0: leave the cell, 1: act on it): what an RL agent chooses from."""
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
        """The step's action at its cell (0 or 1); an action naming a cell moves the cursor
        there for this step and marks the step as pi_LLM's."""
        action = int(action)
        if not 0 <= action < 2 + 2 * self._cells:
            raise ValueError(f"action {action} outside Discrete({2 + 2 * self._cells})")
        if action >= 2:
            self._cursor = divmod((action - 2) // 2, self.cols)
            self._steered = True
        return action % 2

    # ------------------------------------------------------------------ pi_LLM's actions
    def cell_action(self, cell: tuple[int, int], action: int) -> int:
        """The env action doing ``action`` (0 or 1) on ``cell`` instead of the cursor's cell."""
        row, col = int(cell[0]), int(cell[1])
        if not (0 <= row < self.rows and 0 <= col < self.cols) or action not in (0, 1):
            raise ValueError(f"action {action} on cell {cell}: expected 0 or 1 on a cell of the {self.rows}x{self.cols} grid")
        return 2 + 2 * (row * self.cols + col) + int(action)

    def at_cell(self, observation: np.ndarray, info: dict[str, Any], cell: tuple[int, int]) -> tuple[np.ndarray, dict[str, Any]]:
        """``observation`` and ``info`` as seen from ``cell`` instead of the cursor's cell (what
        an action naming ``cell`` acts on; a pure function of its arguments, the env is not
        touched)."""
        row, col = int(cell[0]), int(cell[1])
        seen = np.array(observation, dtype=np.float32, copy=True)
        seen[0], seen[1], seen[2] = row, col, seen[3 + row * self.cols + col]
        return seen, {**info, "cursor": (row, col)}

    def render(self) -> str | None:
        if self.render_mode == "ansi":
            return self.task.render(self._grid) + f"\ncursor {self._cursor}\n"
        return None
