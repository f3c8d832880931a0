"""The recorded-answer store: several samples per query key, on disk, safe to share.

Key (DESIGN section 4). A query's key is the sha256 of the key-sorted, compact JSON of::

    {"key_version": 1, "endpoint": "api.openai.com", "model": ..., "messages": [{"role", "content"}],
     "temperature": float, "top_p": float, "max_tokens": int | null, "stop": [str] | null,
     "seed": int | null}

with the API's defaults written in (``top_p`` 1.0, ``stop`` null, ``seed`` null are spelled out,
numbers are normalised so that 0 and 0.0 give one key). Left out, because they do not change what
one sample is: ``n``, ``stream``, ``user`` and the API key. ``endpoint`` is the server's host
(``host:port`` when the port is not the scheme's default), so answers of a local vLLM server never
answer for OpenAI's. The task is kept beside the key, not in it (the server never sees it).

Runtime form: a diskcache ``Cache`` directory whose keys and values are JSON only (values are
``{"request", "task", "samples"}``), ``eviction_policy="none"`` (a recording is never dropped), and
every read-modify-write inside ``transact()``, so several processes can record into one store at
once without losing a sample. diskcache's default disk pickles, and even its ``JSONDisk`` will
unpickle a row whose stored mode says "pickle" (CVE-2025-69872); :class:`JSONOnlyDisk` refuses such
rows, so a store directory someone else could write to cannot run code here.

Portable form: JSONL, one sample per line (``recorded_llm/README.md`` documents it), written by
:func:`export_jsonl` in a stable order and read back by :func:`import_jsonl`. Sample ids make
imports idempotent: importing the same file twice adds nothing.

Which sample a query receives is :func:`pick_index` of (run seed, key, occurrence): the same
trial asking the same key for the n-th time always gets the same sample from the same store.
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import json
import os
import sqlite3
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any
from urllib.parse import urlsplit

import diskcache
import numpy as np
from diskcache.core import MODE_BINARY, MODE_PICKLE, MODE_RAW

from lagrseq.errors import StoreError
from lagrseq.llm.base import Answer, Query, RecordedAs, Usage
from lagrseq.llm.servers import DEFAULT_BASE_URL  # noqa: F401 - re-exported for callers

KEY_VERSION = 1
STORE_FORMAT = "lagrseq.recorded-store"
JSONL_FORMAT = "lagrseq.recorded/1"
META_KEY = "lagrseq-store"
_DEFAULT_PORTS = {"http": 80, "https": 443}


# ------------------------------------------------------------------------------------------
# Keys
# ------------------------------------------------------------------------------------------
def endpoint_of(base_url: str) -> str:
    """The endpoint part of a key: the lower-cased host, with the port when it is not the
    scheme's default (``https://api.openai.com/v1`` -> ``api.openai.com``)."""
    parts = urlsplit(base_url if "://" in base_url else f"https://{base_url}")
    host = (parts.hostname or "").lower()
    if not host:
        raise StoreError(f"base URL {base_url!r} has no host; expected e.g. https://api.openai.com/v1")
    try:
        port = parts.port
    except ValueError:
        raise StoreError(f"base URL {base_url!r} has a bad port") from None
    if port is not None and port != _DEFAULT_PORTS.get(parts.scheme):
        return f"{host}:{port}"
    return host


def request_of(query: Query, endpoint: str) -> dict[str, Any]:
    """The canonical request a key is the hash of (module docstring)."""
    return {
        "key_version": KEY_VERSION,
        "endpoint": endpoint,
        "model": query.model,
        "messages": [{"role": m.role, "content": m.content} for m in query.messages],
        "temperature": float(query.temperature),
        "top_p": float(query.top_p),
        "max_tokens": None if query.max_tokens is None else int(query.max_tokens),
        "stop": list(query.stop) if query.stop else None,
        "seed": None if query.seed is None else int(query.seed),
    }


def key_of_request(request: dict[str, Any]) -> str:
    text = json.dumps(request, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(text.encode()).hexdigest()


def query_key(query: Query, endpoint: str) -> tuple[str, dict[str, Any]]:
    """``(key, request)`` of a query sent to ``endpoint``."""
    request = request_of(query, endpoint)
    return key_of_request(request), request


def pick_index(run_seed: int, key: str, occurrence: int, count: int) -> int:
    """Which of ``count`` samples the ``occurrence``-th query of ``key`` in a run receives: a
    uniform draw from a generator seeded by (run seed, key, occurrence), so it depends on nothing
    else (not on the order of other queries, the process or the number of trials)."""
    if count <= 0:
        raise ValueError("no samples to choose from")
    sequence = np.random.SeedSequence([int(run_seed) & (2**64 - 1), int(key, 16), int(occurrence)])
    return int(np.random.Generator(np.random.PCG64(sequence)).integers(count))


class SampleChooser:
    """Counts the occurrences of each key in one run and picks samples with :func:`pick_index`."""

    def __init__(self, run_seed: int) -> None:
        self.run_seed = int(run_seed)
        self.occurrences: dict[str, int] = {}

    def choose(self, key: str, count: int) -> int:
        occurrence = self.occurrences.get(key, 0)
        self.occurrences[key] = occurrence + 1
        return pick_index(self.run_seed, key, occurrence, count)


# ------------------------------------------------------------------------------------------
# Samples and entries
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sample:
    """One recorded answer of a key."""

    id: str
    """Unique id (imports skip samples whose id the key already has)."""
    text: str
    origin: str
    """Where it came from: ``live`` (recorded from a server), ``authors-cache`` (imported pickle)."""
    model: str | None = None
    """Model the server reported (for imports: the model the importer was told)."""
    recorded_as: RecordedAs = "text"
    usage: Usage | None = None
    """Token counts the server reported; None when unknown (the authors' caches have none)."""
    finish_reason: str | None = None
    system_fingerprint: str | None = None
    latency_s: float | None = None
    cost_usd: float | None = None
    """What the sample cost when recorded (None: unknown or unpriced)."""
    recorded_at: str | None = None
    """UTC time of recording, ISO 8601 (None for imports of undated caches)."""
    provenance: str | None = None
    """Free text: e.g. the pickle file and pair index an imported sample came from."""

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["usage"] = None if self.usage is None else asdict(self.usage)
        return data

    @classmethod
    def from_json(cls, data: Any, where: str = "sample") -> Sample:
        if not isinstance(data, dict):
            raise StoreError(f"{where}: expected a JSON object, found {type(data).__name__}")
        names = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(data) - names)
        if unknown:
            raise StoreError(f"{where}: unknown field {unknown[0]!r}; fields are {', '.join(sorted(names))}")
        for required in ("id", "text", "origin"):
            if not isinstance(data.get(required), str):
                raise StoreError(f"{where}: field {required!r} must be a string, found {data.get(required)!r}")
        if data.get("recorded_as", "text") not in ("text", "array", "list"):
            raise StoreError(f"{where}: recorded_as must be text, array or list, found {data['recorded_as']!r}")
        usage = data.get("usage")
        if usage is not None:
            if not isinstance(usage, dict) or not all(
                isinstance(usage.get(k, 0), int) for k in ("prompt_tokens", "completion_tokens", "cached_tokens")
            ):
                raise StoreError(f"{where}: usage must hold integer token counts, found {usage!r}")
            usage = Usage(
                int(usage.get("prompt_tokens", 0)),
                int(usage.get("completion_tokens", 0)),
                int(usage.get("cached_tokens", 0)),
            )
        return cls(**{**data, "usage": usage})

    def answer(self, key: str, index: int) -> Answer:
        """This sample served as a recorded answer (it costs nothing now)."""
        return Answer(
            text=self.text,
            source="recorded",
            model=self.model or "",
            usage=self.usage or Usage(),
            finish_reason=self.finish_reason,
            latency_s=0.0,
            cost_usd=0.0,
            system_fingerprint=self.system_fingerprint,
            record_key=key,
            sample_index=index,
            recorded_as=self.recorded_as,
        )


def sample_from_answer(answer: Answer, key: str, recorded_at: str | None = None) -> Sample:
    """A live answer as a sample to store (its id is unique to this answer)."""
    recorded_at = recorded_at or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    seed = f"{key}|{answer.response_id}|{answer.sample_index}|{time.time_ns()}|{os.getpid()}|{id(answer)}"
    return Sample(
        id=hashlib.sha256(seed.encode()).hexdigest()[:24],
        text=answer.text,
        origin=answer.source,
        model=answer.model,
        recorded_as="text",
        usage=answer.usage,
        finish_reason=answer.finish_reason,
        system_fingerprint=answer.system_fingerprint,
        latency_s=answer.latency_s,
        cost_usd=answer.cost_usd,
        recorded_at=recorded_at,
        provenance=answer.response_id,
    )


@dataclass(frozen=True)
class Entry:
    """Everything recorded for one key."""

    key: str
    request: dict[str, Any]
    task: str | None
    samples: tuple[Sample, ...] = field(default_factory=tuple)

    def describe(self) -> str:
        """``model M, temperature T, endpoint E, N samples`` (for messages)."""
        r = self.request
        return (
            f"model {r.get('model')}, temperature {r.get('temperature')}, endpoint {r.get('endpoint')}, "
            f"{len(self.samples)} sample{'s' if len(self.samples) != 1 else ''}"
        )

    @property
    def prompt(self) -> str:
        messages = self.request.get("messages") or [{}]
        return str(messages[-1].get("content", ""))


# ------------------------------------------------------------------------------------------
# The diskcache store
# ------------------------------------------------------------------------------------------
class JSONOnlyDisk(diskcache.JSONDisk):
    """diskcache's JSONDisk, minus every path that can unpickle.

    JSONDisk writes keys as raw bytes and values as bytes (modes raw and binary), but it reads with
    the base class, which unpickles a key row whose ``raw`` flag is 0 and a value row whose mode is
    "pickle". Rows like that can only come from another writer; refuse them.
    """

    def get(self, key: Any, raw: bool) -> Any:
        if not raw:
            raise StoreError(
                f"store {self._directory} holds a pickled key; lagrseq stores are JSON only and never "
                "unpickle (a pickle can run code). Do not use this directory as a lagrseq store"
            )
        return self._json(diskcache.Disk.get(self, key, raw), "key")

    def fetch(self, mode: int, filename: str | None, value: Any, read: bool) -> Any:
        if mode not in (MODE_RAW, MODE_BINARY) or read:
            raise StoreError(
                f"store {self._directory} holds a value stored as {'pickle' if mode == MODE_PICKLE else f'mode {mode}'}; "
                "lagrseq stores are JSON only and never unpickle. Do not use this directory as a lagrseq store"
            )
        return self._json(diskcache.Disk.fetch(self, mode, filename, value, read), "value")

    def _json(self, data: Any, what: str) -> Any:
        try:
            if not isinstance(data, bytes):
                raise TypeError(type(data).__name__)
            return json.loads(zlib.decompress(data).decode("utf-8"))
        except (TypeError, zlib.error, UnicodeDecodeError, ValueError):
            raise StoreError(
                f"store {self._directory} holds a {what} that lagrseq did not write (not compressed "
                "JSON); do not use this directory as a lagrseq store"
            ) from None


_FOREIGN = (sqlite3.Error, diskcache.Timeout, OSError, json.JSONDecodeError, UnicodeDecodeError, ValueError)


@contextlib.contextmanager
def _translated(directory: Path, action: str) -> Iterator[None]:
    try:
        yield
    except StoreError:
        raise
    except _FOREIGN as exc:
        raise StoreError(f"store {directory}: could not {action} ({type(exc).__name__}: {exc})") from None


class RecordStore:
    """A directory of recorded answers (module docstring). A context manager; ``close`` is
    idempotent. ``create=False`` refuses a directory that is not already a store."""

    def __init__(self, directory: str | Path, create: bool = True, timeout_s: float = 60.0) -> None:
        self.directory = Path(directory)
        if not create and not (self.directory / "cache.db").is_file():
            raise StoreError(
                f"no recorded store at {self.directory}; create one with `lagrseq record` or "
                "`lagrseq cache import`"
            )
        if self.directory.exists() and not self.directory.is_dir():
            raise StoreError(f"store path {self.directory} is a file; expected a directory")
        with _translated(self.directory, "open it"):
            self._cache = diskcache.Cache(
                str(self.directory),
                disk=JSONOnlyDisk,
                eviction_policy="none",
                timeout=timeout_s,
                statistics=False,
                tag_index=False,
            )
        self._closed = False
        try:
            self._check_header()
        except BaseException:
            self.close()
            raise

    def _check_header(self) -> None:
        with _translated(self.directory, "read its header"), self._cache.transact(retry=True):
            meta = self._cache.get(META_KEY)
            if meta is None:
                if len(self._cache):
                    raise StoreError(
                        f"{self.directory} holds a diskcache that is not a lagrseq store; use another directory"
                    )
                self._cache.set(META_KEY, {"format": STORE_FORMAT, "version": 1})
            elif not isinstance(meta, dict) or meta.get("format") != STORE_FORMAT:
                raise StoreError(f"{self.directory} is not a lagrseq store (header {meta!r})")

    # ------------------------------------------------------------------ reading
    def entry(self, key: str) -> Entry | None:
        with _translated(self.directory, f"read key {key[:12]}"):
            value = self._cache.get(key)
        return None if value is None else self._entry(key, value)

    def _entry(self, key: str, value: Any) -> Entry:
        where = f"store {self.directory}, key {key[:12]}"
        if not isinstance(value, dict) or not isinstance(value.get("request"), dict):
            raise StoreError(f"{where}: not a lagrseq entry")
        samples = tuple(
            Sample.from_json(s, f"{where}, sample {i}") for i, s in enumerate(value.get("samples", []))
        )
        return Entry(key, value["request"], value.get("task"), samples)

    def keys(self) -> list[str]:
        with _translated(self.directory, "list its keys"):
            return sorted(k for k in self._cache.iterkeys() if isinstance(k, str) and k != META_KEY)

    def entries(self) -> Iterator[Entry]:
        """Every entry, in key order."""
        for key in self.keys():
            found = self.entry(key)
            if found is not None:
                yield found

    def __len__(self) -> int:
        return len(self.keys())

    # ------------------------------------------------------------------ writing
    def add(self, key: str, request: dict[str, Any], task: str | None, samples: list[Sample] | tuple[Sample, ...]) -> int:
        """Append the samples whose ids the key does not have yet, atomically (one transaction);
        return how many the key holds afterwards."""
        if key_of_request(request) != key:
            raise StoreError(f"key {key[:12]} is not the hash of its request; refusing to store it")
        with _translated(self.directory, f"write key {key[:12]}"), self._cache.transact(retry=True):
            value = self._cache.get(key)
            if value is None:
                value = {"request": request, "task": task, "samples": []}
            have = {s.get("id") for s in value["samples"] if isinstance(s, dict)}
            added = [s.to_json() for s in samples if s.id not in have]
            if added:
                value["samples"] = list(value["samples"]) + added
                if value.get("task") is None:
                    value["task"] = task
                self._cache.set(key, value)
            return len(value["samples"])

    # ------------------------------------------------------------------ misses
    def nearest(self, request: dict[str, Any], task: str | None = None, limit: int = 3) -> list[tuple[Entry, str]]:
        """The recorded entries most like ``request`` and, for each, how it differs: same prompt
        with other settings first, then the most similar prompts of the same task."""
        prompt = str(request["messages"][-1]["content"]) if request.get("messages") else ""
        scored: list[tuple[float, str, Entry, str]] = []
        for entry in self.entries():
            if task is not None and entry.task not in (None, task):
                continue
            differences = [
                f"{name} {entry.request.get(name)!r} instead of {request.get(name)!r}"
                for name in ("endpoint", "model", "temperature", "top_p", "max_tokens", "stop", "seed")
                if entry.request.get(name) != request.get(name)
            ]
            same_messages = entry.request.get("messages") == request.get("messages")
            if same_messages:
                similarity = 2.0
            else:
                matcher = difflib.SequenceMatcher(None, entry.prompt, prompt, autojunk=False)
                similarity = matcher.ratio()
                differences.insert(0, f"another prompt ({similarity:.1%} alike{_diff_hint(entry.prompt, prompt)})")
            score = similarity - 0.1 * len(differences)
            scored.append((-score, entry.key, entry, "; ".join(differences) or "identical"))
        scored.sort(key=lambda item: (item[0], item[1]))
        return [(entry, why) for _, _, entry, why in scored[:limit]]

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._cache.close()

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RecordStore({str(self.directory)!r})"


def _diff_hint(recorded: str, asked: str) -> str:
    """Where two prompts first differ, e.g. ``; differs at ...['e','f']`` (the end of prompts
    holds the partial pattern, which is what usually differs)."""
    i = 0
    while i < min(len(recorded), len(asked)) and recorded[i] == asked[i]:
        i += 1
    if i == len(recorded) == len(asked):
        return ""
    snippet = " ".join(recorded[i : i + 40].split())
    return f"; recorded text from the first difference: {snippet!r}"


# ------------------------------------------------------------------------------------------
# The strict-miss message
# ------------------------------------------------------------------------------------------
def miss_message(store: RecordStore, key: str, request: dict[str, Any], task: str | None) -> str:
    """One line: what was asked (task, model, temperature, key), the nearest recorded keys and how
    they differ, and what to do."""
    near = store.nearest(request, task)
    if near:
        listing = " | ".join(f"{e.key[:12]} ({e.describe()}; {why})" for e, why in near)
        nearest = f"nearest recorded keys: {listing}"
    else:
        nearest = "the store is empty"
    return (
        f"no recorded answer in {store.directory} for task {task}, model {request['model']}, "
        f"temperature {request['temperature']}, endpoint {request['endpoint']} (key {key[:12]}); "
        f"{nearest}. Record it with `lagrseq record`, or run with --on-miss mock|live"
    )


# ------------------------------------------------------------------------------------------
# JSONL
# ------------------------------------------------------------------------------------------
def jsonl_lines(store: RecordStore) -> Iterator[str]:
    """The store as JSONL lines: keys in order, samples in recorded order."""
    for entry in store.entries():
        for index, sample in enumerate(entry.samples):
            record = {
                "format": JSONL_FORMAT,
                "key": entry.key,
                "task": entry.task,
                "request": entry.request,
                "index": index,
                "sample": sample.to_json(),
            }
            yield json.dumps(record, sort_keys=True, ensure_ascii=False, separators=(", ", ": "))


@dataclass(frozen=True)
class JsonlReport:
    """What an export or import did."""

    lines: int
    keys: int
    added: int = 0
    already_present: int = 0


def export_jsonl(store: RecordStore, out: IO[str]) -> JsonlReport:
    """Write every sample as one JSON line to ``out``."""
    lines = 0
    keys: set[str] = set()
    for line in jsonl_lines(store):
        out.write(line + "\n")
        lines += 1
        keys.add(json.loads(line)["key"])
    return JsonlReport(lines=lines, keys=len(keys))


def import_jsonl(
    source: IO[str], store: RecordStore, name: str = "JSONL", warn: Callable[[str], None] | None = None
) -> JsonlReport:
    """Add every sample of a JSONL export to ``store`` (samples already there are skipped).

    The key of each line is recomputed from its request, which is the truth: a hand-edited request
    files its samples under the new key (with a warning naming the line)."""
    groups: dict[str, tuple[dict[str, Any], str | None, list[Sample]]] = {}
    lines = 0
    for number, raw in enumerate(source, 1):
        if not raw.strip():
            continue
        where = f"{name} line {number}"
        try:
            record = json.loads(raw)
        except json.JSONDecodeError as exc:
            raise StoreError(f"{where}: not JSON ({exc.msg} at column {exc.colno})") from None
        if not isinstance(record, dict) or record.get("format") != JSONL_FORMAT:
            found = record.get("format") if isinstance(record, dict) else type(record).__name__
            raise StoreError(f"{where}: expected a {JSONL_FORMAT!r} record, found format {found!r}")
        request = record.get("request")
        if not isinstance(request, dict) or not isinstance(request.get("messages"), list):
            raise StoreError(f"{where}: 'request' must be an object with 'messages'")
        if request.get("key_version") != KEY_VERSION:
            raise StoreError(
                f"{where}: key_version {request.get('key_version')!r}; this lagrseq reads version {KEY_VERSION}"
            )
        key = key_of_request(request)
        if record.get("key") != key and warn is not None:
            warn(f"{where}: key {str(record.get('key'))[:12]} does not match its request; filed under {key[:12]}")
        sample = Sample.from_json(record.get("sample"), where)
        task = record.get("task")
        groups.setdefault(key, (request, task if isinstance(task, str) else None, []))[2].append(sample)
        lines += 1
    added = 0
    for key, (request, task, samples) in groups.items():
        before = store.entry(key)
        count_before = len(before.samples) if before else 0
        added += store.add(key, request, task, samples) - count_before
    return JsonlReport(lines=lines, keys=len(groups), added=added, already_present=lines - added)
