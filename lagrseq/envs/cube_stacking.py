"""Gymnasium environment for cube stacking (SPEC section 1.1)."""

from __future__ import annotations

from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lagrseq.tasks.cube import CubeStacking


class CubeStackingEnv(gym.Env[np.ndarray, np.int64]):
    """Stack cubes in the order of a hidden target pattern.

    ## Description
    A table holds N cubes (N = 5, 8 or 11) of two colours and several edge lengths; the target
    stack (bottom to top) is in decreasing edge length. Each step adds a cube on top of the
    stack or removes the top cube. The pattern is the LaGR-SEQ paper's cube-stacking task.

    ## Action Space
    ``Discrete(N + 1)``: 0 removes the top cube (a no-op on an empty stack); k in 1..N adds cube
    k - 1. Adding a cube that is already stacked, or adding to a full stack, is a no-op.
    ``info["action_mask"]`` marks valid actions: "remove" always, "add" unless the cube is
    already stacked or the stack is full.

    ## Observation Space
    ``MultiDiscrete([N + 1] * N)``: the stack from bottom to top, cube ids 0..N-1, padded with N.

    ## Reward
    ``E(s') - E(s) + b`` with E(s) = len(s) * (number of cubes in their target position) and the
    bonus b paid when s' is the complete target (``bonus_on="next-state"``) or, as in the released
    code, when s or s' is (``"either-state"``). With ``revert_wrong_cube`` a wrong top cube is
    taken off again; its reward is 0 (``wrong_cube_reward="zero"``) or, as in the released code,
    computed on the wrong stack before the revert (``"pre-revert"``: +L on a prefix of length L).

    ## Starting State
    The empty stack.

    ## Episode End
    Terminated when the stack is complete if ``terminate_on_complete``; truncated after
    ``horizon`` steps.

    ## Information
    ``info["pattern"]``: the stack as a tuple of ids; ``info["pre_revert_pattern"]``: s' before a
    wrong cube was taken off; ``info["evaluation"]``: E(s').

    ## Arguments
    ``stack_size``, ``horizon``, ``bonus``, ``bonus_on``, ``revert_wrong_cube``,
    ``wrong_cube_reward``, ``terminate_on_complete``, ``render_mode`` (``"ansi"``).

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        stack_size: int = 8,
        horizon: int = 100,
        bonus: float = 1.0,
        bonus_on: Literal["next-state", "either-state"] = "next-state",
        revert_wrong_cube: bool = True,
        wrong_cube_reward: Literal["pre-revert", "zero"] = "zero",
        terminate_on_complete: bool = True,
        render_mode: str | None = None,
    ) -> None:
        self.task = CubeStacking(stack_size)
        self.n = stack_size
        self.horizon = horizon
        self.bonus = bonus
        self.bonus_on = bonus_on
        self.revert_wrong_cube = revert_wrong_cube
        self.wrong_cube_reward = wrong_cube_reward
        self.terminate_on_complete = terminate_on_complete
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} not in {self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(self.n + 1)
        self.observation_space = spaces.MultiDiscrete(np.full(self.n, self.n + 1, dtype=np.int64))
        self._target = self.task.target
        self._stack: tuple[int, ...] = ()
        self._steps = 0
        self._cache: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray, int]] = {}

    # ------------------------------------------------------------------ helpers
    def _views(self, stack: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, int]:
        """The observation, action mask and E(s) of ``stack``, made once per distinct stack (a
        trial visits a few dozen stacks, 5,000 times); callers hand out copies, since Gymnasium
        wants new arrays from every call."""
        views = self._cache.get(stack)
        if views is None:
            obs = np.full(self.n, self.n, dtype=np.int64)
            obs[: len(stack)] = stack
            mask = np.zeros(self.n + 1, dtype=np.int8)
            mask[0] = 1
            if len(stack) < self.n:
                mask[1:] = 1
                for cube in stack:
                    mask[cube + 1] = 0
            obs.flags.writeable = mask.flags.writeable = False
            views = self._cache[stack] = (obs, mask, self._evaluation(stack))
        return views

    def _observation(self) -> np.ndarray:
        return self._views(self._stack)[0].copy()

    def action_mask(self) -> np.ndarray:
        """Valid actions as the released code judges them: "remove" always (a no-op on the empty
        stack), "add" unless the cube is already stacked or the stack is full."""
        return self._views(self._stack)[1].copy()

    def _evaluation(self, stack: tuple[int, ...]) -> int:
        target = self._target
        correct = 0
        for a, b in zip(stack, target):
            if a == b:
                correct += 1
        return len(stack) * correct

    def _info(self, pre_revert: tuple[int, ...] | None = None) -> dict[str, Any]:
        _obs, mask, evaluation = self._views(self._stack)
        return {
            "pattern": self._stack,
            "pre_revert_pattern": self._stack if pre_revert is None else pre_revert,
            "evaluation": evaluation,
            "action_mask": mask.copy(),
        }

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._stack = ()
        self._steps = 0
        return self._observation(), self._info()

    def step(self, action: np.int64 | int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = int(action)
        if not 0 <= action <= self.n:
            raise ValueError(f"action {action} outside Discrete({self.n + 1})")
        before = self._stack
        if action == 0:
            after = before[:-1]
        elif len(before) < self.n and (action - 1) not in before:
            after = before + (action - 1,)
        else:
            after = before  # no-op: cube already stacked, or the stack is full
        target = self._target
        cache = self._cache  # each stack's views, looked up once per step and stack
        views = cache.get(after) or self._views(after)
        views_before = views if after is before else (cache.get(before) or self._views(before))
        reward = float(views[2] - views_before[2])
        if after == target or (self.bonus_on == "either-state" and before == target):
            reward += self.bonus
        pre_revert = after
        if self.revert_wrong_cube and len(after) > len(before) and after[-1] != target[len(after) - 1]:
            after, views = before, views_before  # the wrong cube is taken off again
            if self.wrong_cube_reward == "zero":
                reward = 0.0
        self._stack = after
        self._steps += 1
        terminated = bool(self.terminate_on_complete and after == target)
        truncated = bool(not terminated and self._steps >= self.horizon)
        obs, mask, evaluation = views
        info = {"pattern": after, "pre_revert_pattern": pre_revert, "evaluation": evaluation, "action_mask": mask.copy()}
        return obs.copy(), reward, terminated, truncated, info

    def render(self) -> str | None:
        if self.render_mode == "ansi":
            return f"stack (bottom to top): {self.task.render(self._stack)}\n"
        return None
