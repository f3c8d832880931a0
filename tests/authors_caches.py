"""The authors' grid caches for tests (../shared/data/authors_caches, never copied into the repo),
read with lagrseq's own numpy-only unpickler."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lagrseq.llm.authors_cache import read_pairs
from tests.conftest import AUTHORS_CACHES


def grid_pairs(name: str, shape: tuple[int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(key, answer) pairs of a grid cache as int8 grids; pairs of another shape (the 10x10 seed
    pair copied into the arrangement cache) are skipped with a warning."""
    path = AUTHORS_CACHES / name
    if not path.exists():
        pytest.skip(f"authors' cache {path} is not present (it lives in the shared/ folder beside the repo)")
    pairs = []
    for key, answer in read_pairs(path):
        if np.shape(key) != shape or np.shape(answer) != shape:
            warnings.warn(
                f"{name}: skipping a {np.shape(key)} -> {np.shape(answer)} pair (expected {shape})",
                stacklevel=2,
            )
            continue
        pairs.append((np.asarray(key).astype(np.int8), np.asarray(answer).astype(np.int8)))
    return pairs
