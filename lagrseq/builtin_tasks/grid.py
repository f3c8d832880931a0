"""What the grid tasks (image completion, object arrangement, the arm) register alike: the grid
mock profiles and extrapolator, the steering guide, the calibrated miss answer and the grid
picture."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from lagrseq.errors import UsageError
from lagrseq.logs import foxglove
from lagrseq.logs.events import View
from lagrseq.registry import TASKS
from lagrseq.tasks import grid, grid_profiles
from lagrseq.tasks.base import Parsed, Task


def _task(config: Any) -> Task:
    """The task of ``config`` (its registered ``make_task``)."""
    return TASKS.get(config.task.name).make_task(config)  # type: ignore[no-any-return]


def profiles() -> tuple[str, ...]:
    return tuple(grid_profiles.PROFILES)


def extrapolator(config: Any, profile: str) -> Callable[[str, float, np.random.Generator], str]:
    """The grid extrapolator or one of the grid profiles (``grid_profiles.PROFILES``)."""
    if profile in grid_profiles.PROFILES:
        task = _task(config)
        if isinstance(task, grid.GridTask):
            return grid_profiles.profile_extrapolator(task, profile, config.lagr.threshold)
    if profile != "ideal":
        raise UsageError(
            f"mock profile {profile!r} is calibrated for cube stacking only; "
            f"{config.task.name} has the ideal mock (--provider mock) and: {', '.join(grid_profiles.PROFILES)}"
        )
    return grid.extrapolate


def steering_guide(config: Any, task: Any, env: Any) -> Any:
    """The released grid code's pi_LLM picks its own cell (the solution's next missing one)
    instead of the scanned or drawn cell: its action names that cell (the grid envs' cell
    actions, judged by ``guided_goal_threshold``) and is the task's guidance there; the step
    goes through ``env.step`` like any other."""
    from lagrseq.loop.experiment import Guided

    grid_env = env.unwrapped

    def guide(solution: Any, observation: Any, info: dict[str, Any]) -> Guided | None:
        pattern = info["pattern"]
        cell = task.guided_cell(pattern, solution, info.get("cursor"))
        if cell is None:
            action = task.guidance(pattern, solution, info.get("cursor"))
            return None if action is None else Guided(action, action, observation, info)
        action = task.guidance(pattern, solution, cell)
        if action is None:
            return None
        observation, info = grid_env.at_cell(observation, info, cell)
        return Guided(action, grid_env.cell_action(cell, action), observation, info)

    return guide


def miss_calibration(config: Any) -> Any:
    """A grid task's calibrated miss answer: the kind of a prompt is the number of cells its
    partial pattern shows, in the bins of :data:`lagrseq.tasks.grid_profiles.SHOWN_BINS`; the
    right answer is the target, a wrong one as :func:`lagrseq.tasks.grid_profiles.wrong_answer`."""
    from lagrseq.llm.calibrated import MissCalibration
    from lagrseq.tasks import shapes

    task = _task(config)
    if not isinstance(task, grid.GridTask):
        raise UsageError(f"--on-miss calibrated: task {config.task.name} is not a grid task")
    edges = grid_profiles.SHOWN_BINS.get(config.task.name)
    if edges is None:
        raise UsageError(f"--on-miss calibrated: task {config.task.name} has no bins of cells shown (grid_profiles.SHOWN_BINS)")
    labels = grid_profiles.shown_labels(edges)
    threshold = config.lagr.threshold
    library = shapes.library(task.rows, task.cols)

    def partial_of(prompt: str) -> np.ndarray:
        try:
            partial = grid.partial_grid(prompt)
        except (ValueError, IndexError) as exc:
            raise ValueError(f"no {task.rows}x{task.cols} partial grid in the prompt: {exc}") from None
        if partial.shape != task.target.shape:
            raise ValueError(f"the prompt's grid is {partial.shape}, the task's {task.target.shape}")
        return partial

    def accepted(text: str) -> bool:
        parsed: Parsed = task.parse(text)
        return bool(parsed.ok and parsed.solution is not None and task.evaluate(parsed.solution) >= threshold)

    return MissCalibration(
        task=config.task.name,
        kinds=labels,
        kind=lambda prompt: labels[grid_profiles.shown_bin(partial_of(prompt), edges)],
        accepted=accepted,
        right=lambda prompt: grid.format_comma(task.target),
        wrong=lambda prompt: grid.format_comma(grid_profiles.wrong_answer(task, partial_of(prompt), threshold, library)),
        about=f"cells shown in the partial pattern, bins {', '.join(labels)}",
    )


def view_topics(config: Any) -> dict[str, tuple[str, str, bytes]] | None:
    """The grid picture's topic."""
    return foxglove.view_topics(grid=True)


def pictures(topic: str, picture: Callable[[Any, int], dict[str, Any]]) -> Callable[[dict[str, Any], int], list[View]]:
    """The step's pattern drawn by ``picture`` on ``topic``."""
    return lambda info, global_step: [View(topic, picture(info["pattern"], global_step), global_step)]


def views(config: Any, env: Any) -> Callable[[dict[str, Any], int], list[View]]:
    """The grid picture after every step."""
    return pictures(foxglove.GRID_TOPIC, foxglove.grid)
