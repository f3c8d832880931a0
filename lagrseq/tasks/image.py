"""Image completion (SPEC section 2): turn pixels of a blank 10 x 10 image on and off until it shows
the target shape (the released code's X, or another shape of :mod:`lagrseq.tasks.shapes`).

The descriptor is the released ``Image_completion/LLM.py`` prompt, byte for byte: instructions
and three examples (a square, a right-angled triangle, a horizontal line) first, then the context
sentence and the partial image inside triple backticks. The paper's appendix shows two examples
(oval, triangle) in another order; the recorded answers were obtained with the code's text.
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

NAME = "image-completion"
SIZE = 10

_EXAMPLE_1 = grid_of(
    ["1000000010", "1000000000", "1000000001", "1000000000", "1000000001",
     "0000000000", "0000000000", "0000000001", "1000000000", "1010100011"]
)  # fmt: skip
_SQUARE = grid_of(["1111111111"] + ["1000000001"] * 8 + ["1111111111"])
_EXAMPLE_2 = grid_of(
    ["0000000000", "1000000000", "1010000000", "0000000000", "1000000000",
     "1000000000", "1000000000", "0000000100", "1000000000", "1110111011"]
)  # fmt: skip
_TRIANGLE = grid_of(
    ["1000000000", "1010000000", "1001000000", "1000100000", "1000010000",
     "1000001000", "1000000100", "1000000010", "1000000001", "1111111111"]
)  # fmt: skip
_EXAMPLE_3 = grid_of(["0000000000"] * 5 + ["1001010010"] + ["0000000000"] * 4)
_LINE = grid_of(["0000000000"] * 5 + ["1111111111"] + ["0000000000"] * 4)

# The released text joins its source lines with backslash continuations, so every line break of
# the source became four spaces; the example matrices keep their own newlines.
DESCRIPTOR = Descriptor(
    instructions=(
        "Observe the pattern in the initial image. It is a partially complete pattern of a common "
        "geometric shape. Guess the final shape and display it in the form of a 10x10 matrix.    "
        "Note that all the initial pixels are in their correct positions. So the final image must "
        "necessarily contain the initial pixels as they are, and should not contain any additional "
        "pixels that are not part of the shape.    Make sure your response contains only the "
        "image, and not the explanation. Lets think step by step.    "
        f"Example 1: If the initial image is:     {format_comma(_EXAMPLE_1)}    "
        "Then the full image may be in the shape of a square, in which case the final image would "
        f"be:    {format_comma(_SQUARE)}    "
        f"Example 2: If the initial pixel configuration is:     {format_comma(_EXAMPLE_2)}    "
        "Then the full image may be in the shape of a right angled triangle, such that the final "
        f"pattern would be:    {format_comma(_TRIANGLE)}    "
        f"Example 3: If the initial image is:     {format_comma(_EXAMPLE_3)}    "
        "Then the full image may be depicting a horizontal line, such that the final pattern "
        f"would be:    {format_comma(_LINE)}    "
    ),
    context=(
        " The following matrix corresponds to an image of size 10x10. 1 represents a white pixel,"
        " while 0 represents a black pixel.    If the initial image is:    "
    ),
)


def image_completion(
    target: str = "x",
    goal_threshold: float = 1.0,
    matrix_format: MatrixFormat = "numpy",
    guidance_mode: GuidanceMode = "cell-by-cell",
) -> GridTask:
    """The image-completion task on a 10 x 10 image. Action 1 flips the scanned pixel."""
    return GridTask(
        name=NAME,
        target=shapes.target(target, SIZE),
        target_name=target,
        descriptor=DESCRIPTOR,
        cell_action="flip",
        goal_threshold=goal_threshold,
        matrix_format=matrix_format,
        guidance_mode=guidance_mode,
    )
