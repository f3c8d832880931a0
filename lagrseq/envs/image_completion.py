"""Gymnasium environment for image completion (SPEC section 2.1)."""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from lagrseq.envs.grid_base import GridEnv
from lagrseq.tasks.image import image_completion


class ImageCompletionEnv(GridEnv):
    """Turn pixels of a blank 10 x 10 image on or off, one scanned pixel at a time, until the image
    shows a hidden target shape.

    ## Description
    The image starts all black (0). Each episode scans the pixels in raster order (row by row,
    left to right) ``scans`` times; at every step the agent decides whether to flip the scanned
    pixel. The target is the released code's X (20 white pixels) or another shape of the library
    (``target``). The pattern is the LaGR-SEQ paper's image-completion task.

    ## Action Space
    ``Discrete(202)``: 1 flips the scanned pixel (0 -> 1 or 1 -> 0), 0 leaves it (the primary
    agent's ``agent_action_space``, ``Discrete(2)``); ``2 + 2 * k + a`` does the same to pixel
    ``k`` instead (pi_LLM's action naming its pixel); the scan goes on from where it was.

    ## Observation Space
    ``Box(0, [9, 9, 1, 1, ..., 1], (103,), float32)``: the scanned pixel's row and column, its
    value, then the 100 pixels row by row.

    ## Reward
    ``E(I') - E(I) + b`` with E the fraction of pixels equal to the target's (so +-0.01 per pixel)
    and the bonus b paid when E(I') >= ``goal_threshold`` (1.0: the exact target; the paper pays it
    for E > delta = 0.95, i.e. 0.96); on pi_LLM's steps (an action naming its cell) the threshold is
    ``guided_goal_threshold`` (default: the same). With ``block_wrong_flips`` (released code) turning on a pixel
    that is black in the target is undone and earns 0 (no bonus either: the released code judges
    the step on the wrong image), so the image is always part of the target; turning a pixel off
    is always done.

    ## Starting State
    The black image; the scan at pixel (0, 0).

    ## Episode End
    Reaching the goal terminates the episode (``goal_ends="episode"``) or, as in the released code,
    only ends the current scan (``"scan"``): the next scan starts at (0, 0) on the same image, so a
    complete image earns the bonus again at the next step. Truncated after ``scans`` scans
    (H = 500 steps for 5 full scans).

    ## Information
    ``info["pattern"]``: the image (10 x 10 int8); ``info["cursor"]``: the scanned pixel;
    ``info["evaluation"]``: E(I).

    ## Arguments
    ``target``, ``scans``, ``bonus``, ``goal_threshold``, ``goal_ends``, ``block_wrong_flips``,
    ``guided_goal_threshold``, ``render_mode`` (``"ansi"``).

    ## Version History
    * v0: initial version.
    """

    def __init__(
        self,
        target: str = "x",
        scans: int = 5,
        bonus: float = 1.0,
        goal_threshold: float = 0.96,
        goal_ends: Literal["episode", "scan"] = "episode",
        block_wrong_flips: bool = True,
        guided_goal_threshold: float | None = None,
        render_mode: str | None = None,
    ) -> None:
        if goal_ends not in ("episode", "scan"):
            raise ValueError(f"goal_ends {goal_ends!r}; expected 'episode' or 'scan'")
        if scans < 1:
            raise ValueError(f"scans must be at least 1, got {scans}")
        task = image_completion(target, goal_threshold)
        super().__init__(task, bonus, render_mode, guided_goal_threshold)
        self.scans = scans
        self.goal_ends = goal_ends
        self.block_wrong_flips = block_wrong_flips
        self._scan = 0
        self._position = 0  # index of the scanned pixel within the scan

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        self._clear(seed)
        self._scan = 0
        self._position = 0
        self._cursor = (0, 0)
        return self._observe(), self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = self._check(action)
        grid, target, cursor = self._grid, self._target, self._cursor
        before = after = self._matches()  # counted once a step: a flip changes one cell's match
        blocked = False
        if action == 1:
            if self.block_wrong_flips and grid[cursor] == 0 and target[cursor] == 0:
                blocked = True  # released code: a wrong pixel turned on is undone, reward 0
            else:
                grid[cursor] = 1 - grid[cursor]
                after += 1 if grid[cursor] == target[cursor] else -1
        goal = self._goal(after) and not blocked
        reward = 0.0 if blocked else (after - before) / self._cells + (self.bonus if goal else 0.0)

        self._position += 1
        if self._position == self._cells or (goal and self.goal_ends == "scan"):
            self._scan += 1
            self._position = 0
        self._cursor = divmod(self._position, self.cols)
        terminated = goal and self.goal_ends == "episode"
        truncated = not terminated and self._scan >= self.scans
        return self._observe(), reward, terminated, truncated, self._info(after)
