"""Object arrangement, as registered: the task and its env (its picture and the rest it shares
with the other grid tasks are :mod:`lagrseq.builtin_tasks.grid`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lagrseq.config import ArrangementEnvConfig, ArrangementTaskConfig
from lagrseq.tasks.base import Task, expect


def make_task(config: Any) -> Task:
    from lagrseq.tasks.arrangement import object_arrangement

    task = expect(config.task, ArrangementTaskConfig, "task")
    return object_arrangement(task.target, task.goal_threshold, task.prompt_matrix, task.guidance)


def make_env(config: Any, render_dir: Path | None = None) -> Any:
    from lagrseq.envs.object_arrangement import ObjectArrangementEnv

    table = expect(config.env, ArrangementEnvConfig, "env")
    arrangement = expect(config.task, ArrangementTaskConfig, "task")
    return ObjectArrangementEnv(
        target=arrangement.target,
        horizon=table.horizon,
        bonus=table.bonus,
        goal_threshold=arrangement.goal_threshold,
    )
