"""Shared fixtures: the authors' recorded caches (read from ../shared at test time, never copied)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from lagrseq import keys
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


@pytest.fixture(autouse=True)
def fresh_key_guard(monkeypatch: pytest.MonkeyPatch) -> None:
    """The process-wide key guard (:mod:`lagrseq.keys`) forgets, after each test, the variables
    and secrets the test made it watch (a provider's --api-key-env, a robot token): a command
    is one process, the tests share one, and a test's secret must not blank another's output."""
    monkeypatch.setattr(keys, "_watched", dict(keys._watched))
    monkeypatch.setattr(keys, "_remembered", dict(keys._remembered))


@pytest.fixture(autouse=True)
def _native_numerics(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test starts with the machine's own numerics (LAGRSEQ_NUMERICS unset), whatever the
    shell that started pytest set: the golden-log and determinism tests are native by definition;
    a test that wants ``perturbed`` sets it itself."""
    monkeypatch.delenv("LAGRSEQ_NUMERICS", raising=False)
