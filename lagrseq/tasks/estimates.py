"""Tokens of one query per task, estimated as the mock does (about 4 characters a token), from a
logged configuration (JSON data): the frontier's cost of answers that logged no usage. Each
function is a task's registered ``estimated_tokens``; None when the configuration cannot say."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from lagrseq.tasks import cube
from lagrseq.tasks.arrangement import object_arrangement
from lagrseq.tasks.grid import GridTask
from lagrseq.tasks.image import image_completion


def _tokens(prompt: str, answer: int) -> tuple[float, float]:
    return float(max(1, len(prompt) // 4)), float(max(1, answer // 4))


def cube_tokens(config: dict[str, Any]) -> tuple[float, float] | None:
    """The prompt of the empty stack, and an answer listing every cube."""
    try:
        size = int(config.get("task", {}).get("stack_size", 8))
        return _tokens(cube.CubeStacking(size).prompt(()), 4 * size + 2)
    except (TypeError, ValueError, KeyError):
        return None


def _grid_tokens(make: Callable[..., GridTask], config: dict[str, Any]) -> tuple[float, float] | None:
    """The prompt of the empty grid, and an answer the size of a bracketed 0/1 matrix."""
    task = config.get("task", {})
    try:
        grid = make(task.get("target", "x"), float(task.get("goal_threshold", 1.0)), task.get("prompt_matrix", "numpy"))
        prompt = grid.prompt(np.zeros((grid.rows, grid.cols), dtype=np.int8))
    except (TypeError, ValueError, KeyError):
        return None
    return _tokens(prompt, 2 * grid.rows * grid.cols + 2 * grid.rows)


def image_tokens(config: dict[str, Any]) -> tuple[float, float] | None:
    return _grid_tokens(image_completion, config)


def arrangement_tokens(config: dict[str, Any]) -> tuple[float, float] | None:
    return _grid_tokens(object_arrangement, config)
