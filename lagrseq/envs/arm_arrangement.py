"""Gymnasium environment for object arrangement executed by a robot arm (the paper's UR5e)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from lagrseq.envs.object_arrangement import ObjectArrangementEnv
from lagrseq.robot import PlacementResult, Robot, RobotError
from lagrseq.tasks.base import EPISODE_LOG, STEP_LOG


def make_robot(spec: str | Robot, timeout_s: float = 30.0, token_file: str = "", tls_ca: str = "") -> Robot:
    """``sim`` (a :class:`~lagrseq.robot.sim.SimRobot` in this process), ``remote:HOST:PORT``
    or ``remote+tls:HOST:PORT`` (a :class:`~lagrseq.robot.remote.RemoteRobot`; ``token_file``:
    the service's shared secret, ``tls_ca``: the CA certificate to trust), or a Robot as it is."""
    if not isinstance(spec, str):
        return spec
    if spec == "sim":
        try:
            from lagrseq.robot.sim import import_pybullet

            import_pybullet()
        except ImportError:
            raise gym.error.DependencyNotInstalled(
                "the simulated arm needs pybullet: pip install 'lagrseq[arm]' (Python <= 3.11)"
            ) from None
        from lagrseq.robot.sim import SimRobot

        return SimRobot()
    if spec.startswith(("remote:", "remote+tls:")):
        from lagrseq.robot.remote import RemoteRobot, parse_address

        host, port = parse_address(spec)
        return RemoteRobot(
            host, port, timeout_s=timeout_s, tls=spec.startswith("remote+tls:"), tls_ca=tls_ca or None, token_file=token_file or None,
        )
    raise RobotError(f"robot {spec!r}; expected sim, remote:HOST:PORT or remote+tls:HOST:PORT")


class ArmArrangementEnv(ObjectArrangementEnv):
    """Object arrangement on a real table, by a robot arm: every executed drop is a placement by
    a UR5e (simulated in pybullet, or a real arm behind the robot service), and the table's state
    is read back from the objects, not from the env's own bookkeeping.

    ## Description
    The LaGR-SEQ paper's robot experiment. The table holds a 5 x 5 grid of 5 cm cells; at every
    step a cell is drawn uniformly at random and the agent decides whether to put an object
    there. An executed drop is ``robot.place(row, col)``: pick a cube at the pickup spot, carry it
    over the cell (grid -> table -> base frame through one static transform), descend, release.
    The occupancy is then ``robot.observe()``, measured from the objects' poses: a placement
    that fails (the cell out of reach, the cube outside its cell or tipped over) shows in the
    state as what really happened, and in ``info["placement"]``.

    ## Action Space
    ``Discrete(52)``: 1 puts an object on the drawn cell, 0 does nothing (the primary agent's
    ``agent_action_space``, ``Discrete(2)``); ``2 + 2 * k + a`` does the same on cell ``k`` instead
    (pi_LLM's action naming its cell).

    ## Observation Space
    ``Box(0, [4, 4, 1, 1, ..., 1], (28,), float32)``: the drawn cell's row and column, whether it
    holds an object, then the 25 cells row by row (as ``lagrseq/ObjectArrangement-v0``).

    ## Reward
    As ``lagrseq/ObjectArrangement-v0`` (``E(T') - E(T) + b``, E the fraction of cells equal to
    the target), with T' the observed table. A drop is executed only when it is rewarded (paper
    and code: a drop on a cell outside the target or on an occupied cell moves nothing and
    earns 0), so the arm never places a cube where the target has none.

    ## Starting State
    An empty table (``robot.clear()`` at every reset), the arm at home; a random cell drawn with
    the env's generator.

    ## Episode End
    Terminated at the goal; truncated after ``horizon`` steps (paper and code: 50).

    ## Information
    As ``lagrseq/ObjectArrangement-v0`` (``pattern``: the observed table), plus
    ``info["placement"]``: None when nothing was placed, else the placement's result as a dict
    (``row``, ``col``, ``outcome`` in ``placed | unreachable | outside-cell | tipped |
    not-resting``, ``ok``, ``offset_mm``, ``tilt_deg``, ``height_mm``, ``landed_row``,
    ``landed_col``, ``sim_steps``).

    ## Arguments
    ``target``, ``horizon``, ``bonus``, ``goal_threshold``, ``guided_goal_threshold``, ``robot``
    (``"sim"``, ``"remote:HOST:PORT"`` or a :class:`~lagrseq.robot.Robot`), ``robot_timeout_s``,
    ``render_mode`` (``"rgb_array"``: the robot's camera, ``"ansi"``).

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 4}

    def __init__(
        self,
        target: str = "diamond",
        horizon: int = 50,
        bonus: float = 1.0,
        goal_threshold: float = 1.0,
        guided_goal_threshold: float | None = None,
        robot: str | Robot = "sim",
        robot_timeout_s: float = 30.0,
        robot_token_file: str = "",
        robot_tls_ca: str = "",
        render_mode: str | None = None,
        render_size: tuple[int, int] = (320, 240),
    ) -> None:
        super().__init__(target, horizon, bonus, goal_threshold, guided_goal_threshold, None)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} not in {self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.task.name = "arm-arrangement"
        self.render_size = render_size
        self.robot: Robot = make_robot(robot, robot_timeout_s, robot_token_file, robot_tls_ca)
        if (self.robot.rows, self.robot.cols) != (self.rows, self.cols):
            raise RobotError(f"the robot's grid is {self.robot.rows}x{self.robot.cols}; this task needs {self.rows}x{self.cols}")
        self._placement: PlacementResult | None = None
        self._placements = self._failed = 0
        self.recorder: Callable[[str], None] | None = None
        """Called after every reset ("reset") and step ("step"), and at close ("close"): the
        ``--render`` frame writer (:class:`lagrseq.robot.render.EpisodeRenderer`)."""

    def _read_table(self) -> None:
        observed = np.asarray(self.robot.observe(), dtype=np.int8)
        if observed.shape != (self.rows, self.cols):
            raise RobotError(f"the robot observed a {observed.shape} grid; expected {self.rows}x{self.cols}")
        self._grid[:] = (observed != 0)

    def _info(self, matches: int | None = None) -> dict[str, Any]:
        info = super()._info(matches)
        placement = None if self._placement is None else self._placement.to_dict()
        info["placement"] = placement
        if placement is not None:  # the step's /transition record says what the robot did
            info[STEP_LOG] = {"placement": placement}
        info[EPISODE_LOG] = {"placements": self._placements, "failed_placements": self._failed}
        return info

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        self._clear(seed)
        self.robot.clear()
        self._read_table()
        self._placement = None
        self._placements = self._failed = 0
        self._steps = 0
        self._cursor = self._draw_cell()
        if self.recorder is not None:
            self.recorder("reset")
        return self._observe(), self._info()

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = self._check(action)
        cursor = self._cursor
        before = self._matches()
        self._placement = None
        if action == 1 and self._grid[cursor] == 0 and self._target[cursor] == 1:
            self._placement = self.robot.place(*cursor)  # only rewarded drops are executed
            self._placements += 1
            self._failed += not self._placement.ok
            self._read_table()
        after = self._matches()
        goal = self._goal(after)
        reward = (after - before) / self._cells + (self.bonus if goal else 0.0)
        self._steps += 1
        self._cursor = self._draw_cell()
        terminated = goal
        truncated = not terminated and self._steps >= self.horizon
        if self.recorder is not None:
            self.recorder("step")
        return self._observe(), reward, terminated, truncated, self._info(after)

    def render(self) -> Any:
        if self.render_mode == "rgb_array":
            return self.robot.render(*self.render_size)
        return super().render()

    def render_png(self) -> bytes | None:
        """The robot's camera frame as PNG bytes (None: the robot has no camera)."""
        from lagrseq.robot.render import png_bytes

        rgb = self.robot.render(*self.render_size)
        return None if rgb is None else png_bytes(rgb)

    def close(self) -> None:
        if getattr(self, "recorder", None) is not None:
            self.recorder("close")  # type: ignore[misc]
            self.recorder = None
        robot = getattr(self, "robot", None)
        if robot is not None:
            robot.close()
        super().close()
