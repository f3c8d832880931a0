"""Shared fixtures: the authors' recorded caches (read from ../shared at test time, never copied)."""

from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
AUTHORS_CACHES = SHARED / "data" / "authors_caches"

_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
}


class _NumpyOnly(pickle.Unpickler):
    def find_class(self, module: str, name: str):  # type: ignore[override]
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(f"global {module}.{name} is not allowed")
        if name == "_reconstruct":
            import importlib

            core = "numpy._core.multiarray" if hasattr(np, "_core") else "numpy.core.multiarray"
            return importlib.import_module(core)._reconstruct
        return getattr(np, name)


def load_authors_cache(name: str) -> list:
    """A flat [key, answer, key, answer, ...] list, read with a numpy-only unpickler."""
    path = AUTHORS_CACHES / name
    if not path.exists():
        pytest.skip(f"authors' cache {path} not present (it lives in ../shared/data)")
    return _NumpyOnly(io.BytesIO(path.read_bytes())).load()


@pytest.fixture
def cube_cache_8() -> list:
    return load_authors_cache("cube_stacking_cache0.0.pkl")


@pytest.fixture
def cube_cache_11() -> list:
    return load_authors_cache("cube_stacking_cache0.pkl")
