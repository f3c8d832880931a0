"""Object arrangement (SPEC section 3): drop objects on a 5 x 5 table grid until they form the target
arrangement (the released code's diamond, or another shape of :mod:`lagrseq.tasks.shapes` scaled
to 5 x 5).

The descriptor is the released ``Object_arrangement(simulated)/LLM.py`` prompt, byte for byte
(typo "coonfiguration" included): instructions and two examples (a square, an oval) first, then
the context sentence and the partial grid inside triple backticks. The paper's appendix shows the
same examples with the partial grid in the middle.
"""

from __future__ import annotations

from lagrseq.tasks import shapes
from lagrseq.tasks.grid import (
    Descriptor,
    GridTask,
    GuidanceMode,
    MatrixFormat,
    format_comma,
    grid_of,
)

NAME = "object-arrangement"
SIZE = 5

_EXAMPLE_1 = grid_of(["00000", "01010", "00000", "01100", "00000"])
_SQUARE = grid_of(["00000", "01110", "01010", "01110", "00000"])
_EXAMPLE_2 = grid_of(["00100", "01000", "00010", "00100", "00000"])
_OVAL = grid_of(["00100", "01010", "01010", "00100", "00000"])

DESCRIPTOR = Descriptor(
    instructions=(
        "Observe the pattern of objects in the initial configuration. It is a partially complete "
        "pattern of a common scheme in which objects would be arranged. Guess the final "
        "arrangement scheme and display it in the form of a 5x5 matrix.    Note that all the "
        "initial object positions are correct. So the final configuration must necessarily contain "
        "the initial object positions as they are.    Lets think step by step. Make sure your "
        "response contains only the configuration, and not the explanation.    "
        f"Example 1: If the initial arrangement coonfiguration is:     {format_comma(_EXAMPLE_1)}    "
        "Then the full arrangement may be in the shape of a square, in which case the final "
        f"arrangement would be:    {format_comma(_SQUARE)}    "
        f"Example 2: If the initial arrangement is:     {format_comma(_EXAMPLE_2)}    "
        "Then a possible arrangement could be in the shape of an oval, such that the final "
        f"arrangement would be:    {format_comma(_OVAL)}    "
    ),
    context=(
        " The following matrix corresponds to positions on a 5x5 table. 1 represents the presence"
        " of an object, while 0 represents an empty space on the table.    If the initial table"
        " configuration is:    "
    ),
)


def object_arrangement(
    target: str = "diamond",
    goal_threshold: float = 1.0,
    matrix_format: MatrixFormat = "numpy",
    guidance_mode: GuidanceMode = "next-missing",
) -> GridTask:
    """The object-arrangement task on a 5 x 5 table. Action 1 drops an object on the drawn cell."""
    return GridTask(
        name=NAME,
        target=shapes.target(target, SIZE),
        target_name=target,
        descriptor=DESCRIPTOR,
        cell_action="drop",
        goal_threshold=goal_threshold,
        matrix_format=matrix_format,
        guidance_mode=guidance_mode,
    )


ARM_NAME = "arm-arrangement"


def arm_arrangement(
    target: str = "diamond",
    goal_threshold: float = 1.0,
    matrix_format: MatrixFormat = "numpy",
    guidance_mode: GuidanceMode = "next-missing",
) -> GridTask:
    """Object arrangement executed by a robot arm (the paper's UR5e experiment): the same task,
    descriptor and prompt as :func:`object_arrangement` (recorded answers serve both), under its
    own name."""
    task = object_arrangement(target, goal_threshold, matrix_format, guidance_mode)
    task.name = ARM_NAME
    return task
