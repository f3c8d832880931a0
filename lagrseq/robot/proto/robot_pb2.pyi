from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable
from typing import ClassVar as _ClassVar, Optional as _Optional

DESCRIPTOR: _descriptor.FileDescriptor

class DescribeRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class Description(_message.Message):
    __slots__ = ("rows", "cols", "cell_size", "joint_names", "robot")
    ROWS_FIELD_NUMBER: _ClassVar[int]
    COLS_FIELD_NUMBER: _ClassVar[int]
    CELL_SIZE_FIELD_NUMBER: _ClassVar[int]
    JOINT_NAMES_FIELD_NUMBER: _ClassVar[int]
    ROBOT_FIELD_NUMBER: _ClassVar[int]
    rows: int
    cols: int
    cell_size: float
    joint_names: _containers.RepeatedScalarFieldContainer[str]
    robot: str
    def __init__(self, rows: _Optional[int] = ..., cols: _Optional[int] = ..., cell_size: _Optional[float] = ..., joint_names: _Optional[_Iterable[str]] = ..., robot: _Optional[str] = ...) -> None: ...

class PlaceRequest(_message.Message):
    __slots__ = ("row", "col")
    ROW_FIELD_NUMBER: _ClassVar[int]
    COL_FIELD_NUMBER: _ClassVar[int]
    row: int
    col: int
    def __init__(self, row: _Optional[int] = ..., col: _Optional[int] = ...) -> None: ...

class Placement(_message.Message):
    __slots__ = ("row", "col", "outcome", "offset_mm", "tilt_deg", "height_mm", "landed_row", "landed_col", "sim_steps")
    ROW_FIELD_NUMBER: _ClassVar[int]
    COL_FIELD_NUMBER: _ClassVar[int]
    OUTCOME_FIELD_NUMBER: _ClassVar[int]
    OFFSET_MM_FIELD_NUMBER: _ClassVar[int]
    TILT_DEG_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_MM_FIELD_NUMBER: _ClassVar[int]
    LANDED_ROW_FIELD_NUMBER: _ClassVar[int]
    LANDED_COL_FIELD_NUMBER: _ClassVar[int]
    SIM_STEPS_FIELD_NUMBER: _ClassVar[int]
    row: int
    col: int
    outcome: str
    offset_mm: float
    tilt_deg: float
    height_mm: float
    landed_row: int
    landed_col: int
    sim_steps: int
    def __init__(self, row: _Optional[int] = ..., col: _Optional[int] = ..., outcome: _Optional[str] = ..., offset_mm: _Optional[float] = ..., tilt_deg: _Optional[float] = ..., height_mm: _Optional[float] = ..., landed_row: _Optional[int] = ..., landed_col: _Optional[int] = ..., sim_steps: _Optional[int] = ...) -> None: ...

class ClearRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ClearReply(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ObserveRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class Occupancy(_message.Message):
    __slots__ = ("rows", "cols", "cells")
    ROWS_FIELD_NUMBER: _ClassVar[int]
    COLS_FIELD_NUMBER: _ClassVar[int]
    CELLS_FIELD_NUMBER: _ClassVar[int]
    rows: int
    cols: int
    cells: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, rows: _Optional[int] = ..., cols: _Optional[int] = ..., cells: _Optional[_Iterable[int]] = ...) -> None: ...

class JointStateRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class JointState(_message.Message):
    __slots__ = ("names", "positions")
    NAMES_FIELD_NUMBER: _ClassVar[int]
    POSITIONS_FIELD_NUMBER: _ClassVar[int]
    names: _containers.RepeatedScalarFieldContainer[str]
    positions: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, names: _Optional[_Iterable[str]] = ..., positions: _Optional[_Iterable[float]] = ...) -> None: ...

class RenderRequest(_message.Message):
    __slots__ = ("width", "height")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ...) -> None: ...

class Image(_message.Message):
    __slots__ = ("width", "height", "png")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    PNG_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    png: bytes
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ..., png: _Optional[bytes] = ...) -> None: ...
