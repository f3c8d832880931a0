"""Gymnasium environment for object arrangement, simulated (SPEC section 3.1)."""

from __future__ import annotations

from typing import Any

import numpy as np

from lagrseq.envs.grid_base import GridEnv
from lagrseq.tasks.arrangement import object_arrangement


class ObjectArrangementEnv(GridEnv):
    """Drop objects on an empty 5 x 5 table grid, at cells drawn at random, until they form a hidden
    target arrangement.

    ## Description
    The table starts empty. At every step a cell is drawn uniformly at random and the agent decides
    whether to drop an object there. The target is the released code's diamond (8 objects) or
    another shape of the library scaled to 5 x 5 (``target``). The pattern is the LaGR-SEQ paper's
    object-arrangement task (simulated: no robot).

    ## Action Space
    ``Discrete(52)``: 1 drops an object on the drawn cell, 0 does nothing (the primary agent's
    ``agent_action_space``, ``Discrete(2)``); ``2 + 2 * k + a`` does the same on cell ``k``
    instead (pi_LLM's action naming its cell).

    ## Observation Space
    ``Box(0, [4, 4, 1, 1, ..., 1], (28,), float32)``: the drawn cell's row and column, whether it
    holds an object, then the 25 cells row by row.

    ## Reward
    ``E(T') - E(T) + b`` with E the fraction of cells equal to the target's (+0.04 per correct
    object) and the bonus b paid when E(T') >= ``goal_threshold`` (1.0: the exact arrangement,
    paper delta = 0.99 on 25 cells; ``guided_goal_threshold`` on pi_LLM's steps (actions naming their cell), default
    the same). A drop is executed only when it is rewarded (paper and code):
    dropping on a cell outside the target, or on an occupied cell, changes nothing and earns 0.
    Objects are never removed, so the table always holds part of the target.

    ## Starting State
    The empty table; a random cell drawn with the env's generator.

    ## Episode End
    Terminated at the goal; truncated after ``horizon`` steps (paper and code: 50).

    ## Information
    ``info["pattern"]``: the table (5 x 5 int8); ``info["cursor"]``: the drawn cell;
    ``info["evaluation"]``: E(T).

    ## Arguments
    ``target``, ``horizon``, ``bonus``, ``goal_threshold``, ``guided_goal_threshold``,
    ``render_mode`` (``"ansi"``).

    ## Version History
    * v0: initial version.
    """

    def __init__(
        self,
        target: str = "diamond",
        horizon: int = 50,
        bonus: float = 1.0,
        goal_threshold: float = 1.0,
        guided_goal_threshold: float | None = None,
        render_mode: str | None = None,
    ) -> None:
        if horizon < 1:
            raise ValueError(f"horizon must be at least 1, got {horizon}")
        task = object_arrangement(target, goal_threshold)
        super().__init__(task, bonus, render_mode, guided_goal_threshold)
        self.horizon = horizon
        self._steps = 0

    def _draw_cell(self) -> tuple[int, int]:
        return int(self.np_random.integers(self.rows)), int(self.np_random.integers(self.cols))

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        self._clear(seed)
        self._steps = 0
        self._cursor = self._draw_cell()
        return self._observe(), self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = self._check(action)
        cursor = self._cursor
        before = self._matches()
        if action == 1 and self._grid[cursor] == 0 and self._target[cursor] == 1:
            self._grid[cursor] = 1  # only rewarded drops are executed
        after = self._matches()
        goal = self._goal(after)
        reward = (after - before) / self._cells + (self.bonus if goal else 0.0)
        self._steps += 1
        self._cursor = self._draw_cell()
        terminated = goal
        truncated = not terminated and self._steps >= self.horizon
        return self._observe(), reward, terminated, truncated, self._info(after)
