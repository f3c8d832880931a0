"""The cube-stacking environment's dynamics without Gymnasium: what a run steps.

:class:`CubeStackingDynamics` holds everything ``lagrseq.envs.cube_stacking.CubeStackingEnv``
does when it resets and steps: the stack, the reward, the revert of a wrong cube, the ends of an
episode, the observation, the action mask and the info. The Gymnasium env is this class with
Gymnasium's interface added (its spaces, its seeding, ``render``); a trial builds this class
itself, because importing ``gymnasium`` costs about 60 ms of CPU, a tenth of a whole cube run of
10 trials, and the run uses nothing of it (the cube is deterministic: nothing is drawn from the
env's seed). ``tests/envs/test_cube_env.py`` checks both step alike on random action sequences.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from lagrseq.tasks.cube import CubeStacking


class CubeStackingDynamics:
    """Stack cubes in the order of a hidden target pattern; see ``CubeStackingEnv`` for the
    actions, observations, rewards and ends of an episode. ``reset``/``step``/``close`` take and
    give what Gymnasium's do, except that the observation and ``info["action_mask"]`` are each
    stack's one read-only array (writing into one raises), not a fresh copy per call: a run only
    reads them. ``CubeStackingEnv`` hands out copies, as Gymnasium's checker wants."""

    def __init__(
        self,
        stack_size: int = 8,
        horizon: int = 100,
        bonus: float = 1.0,
        bonus_on: Literal["next-state", "either-state"] = "next-state",
        revert_wrong_cube: bool = True,
        wrong_cube_reward: Literal["pre-revert", "zero"] = "zero",
        terminate_on_complete: bool = True,
    ) -> None:
        self.task = CubeStacking(stack_size)
        self.n = stack_size
        self.horizon = horizon
        self.bonus = bonus
        self.bonus_on = bonus_on
        self.revert_wrong_cube = revert_wrong_cube
        self.wrong_cube_reward = wrong_cube_reward
        self.terminate_on_complete = terminate_on_complete
        self._target = self.task.target
        self._stack: tuple[int, ...] = ()
        self._steps = 0
        self._cache: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray, int]] = {}
        self._moves: dict[tuple[tuple[int, ...], Any], tuple[Any, ...]] = {}
        """(stack, action) -> what the step does, but for the step count: the dynamics are
        deterministic, and a trial makes the same few hundred moves 5,000 times."""

    # ------------------------------------------------------------------ helpers
    def _views(self, stack: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, int]:
        """The observation, action mask and E(s) of ``stack``, made once per distinct stack (a
        trial visits a few dozen stacks, 5,000 times), read-only."""
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

    def _restart(self) -> tuple[np.ndarray, dict[str, Any]]:
        self._stack = ()
        self._steps = 0
        obs, mask, evaluation = self._views(self._stack)
        return obs, {"pattern": self._stack, "pre_revert_pattern": self._stack, "evaluation": evaluation, "action_mask": mask}

    # ------------------------------------------------------------------ the env's interface
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """The empty stack (``seed``: accepted and unused, nothing here is random)."""
        return self._restart()

    def step(self, action: np.int64 | int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        key = (self._stack, action)
        try:
            move = self._moves.get(key)  # a numpy integer finds its int's entry
        except TypeError:  # an unhashable action (a 0-d array): worked out every time
            move = self._move(action)
        if move is None:
            move = self._moves[key] = self._move(action)
        after, pre_revert, reward, terminated, obs, mask, evaluation = move
        self._stack = after
        self._steps += 1
        truncated = not terminated and self._steps >= self.horizon
        info = {"pattern": after, "pre_revert_pattern": pre_revert, "evaluation": evaluation, "action_mask": mask}
        return obs, reward, terminated, truncated, info

    def _move(self, action: np.int64 | int) -> tuple[Any, ...]:
        """What ``action`` does from the current stack: the stack after it, the stack before a
        wrong cube's revert, the reward, whether the episode ends there, and the views after."""
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
        terminated = bool(self.terminate_on_complete and after == target)
        return (after, pre_revert, reward, terminated, *views)

    def close(self) -> None:
        """Nothing to release."""
