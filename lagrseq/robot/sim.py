"""A simulated UR5e placing cubes on a 5 x 5 table grid: pybullet, DIRECT mode, in process.

The arm is the paper's (a UR5e: the URDF shipped in ``airo-models``, whose forward kinematics
match UR's published DH table), with a suction-style grasp: a fixed constraint between the tool
flange (``tool0``) and the cube. One placement (``../shared/ARM_NOTES.md``, measured there):

1. a new cube appears at the pickup spot, the arm is put over it and the grasp closes
   (teleported: no physics steps);
2. the arm is put at the hover pose 10 cm above the target cell, cube in hand (teleported);
3. the final 10 cm descent is simulated along cached 1 cm IK waypoints at 0.25 m/s (position
   control with a feed-forward velocity), the arm settles, the grasp opens 2 mm above the table,
   the cube settles;
4. the arm is put back at the hover pose (teleported), and the cube's resting pose is measured:
   its cell through the static transforms, its offset from the cell centre, its tilt.

What is simulated faithfully: the UR5e's kinematics (IK to 1e-7 m), the contact of the cube with
the table and its neighbours during the descent and release, and so the placement accuracy.
What is not: gripper fingers (the grasp is a constraint), the free-space moves (teleported), and
the UR controller's timing (a real placement takes seconds; this one about 120 physics steps).

IK accuracy fix (ARM_NOTES, "Gotchas"): pybullet's null-space IK leaves 2-4 mm of error; one
null-space solve chooses the posture, then the joints are reset to it and the IK is re-solved
without the null-space arguments, seeded from the previous answer, until the residual is below
1e-7 m. Every cell's hover pose and descent waypoints are solved once, when the robot is built.

``clear()`` removes the cubes and sends the arm home; every episode then starts from the same
state whatever happened before, so a run is the same in process and behind ``lagrseq robot serve``.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.robot import JointState, PlacementResult, RobotError
from lagrseq.robot.frames import Workspace

HOME = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
"""Rest pose of the UR5e's six joints (also the IK's null-space rest pose)."""
DOWN = (math.pi, 0.0, 0.0)
"""Euler angles of tool0 pointing down (z out of the flange, as on the UR controller)."""
_MASSLESS = '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'


@contextlib.contextmanager
def _c_output_silenced() -> Iterator[None]:
    """File descriptors 1 and 2 pointed at the null device, C's stdio buffers flushed before they
    are restored: pybullet prints a "build time" banner from C (to stderr, on import), which
    would otherwise land in the middle of a progress bar. Python's own output is flushed first;
    a Python exception raised inside still reaches the terminal (it is printed after)."""
    import ctypes

    sys.stdout.flush()
    sys.stderr.flush()
    saved: list[tuple[int, int]] = []
    try:
        with open(os.devnull, "wb") as null:
            for fd in (1, 2):
                with contextlib.suppress(OSError):  # no such descriptor (a detached process)
                    saved.append((fd, os.dup(fd)))
                    os.dup2(null.fileno(), fd)
        yield
    finally:
        with contextlib.suppress(Exception):
            ctypes.CDLL(None).fflush(None)  # what C buffered goes to the null device too
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


def import_pybullet() -> Any:
    """``import pybullet`` without a line of its own on the terminal (ImportError where it is absent)."""
    loaded = sys.modules.get("pybullet")
    if loaded is not None:  # None: an import that is known to fail, which ``import`` raises again
        return loaded
    with _c_output_silenced():
        import pybullet
    return pybullet


@dataclass
class Timings:
    """Seconds spent so far in each part of the robot's work (``benchmarks/bench_arm.py``)."""

    physics: float = 0.0
    ik: float = 0.0
    render: float = 0.0
    scene: float = 0.0
    placements: int = 0
    steps: int = 0


@dataclass(frozen=True)
class SimSettings:
    """How the simulated placement runs (defaults: ARM_NOTES' measured configuration)."""

    cube_size: float = 0.03
    """Edge of a cube (m). 3 cm leaves 1 cm of slack to each side of a 5 cm cell."""
    cube_mass: float = 0.05
    friction: float = 0.8
    hover: float = 0.10
    """Height of the hover pose above the release pose (m): the simulated descent."""
    release_gap: float = 0.002
    """Height of the cube's bottom above the table when the grasp opens (m)."""
    grasp_gap: float = 0.002
    """Distance from tool0 down to the cube's top while held (m): the wrist housing reaches
    1.5 mm past tool0."""
    descent_speed: float = 0.25
    """m/s along the descent."""
    waypoint: float = 0.01
    """Spacing of the cached IK waypoints on the descent (m)."""
    settle_steps: int = 10
    """Physics steps before and after the grasp opens."""
    position_gain: float = 0.3
    time_step: float = 1.0 / 240.0
    max_offset: float = 0.010
    """A placement is ``outside-cell`` when the cube's centre is further than this from the cell
    centre along either table axis (m): (cell - cube) / 2 keeps the cube inside its cell."""
    max_tilt_deg: float = 15.0
    """A placement is ``tipped`` beyond this tilt."""
    light_meshes: bool = True
    """Draw the arm with its collision meshes (a frame costs a fraction of the visual meshes')."""
    camera: tuple[float, float, float] = (1.45, 90.0, -30.0)
    """Camera distance (m), yaw and pitch (degrees), aimed just behind the grid's centre from
    the operator's side of the table (the grid reads as the paper's matrix, the arm behind it);
    far enough back that the whole arm stays in view (at 1 m and -40 degrees its upper arm left
    the top of the frame)."""


@dataclass
class _Scene:
    robot: int = -1
    joints: list[int] = field(default_factory=list)
    tool: int = -1
    cubes: list[int] = field(default_factory=list)
    cube_shape: tuple[int, int] = (-1, -1)


def _patched_urdf(light: bool = True) -> Path:
    """airo-models' ur5e.urdf with zero-mass inertials on its frame-only links (pybullet would give
    each 1 kg: 2 kg of phantom payload at the flange) and absolute mesh paths, written once to a
    temporary file. ``light``: the arm is drawn with its collision meshes (16 times fewer
    triangles than the visual ones; same origins), which makes a camera frame several times
    cheaper; physics never sees visual meshes."""
    try:
        from airo_models import get_urdf_path
    except ImportError:
        raise RobotError("the simulated arm needs airo-models: pip install 'lagrseq[arm]'") from None
    source = Path(get_urdf_path("ur5e"))
    text = source.read_text()
    for link in ("base_link", "base", "flange", "tool0"):
        text = text.replace(f'<link name="{link}"/>', f'<link name="{link}">{_MASSLESS}</link>')
    if light:
        text = text.replace('filename="visual/base_cable_labels.obj"', 'filename="collision/base.obj"')
        text = re.sub(r'filename="visual/(\w+)\.obj"', r'filename="collision/\1.obj"', text)
    text = re.sub(r'filename="(?!/)([^"]+)"', lambda m: f'filename="{source.parent / m.group(1)}"', text)
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]  # one file per URDF text, every process
    out = Path(tempfile.gettempdir()) / f"lagrseq-ur5e-{digest}.urdf"
    if not out.exists() or out.read_text() != text:
        partial = out.with_suffix(f".{os.getpid()}.partial")
        partial.write_text(text)
        partial.replace(out)
    return out


_PLANS: dict[tuple[Any, ...], Any] = {}
"""Each workspace's IK plans, solved once per process (a second robot, e.g. the server's in a
test, is built in a tenth of the time)."""


class SimRobot:
    """The :class:`~lagrseq.robot.Robot` of a simulated UR5e (pybullet, DIRECT mode)."""

    def __init__(self, workspace: Workspace | None = None, settings: SimSettings | None = None) -> None:
        try:
            pybullet = import_pybullet()
        except ImportError:
            raise RobotError(
                "the simulated arm needs pybullet, which is not installed: pip install 'lagrseq[arm]' "
                "(pybullet publishes wheels for Python <= 3.11)"
            ) from None
        self.p = pybullet
        self.workspace = workspace or Workspace()
        self.settings = settings or SimSettings()
        self.rows, self.cols = self.workspace.rows, self.workspace.cols
        self.timings = Timings()
        self.on_frame: Callable[[str], None] | None = None
        """Called at the key poses of a placement (``--render``): it may call :meth:`render`."""
        self._urdf = str(_patched_urdf(self.settings.light_meshes))
        with _c_output_silenced():  # nothing of pybullet's own on the terminal
            self.client = self.p.connect(self.p.DIRECT)
        self._scene = _Scene()
        self._build()
        key = (self._urdf, self.workspace, self.settings)
        if key not in _PLANS:  # the IK always starts from HOME: the same plans every time
            _PLANS[key] = self._plan_all()
        self._plans: dict[tuple[int, int], tuple[np.ndarray, float]] = _PLANS[key][0]
        self._pickup: np.ndarray = _PLANS[key][1]
        self._pickup_error: float = _PLANS[key][2]

    # ------------------------------------------------------------------ scene
    def _call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        return getattr(self.p, name)(*args, physicsClientId=self.client, **kwargs)

    def _build(self) -> None:
        started = time.perf_counter()
        p, ws, s = self.p, self.workspace, self.settings
        self._call("resetSimulation")
        self._call("setGravity", 0, 0, -9.81)
        self._call("setTimeStep", s.time_step)
        top = ws.base_in_world.translation[2]
        # the table: a box whose top is the base's plane
        half = (0.65, 0.55, top / 2)
        centre = (0.35, 0.0, top / 2)
        table_shape = self._call("createCollisionShape", p.GEOM_BOX, halfExtents=half)
        table_look = self._call("createVisualShape", p.GEOM_BOX, halfExtents=half, rgbaColor=(0.80, 0.68, 0.50, 1))
        table = self._call("createMultiBody", baseMass=0, baseCollisionShapeIndex=table_shape,
                           baseVisualShapeIndex=table_look, basePosition=centre)
        self._call("changeDynamics", table, -1, lateralFriction=s.friction)
        # the grid drawn on the table: visual-only lines at the cell borders
        size = ws.cell_size
        for k in range(ws.rows + 1):
            a, b = ws.table_in_base.apply((k * size, 0, 0)), ws.table_in_base.apply((k * size, ws.cols * size, 0))
            self._line(a, b)
        for k in range(ws.cols + 1):
            a, b = ws.table_in_base.apply((0, k * size, 0)), ws.table_in_base.apply((ws.rows * size, k * size, 0))
            self._line(a, b)
        pickup = ws.pickup_in_world()
        spot = self._call("createVisualShape", p.GEOM_BOX, halfExtents=(0.025, 0.025, 0.0005), rgbaColor=(0.2, 0.45, 0.9, 1))
        self._call("createMultiBody", baseMass=0, baseVisualShapeIndex=spot,
                   basePosition=(pickup[0], pickup[1], top + 0.0005))
        # the arm
        scene = _Scene()
        scene.robot = self._call("loadURDF", self._urdf, basePosition=ws.base_in_world.translation, useFixedBase=True)
        for j in range(self._call("getNumJoints", scene.robot)):
            info = self._call("getJointInfo", scene.robot, j)
            if info[2] == p.JOINT_REVOLUTE:
                scene.joints.append(j)
            if info[12].decode() == "tool0":
                scene.tool = j
        if len(scene.joints) != 6 or scene.tool < 0:
            raise RobotError(f"{self._urdf}: expected a UR5e with 6 revolute joints and a tool0 link")
        self._names = tuple(self._call("getJointInfo", scene.robot, j)[1].decode() for j in scene.joints)
        half_cube = [s.cube_size / 2] * 3
        scene.cube_shape = (
            self._call("createCollisionShape", p.GEOM_BOX, halfExtents=half_cube),
            self._call("createVisualShape", p.GEOM_BOX, halfExtents=half_cube, rgbaColor=(0.85, 0.15, 0.12, 1)),
        )
        self._scene = scene
        self._set_joints(HOME)
        self.timings.scene += time.perf_counter() - started

    def _line(self, a: np.ndarray, b: np.ndarray) -> None:
        world_a, world_b = self.workspace.base_in_world.apply(a), self.workspace.base_in_world.apply(b)
        middle = (world_a + world_b) / 2
        length = float(np.linalg.norm(world_b - world_a))
        yaw = math.atan2(world_b[1] - world_a[1], world_b[0] - world_a[0])
        shape = self._call("createVisualShape", self.p.GEOM_BOX, halfExtents=(length / 2 + 0.001, 0.001, 0.0004),
                           rgbaColor=(0.15, 0.15, 0.15, 1))
        self._call("createMultiBody", baseMass=0, baseVisualShapeIndex=shape,
                   basePosition=(middle[0], middle[1], middle[2] + 0.0004),
                   baseOrientation=self.p.getQuaternionFromEuler((0, 0, yaw)))

    def _set_joints(self, positions: tuple[float, ...] | np.ndarray, velocities: Any = None) -> None:
        scene = self._scene
        for k, (j, q) in enumerate(zip(scene.joints, positions)):
            v = 0.0 if velocities is None else float(velocities[k])
            self._call("resetJointState", scene.robot, j, float(q), v)
        self._call("setJointMotorControlArray", scene.robot, scene.joints, self.p.POSITION_CONTROL,
                   targetPositions=[float(q) for q in positions],
                   positionGains=[self.settings.position_gain] * 6)

    # ------------------------------------------------------------------ inverse kinematics
    def _tool_pose(self) -> np.ndarray:
        return np.array(self._call("getLinkState", self._scene.robot, self._scene.tool, computeForwardKinematics=True)[4])

    def ik(self, position: np.ndarray, rounds: int = 8) -> tuple[np.ndarray, float]:
        """Joint angles putting tool0 at ``position`` (world) pointing down, and the residual (m).
        The joint state is restored afterwards."""
        started = time.perf_counter()
        scene, p = self._scene, self.p
        saved = [self._call("getJointState", scene.robot, j)[:2] for j in scene.joints]
        down = p.getQuaternionFromEuler(DOWN)
        target = [float(x) for x in position]
        # one null-space solve chooses the posture (near HOME)...
        solution = self._call(
            "calculateInverseKinematics", scene.robot, scene.tool, target, down,
            lowerLimits=[-2 * math.pi] * 6, upperLimits=[2 * math.pi] * 6, jointRanges=[4 * math.pi] * 6,
            restPoses=list(HOME), maxNumIterations=200, residualThreshold=1e-9,
        )
        # ...then plain solves seeded from the joints reset to the last answer remove its error
        error = math.inf
        for _ in range(rounds):
            for j, q in zip(scene.joints, solution):
                self._call("resetJointState", scene.robot, j, q)
            error = float(np.linalg.norm(self._tool_pose() - position))
            if error < 1e-7:
                break
            solution = self._call("calculateInverseKinematics", scene.robot, scene.tool, target, down,
                                  maxNumIterations=200, residualThreshold=1e-10)
        for j, (q, v) in zip(scene.joints, saved):
            self._call("resetJointState", scene.robot, j, q, v)
        self.timings.ik += time.perf_counter() - started
        return np.array(solution[:6]), error

    # ------------------------------------------------------------------ planning
    def _heights(self) -> tuple[float, float]:
        """tool0's height above the table at the release pose and at the hover pose."""
        s = self.settings
        release = s.release_gap + s.cube_size + s.grasp_gap
        return release, release + s.hover

    def _plan(self, xy: np.ndarray) -> tuple[np.ndarray, float]:
        """Joint waypoints from the hover pose down to the release pose over ``xy`` (world), and
        the largest IK residual among them (m)."""
        release, hover = self._heights()
        top = self.workspace.base_in_world.translation[2]
        count = int(round(self.settings.hover / self.settings.waypoint))
        path, worst = [], 0.0
        for k in range(count + 1):
            z = top + hover - k * (hover - release) / count
            q, error = self.ik(np.array([xy[0], xy[1], z]))
            path.append(q)
            worst = max(worst, error)
        return np.array(path), worst

    def _plan_all(self) -> tuple[dict[tuple[int, int], tuple[np.ndarray, float]], np.ndarray, float]:
        """Every cell's descent, solved once (about 0.4 s on an idle core): (waypoints, worst
        residual) per cell, and the pickup pose with its residual."""
        plans = {}
        for row in range(self.rows):
            for col in range(self.cols):
                plans[row, col] = self._plan(self.workspace.cell_in_world(row, col)[:2])
        release, _ = self._heights()
        pickup = self.workspace.pickup_in_world()
        pose, error = self.ik(np.array([pickup[0], pickup[1], pickup[2] + release]))
        return plans, pose, error

    def reach_errors(self) -> dict[tuple[int, int], float]:
        """The worst IK residual (m) on each cell's descent, hover to release."""
        return {cell: error for cell, (_, error) in self._plans.items()}

    # ------------------------------------------------------------------ the Robot interface
    def place(self, row: int, col: int) -> PlacementResult:
        p, s, scene = self.p, self.settings, self._scene
        if not (0 <= row < self.rows and 0 <= col < self.cols):
            raise RobotError(f"cell ({row}, {col}) is outside the {self.rows}x{self.cols} grid")
        path, error = self._plans[row, col]
        if error > 1e-3 or self._pickup_error > 1e-3:
            return PlacementResult(row, col, "unreachable")
        self.timings.placements += 1
        top = self.workspace.base_in_world.translation[2]
        # 1. a new cube at the pickup spot, the arm over it, the grasp closes (teleported)
        pickup = self.workspace.pickup_in_world()
        cube = self._call("createMultiBody", baseMass=s.cube_mass, baseCollisionShapeIndex=scene.cube_shape[0],
                          baseVisualShapeIndex=scene.cube_shape[1],
                          basePosition=(pickup[0], pickup[1], top + s.cube_size / 2))
        self._call("changeDynamics", cube, -1, lateralFriction=s.friction, frictionAnchor=1)
        scene.cubes.append(cube)
        self._set_joints(self._pickup)
        self._hold(cube)
        grasp = self._call("createConstraint", scene.robot, scene.tool, cube, -1, p.JOINT_FIXED, (0, 0, 0),
                           parentFramePosition=(0, 0, s.grasp_gap + s.cube_size / 2), childFramePosition=(0, 0, 0),
                           parentFrameOrientation=p.getQuaternionFromEuler((math.pi, 0, 0)))
        self._call("changeConstraint", grasp, maxForce=50)
        self._frame("pick")
        # 2. the hover pose over the cell, cube in hand (teleported)
        self._set_joints(path[0])
        self._hold(cube)
        self._frame("hover")
        # 3. the descent, simulated
        steps = self._descend(path)
        self._frame("release")
        self._call("removeConstraint", grasp)
        steps += self._simulate(s.settle_steps)
        # 4. back up to the hover pose (teleported); measure where the cube came to rest
        self._set_joints(path[0])
        self._frame("retreat")
        return self._judge(cube, row, col, steps)

    def _hold(self, cube: int) -> None:
        """Put a held cube where the grasp holds it (after a teleport of the arm)."""
        s = self.settings
        tool = self._call("getLinkState", self._scene.robot, self._scene.tool, computeForwardKinematics=True)
        position = np.array(tool[4]) - np.array([0, 0, s.grasp_gap + s.cube_size / 2])
        self._call("resetBasePositionAndOrientation", cube, position.tolist(), (0, 0, 0, 1))
        self._call("resetBaseVelocity", cube, (0, 0, 0), (0, 0, 0))

    def _descend(self, path: np.ndarray) -> int:
        s, scene, p = self.settings, self._scene, self.p
        segment_steps = max(1, int(round(s.waypoint / s.descent_speed / s.time_step)))
        steps = 0
        for a, b in zip(path[:-1], path[1:]):
            velocity = (b - a) / (segment_steps * s.time_step)
            for k in range(1, segment_steps + 1):
                target = a + (b - a) * (k / segment_steps)
                self._call("setJointMotorControlArray", scene.robot, scene.joints, p.POSITION_CONTROL,
                           targetPositions=target.tolist(), targetVelocities=velocity.tolist(),
                           positionGains=[s.position_gain] * 6, velocityGains=[1.0] * 6)
                steps += self._simulate(1)
        self._call("setJointMotorControlArray", scene.robot, scene.joints, p.POSITION_CONTROL,
                   targetPositions=path[-1].tolist(), targetVelocities=[0.0] * 6,
                   positionGains=[s.position_gain] * 6, velocityGains=[1.0] * 6)
        return steps + self._simulate(s.settle_steps)

    def _simulate(self, steps: int) -> int:
        started = time.perf_counter()
        for _ in range(steps):
            self._call("stepSimulation")
        self.timings.physics += time.perf_counter() - started
        self.timings.steps += steps
        return steps

    def _pose(self, cube: int) -> tuple[np.ndarray, float, float]:
        """A cube's centre (world), its height above the table (m) and its tilt (degrees): the
        smallest angle between one of its axes and the vertical, so a cube lying on any face is
        flat."""
        position, orientation = self._call("getBasePositionAndOrientation", cube)
        matrix = np.array(self.p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        tilt = math.degrees(math.acos(min(1.0, float(np.max(np.abs(matrix[2, :]))))))
        height = position[2] - self.workspace.base_in_world.translation[2]
        return np.array(position), height, tilt

    def _judge(self, cube: int, row: int, col: int, steps: int) -> PlacementResult:
        s = self.settings
        position, height, tilt = self._pose(cube)
        landed = self.workspace.cell_of_world(position)
        offset = self.workspace.offset_in_cell(position, row, col)
        if abs(height - s.cube_size / 2) > 0.005:
            outcome = "not-resting"
        elif tilt > s.max_tilt_deg:
            outcome = "tipped"
        elif landed != (row, col) or np.max(np.abs(offset)) > s.max_offset:
            outcome = "outside-cell"
        else:
            outcome = "placed"
        return PlacementResult(
            row, col, outcome,
            offset_mm=round(float(np.hypot(*offset)) * 1000, 4),
            tilt_deg=round(tilt, 4),
            height_mm=round(height * 1000, 4),
            landed_row=landed[0] if landed else -1,
            landed_col=landed[1] if landed else -1,
            sim_steps=steps,
        )

    def clear(self) -> None:
        """Take every cube away and bring the arm home (about 0.1 ms). Measured: the placements
        that follow are bit for bit those of a freshly built robot, so a run is the same in
        process and behind ``lagrseq robot serve``, whatever the server did before."""
        for cube in self._scene.cubes:
            self._call("removeBody", cube)
        self._scene.cubes.clear()
        self._set_joints(HOME)

    def observe(self) -> np.ndarray:
        """Occupancy from the cubes' poses: a cell holds an object when a cube's centre lies over
        it (world -> base -> table -> cell) and the cube rests flat on the table."""
        grid = np.zeros((self.rows, self.cols), dtype=np.int8)
        for cube in self._scene.cubes:
            position, height, tilt = self._pose(cube)
            if abs(height - self.settings.cube_size / 2) > 0.005 or tilt > self.settings.max_tilt_deg:
                continue
            cell = self.workspace.cell_of_world(position)
            if cell is not None:
                grid[cell] = 1
        return grid

    @property
    def cubes(self) -> list[int]:
        """pybullet body ids of the cubes on the table (tests move them by hand)."""
        return list(self._scene.cubes)

    def joint_state(self) -> JointState:
        states = [self._call("getJointState", self._scene.robot, j) for j in self._scene.joints]
        return JointState(self._names, tuple(round(float(s[0]), 6) for s in states))

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        """The scene from behind the robot (TinyRenderer: works headless), RGB uint8."""
        started = time.perf_counter()
        p = self.p
        distance, yaw, pitch = self.settings.camera
        centre = self.workspace.cell_in_world((self.rows - 1) / 2, (self.cols - 1) / 2)  # type: ignore[arg-type]
        target = (float(centre[0]) - 0.13, float(centre[1]) - 0.05, float(centre[2]) + 0.16)
        view = p.computeViewMatrixFromYawPitchRoll(target, distance, yaw, pitch, 0, 2)
        projection = p.computeProjectionMatrixFOV(55, width / height, 0.05, 5.0)
        image = self._call("getCameraImage", width, height, view, projection, renderer=p.ER_TINY_RENDERER,
                           shadow=0, lightDirection=(0.4, -0.6, 1.0))
        rgb = np.asarray(image[2], dtype=np.uint8).reshape(height, width, 4)[:, :, :3].copy()
        self.timings.render += time.perf_counter() - started
        return rgb

    def _frame(self, moment: str) -> None:
        if self.on_frame is not None:
            self.on_frame(moment)

    def close(self) -> None:
        if self.client >= 0:
            try:
                self.p.disconnect(physicsClientId=self.client)
            finally:
                self.client = -1

    def __del__(self) -> None:  # a robot dropped without close() still frees its engine
        with contextlib.suppress(Exception):
            self.close()
