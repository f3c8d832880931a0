"""Gymnasium environment for cube stacking (SPEC section 1.1)."""

from __future__ import annotations

from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from lagrseq.tasks.cube_dynamics import CubeStackingDynamics


class CubeStackingEnv(CubeStackingDynamics, gym.Env[np.ndarray, np.int64]):
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

    ## Dynamics
    Everything but Gymnasium's interface is ``lagrseq.tasks.cube_dynamics.CubeStackingDynamics``,
    which a run steps directly (without importing Gymnasium).

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
        super().__init__(stack_size, horizon, bonus, bonus_on, revert_wrong_cube, wrong_cube_reward, terminate_on_complete)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} not in {self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(self.n + 1)
        self.observation_space = spaces.MultiDiscrete(np.full(self.n, self.n + 1, dtype=np.int64))

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        gym.Env.reset(self, seed=seed)
        obs, info = self._restart()
        info["action_mask"] = info["action_mask"].copy()
        return obs.copy(), info

    def step(self, action: np.int64 | int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """The dynamics' step, with new arrays (Gymnasium wants a fresh observation every call)."""
        obs, reward, terminated, truncated, info = super().step(action)
        info["action_mask"] = info["action_mask"].copy()
        return obs.copy(), reward, terminated, truncated, info

    def render(self) -> str | None:
        if self.render_mode == "ansi":
            return f"stack (bottom to top): {self.task.render(self._stack)}\n"
        return None
