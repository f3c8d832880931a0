"""Cube stacking, as registered: the task, its env's dynamics, its mock profiles and the
released code's aliased state index."""

from __future__ import annotations

from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.config import CubeEnvConfig, CubeTaskConfig
from lagrseq.errors import UsageError
from lagrseq.tasks import cube, grid_profiles
from lagrseq.tasks.base import Task, expect


def make_task(config: Any) -> Task:
    return cube.CubeStacking(expect(config.task, CubeTaskConfig, "task").stack_size)  # type: ignore[return-value]


def make_env(config: Any, render_dir: Path | None = None) -> Any:
    """The cube env's dynamics without Gymnasium's interface (``CubeStackingEnv`` is this class
    with it): a run needs nothing more, and importing gymnasium costs about 60 ms of CPU."""
    from lagrseq.tasks.cube_dynamics import CubeStackingDynamics

    task = expect(config.task, CubeTaskConfig, "task")
    env = expect(config.env, CubeEnvConfig, "env")
    return CubeStackingDynamics(
        stack_size=task.stack_size,
        horizon=env.horizon,
        bonus=env.bonus,
        bonus_on=env.bonus_on,
        revert_wrong_cube=env.revert_wrong_cube,
        wrong_cube_reward=env.wrong_cube_reward,
        terminate_on_complete=env.terminate_on_complete,
    )


def profiles() -> tuple[str, ...]:
    return tuple(cube.PROFILES)


def extrapolator(config: Any, profile: str) -> Callable[[str, float, np.random.Generator], str]:
    """The cube's extrapolator or one of its calibrated profiles (``cube.PROFILES``)."""
    if profile in grid_profiles.PROFILES:
        raise UsageError(f"mock profile {profile!r} is calibrated for the grid tasks; cube stacking has: {', '.join(cube.PROFILES)}")
    return cube.profile_extrapolator(cube.CubeStacking(expect(config.task, CubeTaskConfig, "task").stack_size), profile)


def upstream_aliased(task: Any) -> Callable[[Any], Hashable]:
    """``primary.state_index = "upstream-aliased"``: the released cube code's ranking, which
    gives the stacks [], [e], [e,f] and [e,f,g] one shared Q row (SPEC 1.1)."""
    target = expect(task, cube.CubeStacking, "task").target
    return lambda pattern: cube.upstream_state_key(pattern, target)  # type: ignore[no-any-return]
