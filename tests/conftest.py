"""Shared fixtures: the authors' recorded caches (read from ../shared at test time, never copied)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from lagrseq.llm.authors_cache import read_pairs

# CI explores the same examples on every run (a red CI is then reproducible), and keeps no
# example database; a developer's run draws new examples each time and remembers failures.
settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


SHARED = Path(os.environ.get("LAGRSEQ_SHARED") or Path(__file__).resolve().parents[1].parent / "shared")
"""The shared/ folder beside the repository (``LAGRSEQ_SHARED`` names another, e.g. from a worktree)."""
AUTHORS_CACHES = SHARED / "data" / "authors_caches"


def load_authors_cache(name: str) -> list:
    """A flat [key, answer, key, answer, ...] list, read with lagrseq's numpy-only unpickler."""
    path = AUTHORS_CACHES / name
    if not path.exists():
        pytest.skip(f"authors' cache {path} not present (it lives in ../shared/data)")
    return [item for pair in read_pairs(path) for item in pair]


@pytest.fixture
def cube_cache_8() -> list:
    return load_authors_cache("cube_stacking_cache0.0.pkl")


@pytest.fixture
def cube_cache_11() -> list:
    return load_authors_cache("cube_stacking_cache0.pkl")
