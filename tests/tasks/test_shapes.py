"""The shape library: the released targets, every target in the library, order and uniqueness."""

from __future__ import annotations

import numpy as np
import pytest

from lagrseq.tasks import shapes
from lagrseq.tasks.grid import grid_of

# SPEC 2.1 and 3.1, copied by hand from the released code's ideal_im arrays.
UPSTREAM_X = grid_of(
    ["1000000001", "0100000010", "0010000100", "0001001000", "0000110000",
     "0000110000", "0001001000", "0010000100", "0100000010", "1000000001"]
)  # fmt: skip
UPSTREAM_DIAMOND = grid_of(["00100", "01010", "10001", "01010", "00100"])


def test_released_targets() -> None:
    assert np.array_equal(shapes.target("x", 10), UPSTREAM_X)
    assert np.array_equal(shapes.target("diamond", 5), UPSTREAM_DIAMOND)
    assert int(UPSTREAM_X.sum()) == 20 and int(UPSTREAM_DIAMOND.sum()) == 8


@pytest.mark.parametrize("size", [5, 10])
@pytest.mark.parametrize("name", shapes.TARGETS)
def test_every_target_is_a_library_shape_of_its_family(name: str, size: int) -> None:
    grid = shapes.target(name, size)
    assert grid.shape == (size, size) and set(np.unique(grid)) <= {0, 1} and grid.sum() >= size
    lib = shapes.library(size, size)
    index = lib.index(grid)
    assert index is not None
    assert lib.families[index] == name


def test_scaled_targets_look_as_named() -> None:
    assert np.array_equal(shapes.target("horizontal-line", 5), grid_of(["00000"] * 2 + ["11111"] + ["00000"] * 2))
    assert np.array_equal(shapes.target("square", 5), grid_of(["00000", "01110", "01010", "01110", "00000"]))
    assert np.array_equal(shapes.target("plus", 5), grid_of(["00100", "00100", "11111", "00100", "00100"]))
    assert np.array_equal(shapes.target("oval", 5), grid_of(["01110", "10001", "10001", "10001", "01110"]))
    assert np.array_equal(
        shapes.target("right-triangle", 5), grid_of(["10000", "11000", "10100", "10010", "11111"])
    )
    with pytest.raises(ValueError, match="unknown target"):
        shapes.target("heart", 5)


def test_library_is_ordered_simplest_first_and_has_no_duplicates() -> None:
    lib = shapes.library(10, 10)
    ranks = [shapes.FAMILIES.index(f) for f in lib.families]
    assert ranks == sorted(ranks)
    assert len({m.tobytes() for m in lib.masks}) == len(lib)
    for family in shapes.FAMILIES:
        cells = [int(m.sum()) for m, f in zip(lib.masks, lib.families, strict=True) if f == family]
        assert cells == sorted(cells), family
    assert lib.families[0] == "horizontal-line" and lib.masks[0].sum() == 10
    # every position and size: e.g. all 8 x 8 square outlines of a 10 x 10 grid
    squares8 = [m for m, f in zip(lib.masks, lib.families, strict=True) if f == "square" and m.sum() == 28]
    assert len(squares8) == 9  # an 8 x 8 outline has 28 cells and fits at 3 x 3 positions
    assert len([f for f in lib.families if f == "horizontal-line"]) == 10


def test_containing_finds_exactly_the_supersets() -> None:
    lib = shapes.library(5, 5)
    on = np.zeros(25, dtype=bool)
    on[[2, 6]] = True  # (0, 2) and (1, 1)
    found = lib.containing(on)
    assert found.size > 0
    assert all(lib.masks[k][on].all() for k in found)
    others = np.setdiff1d(np.arange(len(lib)), found)
    assert not any(lib.masks[k][on].all() for k in others)
    assert np.array_equal(lib.containing(np.zeros(25, dtype=bool)), np.arange(len(lib)))


def test_config_offers_exactly_the_library_targets() -> None:
    """config.py may not import tasks/, so it spells the target names out; they must agree."""
    from typing import get_args

    from lagrseq.config import GridTarget
    from lagrseq.tasks.shapes import TARGETS

    assert get_args(GridTarget) == TARGETS
