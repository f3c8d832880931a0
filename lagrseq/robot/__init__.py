"""The robot behind the arm-arrangement env: place an object on a grid cell, clear the table, read
the occupancy back.

:class:`Robot` is the interface the env talks to; two implementations exist:

* :class:`lagrseq.robot.sim.SimRobot`: a UR5e in pybullet (DIRECT mode), in this process (the
  ``arm`` extra: pybullet, airo-models);
* :class:`lagrseq.robot.remote.RemoteRobot`: a gRPC client of a robot service
  (``lagrseq robot serve --sim`` serves a SimRobot; a lab with a UR5e serves its arm through
  ur_rtde behind the same ``.proto``, ``lagrseq/robot/proto/robot.proto``).

Nothing here imports pybullet or grpc: the implementations import them when they are built.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from lagrseq.errors import LagrseqError

OUTCOMES = ("placed", "unreachable", "outside-cell", "tipped", "not-resting")
"""What a placement can come to: ``placed`` is the only success."""


class RobotError(LagrseqError):
    """The robot (or its service) cannot be used: one line naming the problem and the fix."""


@dataclass(frozen=True)
class PlacementResult:
    """What one ``place(cell)`` did, measured from the object's resting pose."""

    row: int
    col: int
    outcome: str
    """One of :data:`OUTCOMES`."""
    offset_mm: float = 0.0
    """Distance of the object's centre from the cell's centre, in the table plane (mm)."""
    tilt_deg: float = 0.0
    """Angle between the object's up axis and the table's normal (degrees)."""
    height_mm: float = 0.0
    """Height of the object's centre above the table top (mm); half the cube when resting."""
    landed_row: int = -1
    landed_col: int = -1
    """The cell under the object's centre (-1: off the grid, or nothing was placed)."""
    sim_steps: int = 0
    """Physics steps the placement took (0 on a real arm or when nothing moved)."""

    @property
    def ok(self) -> bool:
        return self.outcome == "placed"

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "ok": self.ok}


@dataclass(frozen=True)
class JointState:
    """The arm's joints (radians), names as in the URDF and on the UR controller."""

    names: tuple[str, ...]
    positions: tuple[float, ...]


class Robot(Protocol):
    """What the arm-arrangement env needs of an arm."""

    rows: int
    cols: int

    def place(self, row: int, col: int) -> PlacementResult:
        """Pick a new object at the pickup spot and put it on cell (row, col); report what
        happened. A failure is a result, never an exception."""
        ...

    def clear(self) -> None:
        """Take every object off the table and bring the arm home."""
        ...

    def observe(self) -> np.ndarray:
        """Occupancy of the grid (rows x cols int8) measured from the objects, not remembered."""
        ...

    def joint_state(self) -> JointState: ...

    def render(self, width: int, height: int) -> np.ndarray | None:
        """An RGB picture of the scene (height x width x 3 uint8), None if there is no camera."""
        ...

    def close(self) -> None: ...
