"""The paper authors' recorded GPT answers as a source of the suite (``reproduce --authors-caches``).

``DIR`` is a clone of the authors' repository (GKthom/LaGRSEQ: ``Cube_stacking/cache0.0``,
``Cube_stacking/cache0``, ``Image_completion/imagecache_init0``,
``Object_arrangement(simulated)/cache_robotgpt4``) or any folder holding the same pickles under any
names. Each file is identified by its content, never its name: the keys of a cube cache are
prefixes of one stack size's target (8 or 11 cubes), those of a grid cache are 10x10 (image
completion) or 5x5 (object arrangement) arrays. Files are read with the numpy-only
:class:`lagrseq.llm.authors_cache.RestrictedUnpickler`; anything else in DIR (sources, images,
pickles of other content) is passed over.

Every identified cache is imported, for both presets, into one store ``OUT/authors-answers`` keyed
exactly like a run's queries (the preset's model, temperature 0, max tokens). Runs then use the
provider ``recorded:OUT/authors-answers`` with misses answered by the mock; replay counts the
misses of every run from its ``/query.source`` column and shows them next to each number.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.errors import StoreError, UsageError
from lagrseq.progress import Reporter
from lagrseq.suite import AUTHORS_STORE_NAME

MAX_FILE_BYTES = 64 * 1024 * 1024
"""Largest file considered (the authors' biggest cache, the image one, is 1.3 MB)."""
MAX_FILES = 20_000
"""Files looked at in DIR before giving up (a clone of the authors' repository has a few hundred)."""
_PICKLE_PROTOCOL_BYTE = 0x80
PRESETS = ("upstream", "paper")


@dataclass(frozen=True)
class Cache:
    """One identified authors' cache."""

    path: Path
    task: str
    overrides: tuple[str, ...]
    """``--set`` values the cache's keys need (the stack size of a cube cache)."""
    pairs: int
    what: str
    """A short description for the progress line."""

    @property
    def covers(self) -> tuple[str, int]:
        """(task, stack size; 0 for grids)."""
        size = next((int(o.split("=")[1]) for o in self.overrides if o.startswith("task.stack_size=")), 0)
        return self.task, size


def _candidates(root: Path) -> Iterator[Path]:
    """Files under ``root`` that could be pickles (protocol 2+ header, size cap), in sorted order;
    ``.git`` is skipped."""
    seen = 0
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d != ".git")
        for name in sorted(files):
            seen += 1
            if seen > MAX_FILES:
                raise UsageError(f"--authors-caches {root}: more than {MAX_FILES} files; give the folder that holds the caches")
            path = Path(folder) / name
            try:
                if not path.is_file() or path.stat().st_size > MAX_FILE_BYTES:
                    continue
                with path.open("rb") as handle:
                    head = handle.read(1)
            except OSError:
                continue
            if head and head[0] == _PICKLE_PROTOCOL_BYTE:
                yield path


def identify(pairs: list[tuple[Any, Any]]) -> tuple[str, tuple[str, ...], str] | None:
    """(task, overrides, description) of a cache's (key, answer) pairs, from their content; None
    when the keys fit no task lagrseq knows. Most keys must fit (the arrangement cache starts with a
    stray 10x10 pair)."""
    from lagrseq.tasks import cube

    if not pairs:
        return None
    keys = [k for k, _ in pairs]
    shapes: dict[tuple[int, ...], int] = {}
    for key in keys:
        if isinstance(key, np.ndarray):
            shapes[key.shape] = shapes.get(key.shape, 0) + 1
    if shapes:
        shape, count = max(shapes.items(), key=lambda kv: kv[1])
        if count * 2 > len(keys):
            if shape == (10, 10):
                return "image-completion", (), f"image completion, {len(pairs)} GPT-4 answers"
            if shape == (5, 5):
                return "object-arrangement", (), f"object arrangement, {len(pairs)} GPT-4 answers"
        return None
    ids = [
        tuple(int(x) for x in k)
        for k in keys
        if isinstance(k, (list, tuple)) and k and all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in k)
    ]
    best = max(
        (sum(0 < len(k) <= size and k == target[: len(k)] for k in ids), size)
        for size, (_, target) in cube.CUBE_SETS.items()
    )
    fits, size = best
    if fits * 2 > len(keys):
        return "cube-stacking", (f"task.stack_size={size}",), f"cube stacking, {size} cubes, {len(pairs)} GPT answers"
    return None


def find_caches(root: Path, progress: Reporter | None = None) -> list[Cache]:
    """The authors' caches under ``root`` (a file or a folder), each identified by content;
    duplicates (same bytes) count once; a pickle refused as unsafe is one ``warning:`` line to
    ``progress``."""
    from lagrseq.llm.authors_cache import read_pairs

    if not root.exists():
        raise UsageError(f"--authors-caches {root}: no such file or folder; give a clone of GKthom/LaGRSEQ or a folder of its cache pickles")
    found: list[Cache] = []
    digests: set[str] = set()
    for path in [root] if root.is_file() else _candidates(root):
        try:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError:
            continue
        if digest in digests:
            continue
        try:
            pairs = read_pairs(path)
        except StoreError as exc:
            if progress is not None and "refusing" in str(exc):
                progress.say(f"warning: {exc}")
            continue
        kind = identify(pairs)
        if kind is None:
            continue
        digests.add(digest)
        task, overrides, what = kind
        found.append(Cache(path, task, overrides, len(pairs), what))
    if not found:
        raise UsageError(
            f"--authors-caches {root}: no authors' cache found (expected pickles of cube prefixes or "
            "10x10 / 5x5 grids, as in GKthom/LaGRSEQ's Cube_stacking/cache0.0 or Image_completion/imagecache_init0)"
        )
    return found


def store_path(out: Path) -> Path:
    """``OUT/authors-answers``, spelt as ``--out`` was given (a relative OUT stays relative, so
    no log, run folder or report made under it names where it lies)."""
    return out / AUTHORS_STORE_NAME


def provider_spec(out: Path) -> str:
    """The provider of the runs on the authors' answers (misses go to the mock)."""
    return f"recorded:{store_path(out).as_posix()}"


def import_caches(caches: list[Cache], out: Path, progress: Reporter | None = None) -> list[str]:
    """Import every cache for both presets into ``OUT/authors-answers``; one line per cache (a
    skipped pair: one ``note:`` line to ``progress``, once for both presets)."""
    from lagrseq.llm.authors_cache import import_authors_cache
    from lagrseq.llm.servers import DEFAULT_BASE_URL
    from lagrseq.llm.store import RecordStore, endpoint_of
    from lagrseq.running.recording import prompt_function, record_config

    def note(line: str) -> None:
        if progress is not None:
            progress.say(f"note: {line}")

    lines = []
    with RecordStore(store_path(out)) as store:
        for cache in caches:
            added = keys = skipped = 0
            for preset in PRESETS:
                config = record_config(cache.task, preset, None, cache.overrides, temperature=0.0)
                report = import_authors_cache(
                    cache.path,
                    store,
                    prompt_function(config),
                    task=cache.task,
                    model=config.llm.model,
                    temperature=0.0,
                    endpoint=endpoint_of(DEFAULT_BASE_URL),
                    max_tokens=config.llm.max_tokens,
                    reporter=Reporter(warn=note) if preset == PRESETS[0] else None,
                )
                added += report.imported
                keys = max(keys, report.keys)  # the presets' prompts may coincide
                skipped = report.skipped
            lines.append(
                f"{cache.path}: {cache.what} ({cache.pairs} pairs, {skipped} skipped); "
                f"{added} answers added under {keys} keys for the upstream and paper presets"
            )
    return lines
