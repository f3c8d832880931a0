"""Binary shapes on a grid: the targets of the grid tasks and the hypotheses of their extrapolator.

A shape is a boolean mask of the whole grid. Families, simplest first (the rank the rule-based
extrapolator uses to pick "the simplest shape"):

==================  ==========================================================================
family              members (every position and size that fits the grid)
==================  ==========================================================================
horizontal-line     a whole row
vertical-line       a whole column
diagonal            a top-left to bottom-right diagonal, edge to edge, at least 2 cells
anti-diagonal       a top-right to bottom-left diagonal, edge to edge, at least 2 cells
plus                row and column s // 2 of an s x s box (the middle; one cell wide)
x                   both diagonals of an s x s box (the released image target is the 10 x 10 X)
square              the outline of an s x s box
diamond             the cells of an s x s box with |2i-(s-1)| + |2j-(s-1)| = s-1 (s odd) or s
                    (s even); the released arrangement target is the 5 x 5 diamond
right-triangle      two sides of an s x s box and the diagonal between them (4 orientations)
oval                the outline of an h x w box with its corners cut by k = max(1, min(h,w)//4)
                    cells, as the descriptors' "oval" examples draw it
==================  ==========================================================================

Lines are always drawn edge to edge: a model asked for "the final shape" extends a line, it does not
stop where the evidence stops. Identical masks from two families are kept once, in the simpler one.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

FAMILIES = (
    "horizontal-line",
    "vertical-line",
    "diagonal",
    "anti-diagonal",
    "plus",
    "x",
    "square",
    "diamond",
    "right-triangle",
    "oval",
)
"""Shape families, simplest first."""

TARGETS = (
    "x",
    "diamond",
    "horizontal-line",
    "vertical-line",
    "diagonal",
    "anti-diagonal",
    "square",
    "right-triangle",
    "plus",
    "oval",
)
"""Names of the target shapes (one per family, scaled to the grid; see :func:`target`)."""

Cells = list[tuple[int, int]]


# ------------------------------------------------------------------------------------------
# One shape in an s x s (or h x w) box whose top-left cell is (0, 0)
# ------------------------------------------------------------------------------------------
def plus_cells(s: int) -> Cells:
    middle = s // 2
    return sorted({(middle, j) for j in range(s)} | {(i, middle) for i in range(s)})


def x_cells(s: int) -> Cells:
    return sorted({(i, i) for i in range(s)} | {(i, s - 1 - i) for i in range(s)})


def square_cells(s: int) -> Cells:
    return sorted({(i, j) for i in range(s) for j in range(s) if i in (0, s - 1) or j in (0, s - 1)})


def diamond_cells(s: int) -> Cells:
    radius = s - 1 if s % 2 else s
    return [
        (i, j)
        for i in range(s)
        for j in range(s)
        if abs(2 * i - (s - 1)) + abs(2 * j - (s - 1)) == radius
    ]


def right_triangle_cells(s: int, corner: str) -> Cells:
    """Legs on two sides of the box meeting at ``corner`` (bl, br, tl, tr), hypotenuse between."""
    last = s - 1
    cells: set[tuple[int, int]] = set()
    for i in range(s):
        if corner == "bl":
            cells |= {(i, 0), (last, i), (i, i)}
        elif corner == "br":
            cells |= {(i, last), (last, i), (i, last - i)}
        elif corner == "tl":
            cells |= {(i, 0), (0, i), (i, last - i)}
        else:  # tr
            cells |= {(i, last), (0, i), (i, i)}
    return sorted(cells)


def oval_cells(h: int, w: int) -> Cells:
    cut = max(1, min(h, w) // 4)
    cells: set[tuple[int, int]] = set()
    for j in range(cut, w - cut):
        cells |= {(0, j), (h - 1, j)}
    for i in range(cut, h - cut):
        cells |= {(i, 0), (i, w - 1)}
    for step in range(1, cut):  # the diagonal that closes each cut corner
        i, j = step, cut - step
        cells |= {(i, j), (i, w - 1 - j), (h - 1 - i, j), (h - 1 - i, w - 1 - j)}
    return sorted(cells)


# ------------------------------------------------------------------------------------------
# Every member of every family on a rows x cols grid
# ------------------------------------------------------------------------------------------
def _placed(cells: Cells, top: int, left: int) -> Cells:
    return [(top + i, left + j) for i, j in cells]


def _boxes(rows: int, cols: int, smallest: int) -> Iterator[tuple[int, int, int]]:
    """(size, top, left) of every square box that fits, small boxes first, then row-major."""
    for s in range(smallest, min(rows, cols) + 1):
        for top in range(rows - s + 1):
            for left in range(cols - s + 1):
                yield s, top, left


def _family_members(family: str, rows: int, cols: int) -> Iterator[Cells]:
    if family == "horizontal-line":
        for r in range(rows):
            yield [(r, c) for c in range(cols)]
    elif family == "vertical-line":
        for c in range(cols):
            yield [(r, c) for r in range(rows)]
    elif family == "diagonal":
        for offset in range(-(rows - 2), cols - 1):  # c - r
            yield [(r, r + offset) for r in range(rows) if 0 <= r + offset < cols]
    elif family == "anti-diagonal":
        for total in range(1, rows + cols - 2):  # r + c
            yield [(r, total - r) for r in range(rows) if 0 <= total - r < cols]
    elif family == "right-triangle":
        for s, top, left in _boxes(rows, cols, 3):
            for corner in ("bl", "br", "tl", "tr"):
                yield _placed(right_triangle_cells(s, corner), top, left)
    elif family == "oval":
        for h in range(3, rows + 1):
            for w in range(3, cols + 1):
                for top in range(rows - h + 1):
                    for left in range(cols - w + 1):
                        yield _placed(oval_cells(h, w), top, left)
    else:
        make = {"plus": plus_cells, "x": x_cells, "square": square_cells, "diamond": diamond_cells}
        smallest = 2 if family == "square" else 3
        for s, top, left in _boxes(rows, cols, smallest):
            yield _placed(make[family](s), top, left)


@dataclass(frozen=True)
class Library:
    """Every shape that fits a rows x cols grid, simplest first.

    ``masks[k]`` is shape k as a flat boolean row-major mask; ``families[k]`` its family. Order:
    family rank, then fewer cells, then the generation order (smaller boxes, then top-left first),
    so ties are broken the same way every time.
    """

    rows: int
    cols: int
    masks: np.ndarray
    families: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.families)

    def grid(self, k: int) -> np.ndarray:
        """Shape k as a rows x cols int8 grid."""
        return self.masks[k].reshape(self.rows, self.cols).astype(np.int8)

    def containing(self, on_cells: np.ndarray) -> np.ndarray:
        """Indices (simplest first) of the shapes that contain every cell set in the flat
        boolean mask ``on_cells``."""
        on = np.flatnonzero(on_cells)
        if on.size == 0:
            return np.arange(len(self))
        return np.flatnonzero(self.masks[:, on].all(axis=1))

    def index(self, grid: np.ndarray) -> int | None:
        """Position of ``grid`` in the library, or None if it is not one of its shapes."""
        flat = np.asarray(grid, dtype=bool).ravel()
        hits = np.flatnonzero((self.masks == flat).all(axis=1))
        return int(hits[0]) if hits.size else None


@lru_cache(maxsize=8)
def library(rows: int, cols: int) -> Library:
    """The shape library of a rows x cols grid (built once per size)."""
    entries: list[tuple[int, int, int, bytes, str]] = []
    seen: set[bytes] = set()
    order = 0
    for rank, family in enumerate(FAMILIES):
        for cells in _family_members(family, rows, cols):
            mask = np.zeros(rows * cols, dtype=bool)
            for r, c in cells:
                mask[r * cols + c] = True
            key = mask.tobytes()
            if key in seen:
                continue
            seen.add(key)
            entries.append((rank, len(cells), order, key, family))
            order += 1
    entries.sort(key=lambda e: e[:3])
    masks = np.array([np.frombuffer(e[3], dtype=bool) for e in entries])
    masks.setflags(write=False)
    return Library(rows, cols, masks, tuple(e[4] for e in entries))


def target(name: str, size: int) -> np.ndarray:
    """A named target shape on a size x size grid, as an int8 grid.

    ``x`` and ``diamond`` are the released code's targets at 10 x 10 and 5 x 5 (SPEC 2.1, 3.1);
    the others span the grid the same way: lines through the middle (row/column ``size // 2``) or
    corner to corner, the square outline one cell in from the border, the right triangle with its
    right angle at the bottom left, the plus, diamond and oval filling the grid.
    """
    if name not in TARGETS:
        raise ValueError(f"unknown target {name!r}; expected one of {', '.join(TARGETS)}")
    middle = size // 2
    cells: Cells
    if name == "x":
        cells = x_cells(size)
    elif name == "diamond":
        cells = diamond_cells(size)
    elif name == "horizontal-line":
        cells = [(middle, c) for c in range(size)]
    elif name == "vertical-line":
        cells = [(r, middle) for r in range(size)]
    elif name == "diagonal":
        cells = [(i, i) for i in range(size)]
    elif name == "anti-diagonal":
        cells = [(i, size - 1 - i) for i in range(size)]
    elif name == "square":
        cells = _placed(square_cells(size - 2), 1, 1)
    elif name == "right-triangle":
        cells = right_triangle_cells(size, "bl")
    elif name == "plus":
        cells = plus_cells(size)
    else:
        cells = oval_cells(size, size)
    grid = np.zeros((size, size), dtype=np.int8)
    for r, c in cells:
        grid[r, c] = 1
    grid.setflags(write=False)
    return grid
