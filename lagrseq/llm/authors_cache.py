"""Import the LLM caches the paper's authors published (``../shared/data/authors_caches/``).

Their format: a pickle of one flat list ``[key0, answer0, key1, answer1, ...]``. Keys are lists of
ints (cube ids) or numpy arrays (grids); answers are raw strings (cubes) or numpy arrays parsed
from the model's text (grids), and one cube cache starts with a list answer (``['e']``).

Pickles can run code, so they are read with :class:`RestrictedUnpickler`, which allows exactly
numpy's array reconstruction (``numpy.core.multiarray._reconstruct`` or its ``numpy._core``
spelling, ``numpy.ndarray``, ``numpy.dtype``) and refuses every other global before anything is
called.

The caches do not say which prompt produced an answer, only the partial pattern. The importer is
therefore handed ``prompt_for(key) -> str`` (the task's own prompt rendering, wired in by the
command line), so imported answers are keyed exactly like the queries a run sends. ``prompt_for``
raises ``ValueError`` for a key that does not fit the task (wrong shape, unknown cube); such
entries are skipped with a warning, as are answers of an unknown type or of another shape than
their key, and answers a store may not hold (longer than ``MAX_ANSWER_CHARS``, or text that is
not valid Unicode). Answers are stored as samples: the raw text where the cache has text; an array or list
written out as text and marked ``recorded_as="array"`` / ``"list"``.
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import reprlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.errors import StoreError
from lagrseq.llm.base import Message, Query, RecordedAs
from lagrseq.llm.records import MAX_ANSWER_CHARS, SAMPLE_SCHEMA, problems
from lagrseq.llm.store import RecordStore, Sample, query_key
from lagrseq.paths import open_input
from lagrseq.progress import Reporter

ALLOWED_GLOBALS = frozenset(
    {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }
)


def _reconstruct() -> Any:
    import importlib

    try:
        module = importlib.import_module("numpy._core.multiarray")  # NumPy >= 2
    except ImportError:  # pragma: no cover - NumPy 1.x
        module = importlib.import_module("numpy.core.multiarray")
    return module._reconstruct


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that can rebuild numpy arrays and plain Python data, and nothing else."""

    def __init__(self, file: io.BufferedIOBase | io.BytesIO, name: str = "pickle") -> None:
        super().__init__(file)
        self.name = name

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in ALLOWED_GLOBALS:
            raise StoreError(
                f"{self.name}: refusing to load {module}.{name}; an authors' cache may reference only "
                "numpy's array reconstruction, and this pickle could run code. Nothing was executed"
            )
        if name == "_reconstruct":
            return _reconstruct()
        return np.ndarray if name == "ndarray" else np.dtype

    def persistent_load(self, pid: Any) -> Any:
        raise StoreError(f"{self.name}: refusing a persistent id in the pickle; nothing was executed")


def read_pairs(path: str | Path) -> list[tuple[Any, Any]]:
    """The (key, answer) pairs of an authors' cache file, read with the restricted unpickler."""
    path = Path(path)
    try:
        with open_input(path, "authors' cache", StoreError) as handle:
            data = handle.read()
    except OSError as exc:
        raise StoreError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        loaded = RestrictedUnpickler(io.BytesIO(data), path.name).load()
    except StoreError:
        raise
    except Exception as exc:
        # no code runs in load (find_class allows data types only), so any failure is a malformed
        # file; its class differs between Python versions (a huge length is OverflowError on 3.13)
        raise StoreError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc})") from None
    if not isinstance(loaded, list) or len(loaded) % 2:
        shape = f"a list of {len(loaded)} items" if isinstance(loaded, list) else type(loaded).__name__
        raise StoreError(f"{path}: expected a flat list alternating key, answer; found {shape}")
    return [(loaded[i], loaded[i + 1]) for i in range(0, len(loaded), 2)]


_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = _SHORT.maxlong = 40
_SHORT.maxlist = _SHORT.maxtuple = _SHORT.maxdict = _SHORT.maxset = _SHORT.maxfrozenset = 12
MAX_WARNINGS = 1000
"""Skipped pairs named one by one in warnings; the rest are counted in one more line."""


def describe(value: Any) -> str:
    """A short description of a cache item, for warnings (in time and length bounded whatever
    its size: a cache is untrusted input)."""
    if isinstance(value, np.ndarray):
        return f"{value.dtype} array of shape {value.shape}"
    text = " ".join(_SHORT.repr(value).split())
    return text if len(text) <= 40 else text[:37] + "..."


def oversized(answer: Any) -> str | None:
    """Why an array or list ``answer`` cannot be written within MAX_ANSWER_CHARS, judged before
    writing it out (an array of millions of values took minutes and gigabytes to turn into text);
    else None (text is checked against the schema, which says how long it is)."""
    if isinstance(answer, np.ndarray):
        count, least = answer.size, 2 * answer.size - 1  # a digit and a comma per value at least
    elif isinstance(answer, (list, tuple)):
        count, least = len(answer), 3 * len(answer) - 2  # a character and ", " per item at least
    else:
        return None
    if least <= MAX_ANSWER_CHARS:
        return None
    return f"answer of {count} values cannot be stored in {MAX_ANSWER_CHARS} characters (MAX_ANSWER_CHARS)"


def array_text(array: np.ndarray) -> str:
    """An array answer written as text: JSON rows (integers when every value is whole)."""
    if array.size and np.all(np.isfinite(array)) and np.all(np.equal(np.mod(array, 1), 0)):
        return json.dumps(array.astype(int).tolist())
    return json.dumps(array.tolist())


def answer_text(answer: Any) -> tuple[str, RecordedAs] | None:
    """The text to store for a cached answer and how it was recorded; None for an unknown type."""
    if isinstance(answer, str):
        return answer, "text"
    if isinstance(answer, np.ndarray) and answer.dtype.kind in "biuf":  # not complex, object or structured
        return array_text(answer), "array"
    if isinstance(answer, (list, tuple)) and all(isinstance(x, (str, int)) and not isinstance(x, bool) for x in answer):
        return repr(list(answer)), "list"
    return None


@dataclass(frozen=True)
class ImportReport:
    """What an import did."""

    pairs: int
    imported: int
    """Samples added to the store."""
    already_present: int
    """Samples the store already held (a repeated import adds nothing)."""
    skipped: int
    keys: int
    """Distinct keys the imported samples fall under."""


def import_authors_cache(
    path: str | Path,
    store: RecordStore,
    prompt_for: Callable[[Any], str],
    *,
    task: str,
    model: str,
    temperature: float,
    endpoint: str,
    max_tokens: int,
    top_p: float = 1.0,
    reporter: Reporter | None = None,
) -> ImportReport:
    """Import every usable pair of an authors' cache into ``store`` (module docstring); each
    skipped pair is a warning to ``reporter`` (the first :data:`MAX_WARNINGS`; None: none)."""
    reporter = reporter or Reporter.silent()
    path = Path(path)
    pairs = read_pairs(path)
    with open_input(path, "authors' cache", StoreError) as handle:
        digest = hashlib.sha256(handle.read()).hexdigest()
    groups: dict[str, tuple[dict[str, Any], list[Sample]]] = {}
    skipped = 0
    for index, (key, answer) in enumerate(pairs):
        try:
            prompt, text, recorded_as = _usable(key, answer, prompt_for, task)
            sample = _sample(text, recorded_as, model, path, digest, index)
        except _Skip as why:
            skipped += 1
            if skipped <= MAX_WARNINGS:
                reporter.warn(f"{path.name}: skipping pair {index}: {why}")
            continue
        query = Query(
            task=task, model=model, messages=(Message("user", prompt),), temperature=temperature, max_tokens=max_tokens,
            top_p=top_p,
        )
        record_key, request = query_key(query, endpoint)
        groups.setdefault(record_key, (request, []))[1].append(sample)
    if skipped > MAX_WARNINGS:
        reporter.warn(f"{path.name}: skipped {skipped - MAX_WARNINGS} more pairs (the first {MAX_WARNINGS} are named above)")
    imported = _add(store, task, groups)
    usable = len(pairs) - skipped
    return ImportReport(
        pairs=len(pairs),
        imported=imported,
        already_present=usable - imported,
        skipped=skipped,
        keys=len(groups),
    )


class _Skip(Exception):
    """A pair that cannot be imported: why (one line)."""


def _usable(key: Any, answer: Any, prompt_for: Callable[[Any], str], task: str) -> tuple[str, str, RecordedAs]:
    """A pair's prompt and its answer as text and how it was recorded; :class:`_Skip` for a pair
    whose key does not fit the task or whose answer cannot be stored."""
    try:
        prompt = prompt_for(key)
    except ValueError as exc:
        why = " ".join(str(exc).split())
        raise _Skip(f"key {describe(key)} does not fit task {task}: {why if len(why) <= 160 else why[:157] + '...'}") from None
    if isinstance(answer, np.ndarray) and isinstance(key, np.ndarray) and answer.shape != key.shape:
        raise _Skip(f"answer shape {answer.shape} differs from key shape {key.shape}")
    too_large = oversized(answer)
    if too_large is not None:
        raise _Skip(too_large)
    written = answer_text(answer)
    if written is None:
        raise _Skip(f"answer {describe(answer)} is neither text nor a list or an array of numbers")
    return prompt, *written


def _sample(text: str, recorded_as: RecordedAs, model: str, path: Path, digest: str, index: int) -> Sample:
    """Pair ``index`` of the cache at ``path`` (content ``digest``) as a stored sample; :class:`_Skip`
    where it breaks the sample schema (e.g. longer than MAX_ANSWER_CHARS, or text that is not
    valid Unicode)."""
    sample = Sample(
        id=hashlib.sha256(f"authors-cache|{digest}|{index}".encode()).hexdigest()[:24],
        text=text,
        origin="authors-cache",
        model=model,
        recorded_as=recorded_as,
        provenance=f"{path.name} pair {index} (sha256 {digest[:12]})",
    )
    wrong = problems(sample.to_json(), SAMPLE_SCHEMA, root="answer", limit=1)
    if wrong:
        raise _Skip(wrong[0])
    return sample


def _add(store: RecordStore, task: str, groups: dict[str, tuple[dict[str, Any], list[Sample]]]) -> int:
    """Add each key's samples to ``store``; how many it did not hold before."""
    imported = 0
    for record_key, (request, samples) in groups.items():
        before = store.entry(record_key)
        count_before = len(before.samples) if before else 0
        imported += store.add(record_key, request, task, samples) - count_before
    return imported
