"""Image completion, as registered: the task, its env and its picture (the grid parts it shares
with the other grid tasks are :mod:`lagrseq.builtin_tasks.grid`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from lagrseq.builtin_tasks.grid import pictures
from lagrseq.config import ImageEnvConfig, ImageTaskConfig
from lagrseq.logs import foxglove
from lagrseq.logs.events import View
from lagrseq.tasks.base import Task, expect


def make_task(config: Any) -> Task:
    from lagrseq.tasks.image import image_completion

    task = expect(config.task, ImageTaskConfig, "task")
    return image_completion(task.target, task.goal_threshold, task.prompt_matrix, task.guidance)


def make_env(config: Any, render_dir: Path | None = None) -> Any:
    from lagrseq.envs.image_completion import ImageCompletionEnv

    task = expect(config.task, ImageTaskConfig, "task")
    image = expect(config.env, ImageEnvConfig, "env")
    return ImageCompletionEnv(
        target=task.target,
        scans=image.scans,
        bonus=image.bonus,
        goal_threshold=task.goal_threshold,
        goal_ends=image.goal_ends,
        block_wrong_flips=image.block_wrong_flips,
        guided_goal_threshold=image.guided_goal_threshold,
    )


def view_topics(config: Any) -> dict[str, tuple[str, str, bytes]] | None:
    return foxglove.view_topics(image=True)


def views(config: Any, env: Any) -> Callable[[dict[str, Any], int], list[View]]:
    return pictures(foxglove.IMAGE_TOPIC, foxglove.RawImages())
