"""Grid cell -> table frame -> robot base frame: the static transforms of the arm's workspace.

The paper's arm computed each cell's pose as a grid coordinate in the table's frame, carried into
the robot's base frame by one static transform (ROS TF2). :class:`StaticTransform` is that
transform: the pose of a child frame in its parent frame, a translation and a yaw, the same six
numbers as ::

    ros2 run tf2_ros static_transform_publisher --x 0.375 --y -0.125 --z 0 --yaw 0 \\
        --frame-id base_link --child-frame-id table

Frames (metres, right-handed, z up):

* ``table``: origin at the outer corner of cell (0, 0) on the table top; x along the rows (row 0
  is the row nearest the robot), y along the columns. A cell (row, col) has its centre at
  ((row + 1/2) s, (col + 1/2) s, 0) with s the cell size.
* ``base_link``: the UR5e's base, x forward (away from the robot), y to its left. The table
  frame is the base frame moved 0.375 m forward and 0.125 m right, so seen from the operator's
  side of the table (the camera, facing the robot) the grid reads as the paper draws the 5 x 5
  matrix: row 0 at the top (by the robot), column 0 on the left.
* ``world``: pybullet's world; the base stands on the table top at z = 0.625.

Pure numpy: a real arm's server uses the same numbers (see docs/arm.md, "Robot service").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StaticTransform:
    """The pose of ``child`` in ``parent``: ``p_parent = R_z(yaw) p_child + translation``."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    yaw: float = 0.0
    """Rotation about the parent's z axis, radians (the grid lies flat on the table)."""

    def apply(self, point: np.ndarray | tuple[float, ...]) -> np.ndarray:
        """A point of ``child`` in ``parent``."""
        p = np.asarray(point, dtype=float)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x, y = c * p[0] - s * p[1], s * p[0] + c * p[1]
        t = self.translation
        return np.array([x + t[0], y + t[1], p[2] + t[2]])

    def invert(self, point: np.ndarray | tuple[float, ...]) -> np.ndarray:
        """A point of ``parent`` in ``child``."""
        p = np.asarray(point, dtype=float) - np.asarray(self.translation, dtype=float)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([c * p[0] + s * p[1], -s * p[0] + c * p[1], p[2]])


@dataclass(frozen=True)
class Workspace:
    """The 5 x 5 grid of the paper's robot experiment and the transforms that place it."""

    rows: int = 5
    cols: int = 5
    cell_size: float = 0.05
    """Metres. Paper: 5 cm cells."""
    table_in_base: StaticTransform = StaticTransform("base_link", "table", (0.375, -0.125, 0.0))
    """Table frame in the base frame: cell (i, j) centred at (0.40 + 0.05 i, -0.10 + 0.05 j), so
    the grid spans 0.375-0.625 m ahead of the base axis (closer than 0.35 m the UR5e hits its own
    base) and 0.125 m either side."""
    base_in_world: StaticTransform = StaticTransform("world", "base_link", (0.0, 0.0, 0.625))
    """The base on the table top (pybullet's table height)."""
    pickup_in_base: tuple[float, float] = (0.50, -0.30)
    """Where new objects are picked up, in the base frame (to the robot's right)."""

    def cell_in_table(self, row: int, col: int) -> np.ndarray:
        return np.array([(row + 0.5) * self.cell_size, (col + 0.5) * self.cell_size, 0.0])

    def cell_in_base(self, row: int, col: int) -> np.ndarray:
        """Centre of a cell on the table top, in the base frame."""
        return self.table_in_base.apply(self.cell_in_table(row, col))

    def cell_in_world(self, row: int, col: int) -> np.ndarray:
        return self.base_in_world.apply(self.cell_in_base(row, col))

    def cell_of_world(self, point: np.ndarray | tuple[float, ...]) -> tuple[int, int] | None:
        """The cell under a world point (None off the grid): world -> base -> table -> grid."""
        p = self.table_in_base.invert(self.base_in_world.invert(point))
        row, col = math.floor(p[0] / self.cell_size), math.floor(p[1] / self.cell_size)
        if 0 <= row < self.rows and 0 <= col < self.cols:
            return row, col
        return None

    def offset_in_cell(self, point: np.ndarray | tuple[float, ...], row: int, col: int) -> np.ndarray:
        """(dx, dy) of a world point from a cell's centre, in the table frame (metres)."""
        p = self.table_in_base.invert(self.base_in_world.invert(point))
        return p[:2] - self.cell_in_table(row, col)[:2]

    def pickup_in_world(self) -> np.ndarray:
        return self.base_in_world.apply((*self.pickup_in_base, 0.0))
