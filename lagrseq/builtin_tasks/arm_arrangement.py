"""Object arrangement by a UR5e arm, as registered: the task, its env with its robot, the arm
extra it needs and its pictures (the grid parts it shares with the other grid tasks are
:mod:`lagrseq.builtin_tasks.grid`)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from lagrseq.builtin_tasks.grid import pictures
from lagrseq.config import ArmEnvConfig, ArmTaskConfig
from lagrseq.errors import UsageError
from lagrseq.logs import foxglove
from lagrseq.logs.events import View
from lagrseq.tasks.base import Task, expect


def make_task(config: Any) -> Task:
    from lagrseq.tasks.arrangement import arm_arrangement

    task = expect(config.task, ArmTaskConfig, "task")
    return arm_arrangement(task.target, task.goal_threshold, task.prompt_matrix, task.guidance)


def make_env(config: Any, render_dir: Path | None = None) -> Any:
    """The arm-arrangement env with its robot (``env.robot``: sim or remote:HOST:PORT)."""
    import gymnasium as gym

    from lagrseq.envs.arm_arrangement import ArmArrangementEnv

    section = expect(config.env, ArmEnvConfig, "env")
    task = expect(config.task, ArmTaskConfig, "task")
    try:
        env = ArmArrangementEnv(
            target=task.target,
            horizon=section.horizon,
            bonus=section.bonus,
            goal_threshold=task.goal_threshold,
            robot=section.robot,
            robot_timeout_s=section.robot_timeout_s,
            robot_token_file=section.robot_token_file,
            robot_tls_ca=section.robot_tls_ca,
            render_size=(section.view_width, section.view_width * 3 // 4),
        )
    except (ImportError, gym.error.DependencyNotInstalled) as exc:
        raise UsageError(f"arm-arrangement: {exc}") from None
    if render_dir is not None:
        from lagrseq.robot.render import EpisodeRenderer

        EpisodeRenderer(env, Path(render_dir)).attach()
    return env


def missing_dependency(config: Any) -> str:
    """The simulated arm needs pybullet and airo-models, a remote arm grpcio (the ``arm``
    extra)."""
    import importlib.util

    section = expect(config.env, ArmEnvConfig, "env")
    wanted = ("pybullet", "airo_models") if section.robot == "sim" else ("grpc", "google.protobuf")
    absent = [name for name in wanted if importlib.util.find_spec(name.split(".")[0]) is None]
    if absent:
        return f"needs the arm extra ({', '.join(absent)} not installed): pip install 'lagrseq[arm]' (Python <= 3.11)"
    return ""


def view_topics(config: Any) -> dict[str, tuple[str, str, bytes]] | None:
    topics = foxglove.view_topics(grid=True)
    topics.update(foxglove.arm_topics())
    return topics


def views(config: Any, env: Any) -> Callable[[dict[str, Any], int], list[View]]:
    """The grid picture, then the arm's joint state after every step and every
    ``env.view_every`` steps a camera frame (PNG), both read from the env's robot."""
    grid_picture = pictures(foxglove.GRID_TOPIC, foxglove.grid)
    robot = env.unwrapped.robot
    every = expect(config.env, ArmEnvConfig, "env").view_every

    def step_views(info: dict[str, Any], global_step: int) -> list[View]:
        out = grid_picture(info, global_step)
        state = robot.joint_state()
        out.append(View(foxglove.JOINTS_TOPIC, foxglove.joint_state(state.names, state.positions, global_step), global_step))
        if every and global_step % every == 0:
            picture = env.unwrapped.render_png()
            if picture is not None:
                out.append(View(foxglove.ARM_TOPIC, foxglove.compressed_image(picture, global_step), global_step))
        return out

    return step_views
