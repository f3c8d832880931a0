"""Read the authors' recorded caches (../shared/data/authors_caches, never copied into the repo)
with a restricted unpickler that rebuilds numpy arrays and nothing else."""

from __future__ import annotations

import importlib
import io
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest

AUTHORS_CACHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "authors_caches"

_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
}


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Allows numpy's array reconstruction globals; refuses every other global."""

    def find_class(self, module: str, name: str):  # type: ignore[no-untyped-def]
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(f"global {module}.{name} is not allowed in an authors' cache")
        if name == "_reconstruct":
            core = "numpy._core.multiarray" if hasattr(np, "_core") else "numpy.core.multiarray"
            return importlib.import_module(core)._reconstruct
        return getattr(np, name)


def load_flat(name: str) -> list:
    """The flat [key, answer, key, answer, ...] list of one cache; skips the test if absent."""
    path = AUTHORS_CACHES / name
    if not path.exists():
        pytest.skip(f"authors' cache {path} is not present (it lives in the shared/ folder beside the repo)")
    return NumpyOnlyUnpickler(io.BytesIO(path.read_bytes())).load()


def grid_pairs(name: str, shape: tuple[int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(key, answer) pairs of a grid cache as int8 grids; pairs of another shape (the 10x10 seed
    pair copied into the arrangement cache) are skipped with a warning."""
    flat = load_flat(name)
    pairs = []
    for key, answer in zip(flat[0::2], flat[1::2], strict=True):
        if np.shape(key) != shape or np.shape(answer) != shape:
            warnings.warn(
                f"{name}: skipping a {np.shape(key)} -> {np.shape(answer)} pair (expected {shape})",
                stacklevel=2,
            )
            continue
        pairs.append((np.asarray(key).astype(np.int8), np.asarray(answer).astype(np.int8)))
    return pairs
