"""The recorded-answer store: several samples per query key, on disk, safe to share.

Key (DESIGN section 4). A query's key is the sha256 of the key-sorted, compact JSON of::

    {"key_version": 1, "endpoint": "api.openai.com", "model": ..., "messages": [{"role", "content"}],
     "temperature": float, "top_p": float, "max_tokens": int | null, "stop": [str] | null,
     "seed": int | null}

with the API's defaults written in (``top_p`` 1.0, ``stop`` null, ``seed`` null are spelled out,
numbers are normalised so that 0 and 0.0 give one key). A query that pins llama.cpp's samplers
(``top_k``, ``min_p``, ``repeat_penalty``: every query served by llama.cpp, see
:data:`lagrseq.llm.servers.LLAMA_CPP_SAMPLERS`) adds them to the JSON; a query without them keeps
the key it always had, so every store recorded before they existed is still found. Left out, because they do not change what
one sample is: ``n``, ``stream``, ``user`` and the API key. ``endpoint`` is the server's host
(``host:port`` when the port is not the scheme's default), so answers of a local vLLM server never
answer for OpenAI's. The task is kept beside the key, not in it (the server never sees it).

Runtime form: a diskcache ``Cache`` directory whose keys and values are JSON only (values are
``{"request", "task", "samples"}``), ``eviction_policy="none"`` (a recording is never dropped), and
every read-modify-write inside ``transact()``, so several processes can record into one store at
once without losing a sample. diskcache's default disk pickles, and even its ``JSONDisk`` will
unpickle a row whose stored mode says "pickle" (CVE-2025-69872); :class:`JSONOnlyDisk` refuses such
rows, so a store directory someone else could write to cannot run code here. Reading never
writes: rows are read through a read-only SQLite connection (:class:`ReadOnlyDatabase`), and the
diskcache that writes is opened only for the first write, so a read-only store can be read. Every
row is checked when read and every sample before it is written (:mod:`lagrseq.llm.records`).

Claims: several ``lagrseq record`` processes into one store share what they record. Before a
recorder pays for a key it takes the key's claim (:meth:`RecordStore.claim`: an exclusive
``flock`` on ``claims/KEY.lock`` in the store directory, which the kernel releases when the
holder dies, so a killed recorder leaves no stale claim), reads the key again, and asks only for
what it still lacks; the claim is let go after the answers are stored. A key claimed elsewhere is
left for later. Left over: answers paid for by a process killed before it stored them are paid
again; ``--mode all`` pays by design; on a file system whose ``flock`` does not reach other
machines (some network file systems) recorders there may still pay twice.

Portable form: JSONL, one sample per line (``recorded_llm/README.md`` documents it), written by
:func:`export_jsonl` in a stable order and read back by :func:`import_jsonl`, which checks
every line before it writes any. Sample ids make imports idempotent: importing the same file
twice adds nothing.

Which sample a query receives is :func:`pick_index` of (run seed, key, occurrence): the same
trial asking the same key for the n-th time always gets the same sample from the same store.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import sqlite3
import tempfile
import threading
import time
import zlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any
from urllib.parse import quote, urlsplit

import diskcache
import numpy as np
from diskcache.core import MODE_BINARY, MODE_PICKLE, MODE_RAW

from lagrseq import keys
from lagrseq.errors import StoreError
from lagrseq.llm.base import Answer, Query, RecordedAs, Usage, samplers_of
from lagrseq.llm.records import (
    ENTRY_SCHEMA,
    JSONL_FORMAT,
    KEY_VERSION,
    MAX_ANSWER_CHARS,  # noqa: F401 - re-exported: the longest answer a store holds
    MAX_LINE_BYTES,
    RECORD_SCHEMA,
    describe,
    normalise_request,
    normalise_sample,
    problems,
)
from lagrseq.llm.servers import DEFAULT_BASE_URL, base_url_problem  # noqa: F401 - DEFAULT_BASE_URL re-exported for callers
from lagrseq.paths import open_input
from lagrseq.progress import Reporter
from lagrseq.text import kind_of

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: no claims, each recorder reads before it pays
    fcntl = None  # type: ignore[assignment]

STORE_FORMAT = "lagrseq.recorded-store"
CLAIMS_DIR = "claims"
"""The store's subdirectory holding the per-key claim files (empty when no recorder runs)."""
META_KEY = "lagrseq-store"
_DEFAULT_PORTS = {"http": 80, "https": 443}


# ------------------------------------------------------------------------------------------
# Keys
# ------------------------------------------------------------------------------------------
def endpoint_of(base_url: str) -> str:
    """The endpoint part of a key: the lower-cased host, with the port when it is not the
    scheme's default (``https://api.openai.com/v1`` -> ``api.openai.com``). A URL carrying
    credentials or a key-like segment is refused without being shown (:func:`base_url_problem`)."""
    problem = base_url_problem(base_url)
    if problem is not None:
        raise StoreError(problem)
    try:
        parts = urlsplit(base_url if "://" in base_url else f"https://{base_url}")
    except ValueError:  # e.g. an unclosed '[' of an IPv6 host
        raise StoreError("the base URL (not shown) is not a URL (an unclosed [ of an IPv6 host, or characters no host name holds); expected e.g. https://api.openai.com/v1") from None
    host = (parts.hostname or "").lower()
    if not host:
        raise StoreError("the base URL (not shown) has no host; expected e.g. https://api.openai.com/v1")
    try:
        port = parts.port
    except ValueError:
        raise StoreError("the base URL (not shown) has a bad port: expected a number from 0 to 65535, e.g. http://127.0.0.1:8000/v1") from None
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
        # llama.cpp's samplers, only when the query pins them: every key recorded before they
        # existed (and every OpenAI key) stays what it was
        **samplers_of(query),
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


def draw_order(run_seed: int, key: str, count: int) -> list[int]:
    """The order in which a run that draws without replacement receives a key's ``count``
    samples: a permutation seeded by (run seed, key) alone."""
    sequence = np.random.SeedSequence([int(run_seed) & (2**64 - 1), int(key, 16), count, 1])
    return [int(i) for i in np.random.Generator(np.random.PCG64(sequence)).permutation(count)]


class SampleChooser:
    """Counts the occurrences of each key in one run and picks samples with :func:`pick_index`
    (with replacement: what a trial does, whose queries of a key are draws of the model). With
    ``without_replacement`` (Fig. 4's probe, which asks every prefix a fixed number of times to
    measure how often the model is right), the first ``count`` occurrences of a key receive its
    ``count`` samples each once, in :func:`draw_order`; only occurrences beyond them draw with
    replacement. So a probe of 10 per prefix over a store of 10 per prefix shows the recorded
    counts exactly."""

    def __init__(self, run_seed: int, without_replacement: bool = False) -> None:
        self.run_seed = int(run_seed)
        self.without_replacement = without_replacement
        self.occurrences: dict[str, int] = {}

    def choose(self, key: str, count: int) -> int:
        occurrence = self.occurrences.get(key, 0)
        self.occurrences[key] = occurrence + 1
        if self.without_replacement and occurrence < count:
            return draw_order(self.run_seed, key, count)[occurrence]
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
            raise StoreError(f"{where}: unknown field {describe(unknown[0])}; fields are {', '.join(sorted(names))}")
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
            usage=self.usage,
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
    "pickle". Rows like that can only come from another writer; refuse them. A value kept in a
    file must lie inside the store directory.
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
        if filename is not None:
            root = os.path.realpath(self._directory)
            if not isinstance(filename, str) or not os.path.realpath(os.path.join(root, filename)).startswith(root + os.sep):
                raise StoreError(
                    f"store {self._directory} points a value at {filename!r}, outside the store directory; "
                    "do not use this directory as a lagrseq store"
                )
        return self._json(diskcache.Disk.fetch(self, mode, filename, value, read), "value")

    def _json(self, data: Any, what: str) -> Any:
        try:
            if not isinstance(data, bytes):
                raise TypeError(type(data).__name__)
            return json.loads(zlib.decompress(data).decode("utf-8"))
        except (TypeError, zlib.error, UnicodeDecodeError, ValueError, RecursionError):
            raise StoreError(
                f"store {self._directory} holds a {what} that lagrseq did not write (not compressed "
                "JSON); do not use this directory as a lagrseq store"
            ) from None


_FOREIGN = (sqlite3.Error, diskcache.Timeout, OSError, json.JSONDecodeError, UnicodeDecodeError, ValueError)


def _read_only_error(exc: BaseException) -> bool:
    """Whether ``exc`` says the store cannot be written (a read-only directory, file or disk)."""
    if isinstance(exc, PermissionError) or (isinstance(exc, OSError) and exc.errno == 30):  # EROFS
        return True
    name = str(getattr(exc, "sqlite_errorname", ""))
    text = str(exc).lower()
    return name.startswith("SQLITE_READONLY") or "readonly" in text or "read-only" in text


@contextlib.contextmanager
def _translated(directory: Path, action: str) -> Iterator[None]:
    try:
        yield
    except StoreError:
        raise
    except _FOREIGN as exc:
        writing = action.startswith(("write", "open it for writing"))
        if writing and (_read_only_error(exc) or ("unable to open" in str(exc) and (directory / "cache.db").is_file())):
            raise StoreError(
                f"store {directory} cannot be written ({type(exc).__name__}: {exc}): it is read-only; it can "
                "still be read (recorded runs, cache list, cache export), but to record or import into it make "
                "it writable, or use another store"
            ) from None
        raise StoreError(f"store {directory}: could not {action} ({type(exc).__name__}: {exc})") from None


def _cannot_open_writable(exc: sqlite3.Error) -> bool:
    """Whether a ``mode=ro`` connection failed only because SQLite could not create its
    ``-wal``/``-shm`` files beside a WAL database (a read-only directory)."""
    name = str(getattr(exc, "sqlite_errorname", ""))
    text = str(exc).lower()
    return name.startswith(("SQLITE_READONLY", "SQLITE_CANTOPEN")) or "readonly" in text or "unable to open" in text


class ReadOnlyDatabase:
    """Read access to a store's SQLite database that never writes.

    The database is opened ``mode=ro``: SQLite refuses every write on that connection. A store
    in a read-only directory (where SQLite cannot create the ``-wal``/``-shm`` files a WAL database
    needs for shared reading) is opened ``immutable=1`` instead, which reads the file as it is;
    nobody can be writing into a directory that cannot be written. Keys and values are decoded by
    :class:`JSONOnlyDisk`, so nothing read here is ever unpickled.
    """

    SELECT_VALUE = (
        "SELECT mode, filename, value FROM Cache WHERE key = ? AND raw = ?"
        " AND (expire_time IS NULL OR expire_time > ?)"
    )

    def __init__(self, directory: Path, timeout_s: float = 60.0) -> None:
        self.directory = directory
        self.path = directory / "cache.db"
        self.timeout_s = timeout_s
        self.disk = JSONOnlyDisk(str(directory))
        self.immutable = False
        self._lock = threading.Lock()
        self._pid = os.getpid()
        self._connection: sqlite3.Connection | None = None
        self._connection = self._connect()

    def uri(self, immutable: bool) -> str:
        """The SQLite URI of the database, read-only (and immutable when asked)."""
        target = quote(os.path.abspath(self.path), safe="/")
        return f"file:{target}?mode=ro" + ("&immutable=1" if immutable else "")

    def _open(self, immutable: bool) -> sqlite3.Connection:
        connection = sqlite3.connect(
            self.uri(immutable), uri=True, timeout=self.timeout_s, isolation_level=None, check_same_thread=False
        )
        try:
            tables = {name for (name,) in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except BaseException:
            connection.close()
            raise
        if tables - {"Cache", "Settings"}:  # diskcache makes these two (and nothing else) before any row
            connection.close()
            raise StoreError(f"{self.directory} holds an SQLite database that is not a lagrseq store; use another directory")
        return connection

    def _connect(self) -> sqlite3.Connection:
        with _translated(self.directory, "open it"):
            try:
                return self._open(immutable=False)
            except sqlite3.OperationalError as exc:
                if not _cannot_open_writable(exc):
                    raise
            connection = self._open(immutable=True)
            self.immutable = True
            return connection

    def _rows(self, sql: str, parameters: tuple[Any, ...] = (), empty: list[Any] | None = None) -> list[Any]:
        """The rows of a query; ``empty`` (default ``[]``) while the store is still being created by
        another process (its tables do not exist yet)."""
        with self._lock:
            if self._connection is None or self._pid != os.getpid():  # closed, or inherited by fork
                self._pid = os.getpid()
                self._connection = self._connect()
            try:
                return self._connection.execute(sql, parameters).fetchall()
            except sqlite3.OperationalError as exc:
                if "no such table: Cache" not in str(exc):
                    raise
                return [] if empty is None else empty

    def get(self, key: Any) -> Any:
        """The decoded value of ``key``, or None."""
        db_key, raw = self.disk.put(key)
        for attempt in range(3):
            rows = self._rows(self.SELECT_VALUE, (db_key, raw, time.time()))
            if not rows:
                return None
            mode, filename, value = rows[0]
            try:
                return self.disk.fetch(mode, filename, value, False)
            except FileNotFoundError:  # a writer replaced the value (and its file) meanwhile
                if attempt == 2:
                    raise
        return None  # pragma: no cover - the loop returns or raises

    def stored_keys(self) -> list[Any]:
        return [self.disk.get(key, raw) for key, raw in self._rows("SELECT key, raw FROM Cache ORDER BY key, raw")]

    def count(self) -> int:
        return int(self._rows("SELECT count(*) FROM Cache", empty=[(0,)])[0][0])

    def close(self) -> None:
        with self._lock:
            if self._connection is not None:
                self._connection.close()
                self._connection = None


def entry_problems(key: str, value: Any) -> list[str]:
    """What is wrong with a store row (``[]``: nothing); see :mod:`lagrseq.llm.records`."""
    found = problems(value, ENTRY_SCHEMA, limit=3, whole="the entry")
    if not found and key_of_request(value["request"]) != key:
        found = ["the key is not the hash of its request (the request was changed)"]
    return found


class KeyClaim:
    """A held claim on one key (:meth:`RecordStore.claim`); ``release`` (idempotent) lets it go.
    A context manager."""

    def __init__(self, path: Path | None, fd: int | None) -> None:
        self.path = path
        self._fd = fd

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if self.path is not None:  # unlinked while still held: a waiter sees a new file
                with contextlib.suppress(OSError):
                    os.unlink(self.path)
        finally:
            os.close(fd)  # closing the file lets the lock go

    def __enter__(self) -> KeyClaim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class RecordStore:
    """A directory of recorded answers (module docstring). A context manager; ``close`` is
    idempotent. ``create=False`` refuses a directory that is not already a store.

    Reading never writes: an existing store is read through a read-only SQLite connection
    (:class:`ReadOnlyDatabase`), so a read-only store directory serves recorded runs, ``cache list``
    and ``cache export``. The diskcache that writes is opened on the first write (:meth:`add`), or
    at once when the store does not exist yet and ``create`` is true. ``readonly=True`` refuses
    every write."""

    def __init__(
        self, directory: str | Path, create: bool = True, timeout_s: float = 60.0, readonly: bool = False
    ) -> None:
        self.directory = Path(directory)
        self.readonly = readonly
        self.timeout_s = timeout_s
        self._cache: diskcache.Cache | None = None
        self._reader: ReadOnlyDatabase | None = None
        self._closed = False
        if self.directory.exists() and not self.directory.is_dir():
            raise StoreError(f"store path {self.directory} is {kind_of(self.directory.stat().st_mode)}; expected a directory")
        for name in ("cache.db", "cache.db-wal", "cache.db-shm", "cache.db-journal"):
            if os.path.islink(self.directory / name):  # SQLite would write through it, into someone's file
                raise StoreError(
                    f"store {self.directory}: {name} is a symbolic link; lagrseq never opens a store's database through a "
                    "link: remove the link or give another store directory"
                )
        if not (self.directory / "cache.db").is_file() and (
            not create or readonly or (self.directory / "cache.db").exists()
        ):
            raise StoreError(
                    f"no recorded store at {self.directory}; create one with `lagrseq record` or "
                    "`lagrseq cache import`"
                )
        try:
            if not (self.directory / "cache.db").is_file():
                self.writer()
            self._reader = ReadOnlyDatabase(self.directory, timeout_s)
            self._check_header()
        except BaseException:
            self.close()
            raise

    def _check_header(self) -> None:
        with _translated(self.directory, "read its header"):
            # Count first, then read the header: the header is the first row a store gets, so a
            # count taken before it cannot race with another process creating the store.
            rows = self._read().count()
            meta = self._read().get(META_KEY)
            if meta is None:
                if rows:
                    raise StoreError(
                        f"{self.directory} holds a diskcache that is not a lagrseq store; use another directory"
                    )
            elif not isinstance(meta, dict) or meta.get("format") != STORE_FORMAT:
                raise StoreError(f"{self.directory} is not a lagrseq store (header {describe(meta)})")

    def writer(self) -> diskcache.Cache:
        """The diskcache that writes, opened (and its header written) on first use. Call it
        before buying answers, so that a store that cannot be written fails first."""
        if self._closed:
            raise StoreError(f"store {self.directory} is closed")
        if self._cache is not None:
            return self._cache
        if self.readonly:
            raise StoreError(f"store {self.directory} was opened read-only; nothing can be written to it")
        with _translated(self.directory, "open it for writing"):
            cache = diskcache.Cache(
                str(self.directory),
                disk=JSONOnlyDisk,
                eviction_policy="none",
                timeout=self.timeout_s,
                statistics=False,
                tag_index=False,
            )
        try:
            with _translated(self.directory, "write its header"), cache.transact(retry=True):
                meta = cache.get(META_KEY)
                if meta is None:
                    if len(cache):
                        raise StoreError(
                            f"{self.directory} holds a diskcache that is not a lagrseq store; use another directory"
                        )
                    cache.set(META_KEY, {"format": STORE_FORMAT, "version": 1})
                elif not isinstance(meta, dict) or meta.get("format") != STORE_FORMAT:
                    raise StoreError(f"{self.directory} is not a lagrseq store (header {describe(meta)})")
        except BaseException:
            cache.close()
            raise
        self._cache = cache
        return cache

    def _read(self) -> ReadOnlyDatabase:
        if self._closed or self._reader is None:
            raise StoreError(f"store {self.directory} is closed")
        return self._reader

    # ------------------------------------------------------------------ reading
    def entry(self, key: str) -> Entry | None:
        with _translated(self.directory, f"read key {key[:12]}"):
            value = self._read().get(key)
        return None if value is None else self._entry(key, value)

    def _entry(self, key: str, value: Any) -> Entry:
        found = entry_problems(key, value)
        if found:
            raise StoreError(
                f"store {self.directory}, key {key}: {'; '.join(found)}. This entry was not written by this "
                "lagrseq (an older version, another program or a hand edit); move the store aside and "
                "rebuild it with `lagrseq cache import` of your JSONL exports, or record the key again into a new store"
            )
        where = f"store {self.directory}, key {key[:12]}"
        samples = tuple(Sample.from_json(s, f"{where}, sample {i}") for i, s in enumerate(value["samples"]))
        return Entry(key, value["request"], value.get("task"), samples)

    def keys(self) -> list[str]:
        with _translated(self.directory, "list its keys"):
            return sorted(k for k in self._read().stored_keys() if isinstance(k, str) and k != META_KEY)

    def entries(self) -> Iterator[Entry]:
        """Every entry, in key order."""
        for key in self.keys():
            found = self.entry(key)
            if found is not None:
                yield found

    def __len__(self) -> int:
        return len(self.keys())

    # ------------------------------------------------------------------ writing
    def add(self, key: str, request: dict[str, Any], task: str | None, samples: Sequence[Sample]) -> int:
        """Append the samples whose ids the key does not have yet, atomically (one transaction);
        return how many the key holds afterwards."""
        self._check_new(key, request, task, samples)
        with _translated(self.directory, f"write key {key[:12]}"):
            cache = self.writer()
            with cache.transact(retry=True):
                return self._add_locked(cache, key, request, task, samples)[0]

    def add_many(
        self, groups: Mapping[str, tuple[dict[str, Any], str | None, Sequence[Sample]]], checked: bool = False
    ) -> int:
        """:meth:`add` for several keys ``{key: (request, task, samples)}`` in one transaction;
        return how many samples were new. ``checked``: the caller has already checked every
        request and sample against the schema (an import); keys are still recomputed."""
        for key, (request, task, samples) in groups.items():
            if checked:
                if key_of_request(request) != key:
                    raise StoreError(f"key {key[:12]} is not the hash of its request; refusing to store it")
                self._check_no_key(key, request)
            else:
                self._check_new(key, request, task, samples)
        with _translated(self.directory, f"write {len(groups)} keys"):
            cache = self.writer()
            with cache.transact(retry=True):
                return sum(self._add_locked(cache, key, *group)[1] for key, group in groups.items())

    def _check_new(self, key: str, request: dict[str, Any], task: str | None, samples: Sequence[Sample]) -> None:
        if key_of_request(request) != key:
            raise StoreError(f"key {key[:12]} is not the hash of its request; refusing to store it")
        self._check_no_key(key, request)
        found = problems({"request": request, "task": task, "samples": [s.to_json() for s in samples]}, ENTRY_SCHEMA, limit=3)
        if found:
            raise StoreError(f"refusing to store key {key[:12]} in {self.directory}: {'; '.join(found)}")

    def _check_no_key(self, key: str, request: dict[str, Any]) -> None:
        """A StoreError when a request holds a guarded API key (a key passed as --model): the
        request is stored as it is (its hash is the key), so it is refused, never blanked."""
        if keys.active() and keys.holds_key(json.dumps(request, ensure_ascii=False)):
            raise StoreError(
                f"refusing to store key {key[:12]} in {self.directory}: its request holds the API key or 8 or more "
                "characters of it (in the model name?); give the model's name, and keep the key in its environment variable"
            )

    def _add_locked(
        self, cache: diskcache.Cache, key: str, request: dict[str, Any], task: str | None, samples: Sequence[Sample]
    ) -> tuple[int, int]:
        """Inside a transaction: append the new samples of ``key``; (samples held, samples added)."""
        value = cache.get(key)
        if value is None:
            value = {"request": request, "task": task, "samples": []}
        else:
            self._entry(key, value)  # a damaged row is named, never extended
        have = {s["id"] for s in value["samples"]}
        added = []
        guarded = keys.active()  # an answer that echoes a guarded key is stored without it
        for sample in samples:
            if sample.id not in have:
                have.add(sample.id)
                added.append(keys.scrub_value(sample.to_json()) if guarded else sample.to_json())
        if added:
            value["samples"] = list(value["samples"]) + added
            if value.get("task") is None:
                value["task"] = task
            cache.set(key, value)
        return len(value["samples"]), len(added)

    # ------------------------------------------------------------------ claims
    def claim(self, key: str, wait_s: float = 0.0, poll_s: float = 0.05) -> KeyClaim | None:
        """The claim on ``key`` for this caller alone, or None when another recorder (another
        process, or another claim of this one) holds it for ``wait_s`` seconds (0: do not wait).
        Read the key again once claimed: the holder before may have recorded it."""
        if fcntl is None:  # pragma: no cover - no flock: every recorder reads before it pays
            return KeyClaim(None, None)
        if not key or not all(c in "0123456789abcdef" for c in key):
            raise StoreError(f"key {key[:12]!r} is not a hex digest; refusing to claim it")
        folder = self.directory / CLAIMS_DIR
        path = folder / f"{key}.lock"
        deadline = time.monotonic() + wait_s
        while True:
            with _translated(self.directory, "write a claim"):
                folder.mkdir(exist_ok=True)
                fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0), 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
            except OSError:
                os.close(fd)
                raise
            else:
                try:  # the file may have been unlinked by the holder just before: take a fresh one
                    same = os.fstat(fd).st_ino == os.stat(path, follow_symlinks=False).st_ino
                except OSError:
                    same = False
                if same:
                    return KeyClaim(path, fd)
                os.close(fd)
                continue
            if time.monotonic() >= deadline:
                return None
            time.sleep(poll_s)

    # ------------------------------------------------------------------ misses
    def nearest(self, request: dict[str, Any], task: str | None = None, limit: int = 3) -> list[tuple[Entry, str]]:
        """The recorded entries most like ``request`` (:func:`nearest_entries`)."""
        return nearest_entries(self.entries(), request, task, limit)

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._reader is not None:
                self._reader.close()
            if self._cache is not None:
                self._cache.close()

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RecordStore({str(self.directory)!r})"


def nearest_entries(
    entries: Iterable[Entry], request: dict[str, Any], task: str | None = None, limit: int = 3
) -> list[tuple[Entry, str]]:
    """The ``entries`` most like ``request`` and, for each, how it differs: same prompt
    with other settings first, then the most similar prompts of the same task."""
    prompt = str(request["messages"][-1]["content"]) if request.get("messages") else ""
    scored: list[tuple[float, str, Entry, str]] = []
    for entry in entries:
        if task is not None and entry.task not in (None, task):
            continue
        differences = [
            f"{name} {entry.request.get(name)!r} instead of {request.get(name)!r}"
            for name in ("endpoint", "model", "temperature", "top_p", "max_tokens", "stop", "seed", "top_k", "min_p", "repeat_penalty")
            if entry.request.get(name) != request.get(name)
        ]
        same_messages = entry.request.get("messages") == request.get("messages")
        if same_messages:
            similarity = 2.0
        else:
            similarity = prompt_similarity(entry.prompt, prompt)
            differences.insert(0, f"another prompt ({similarity:.1%} alike{_diff_hint(entry.prompt, prompt)})")
        score = similarity - 0.1 * len(differences)
        scored.append((-score, entry.key, entry, "; ".join(differences) or "identical"))
    scored.sort(key=lambda item: (item[0], item[1]))
    return [(entry, why) for _, _, entry, why in scored[:limit]]


def prompt_similarity(recorded: str, asked: str) -> float:
    """How alike two prompts are, 0 to 1, in time linear in their length: the characters of their
    common beginning and end, and of the stretch between them the characters equal at the same
    place, over the longer prompt's length. Prompts of one task share their wording and differ
    in the partial pattern, which this measures cell by cell. (``difflib``'s ratio took 0.3 s a
    pair on the 10 x 10 image prompts, 131 s for one miss in a store of 418 of them.)"""
    longest = max(len(recorded), len(asked))
    if longest == 0:
        return 1.0
    shortest = min(len(recorded), len(asked))
    head = 0
    while head < shortest and recorded[head] == asked[head]:
        head += 1
    tail = 0
    while tail < shortest - head and recorded[-1 - tail] == asked[-1 - tail]:
        tail += 1
    middle = sum(x == y for x, y in zip(recorded[head : len(recorded) - tail], asked[head : len(asked) - tail]))
    return (head + tail + middle) / longest


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
def miss_message(store: RecordStore | JsonlStore, key: str, request: dict[str, Any], task: str | None) -> str:
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
    """Write every sample as one JSON line to ``out``. Every entry is checked first, so a
    damaged store writes nothing (not half an export)."""
    for _ in store.entries():
        pass
    lines = 0
    keys: set[str] = set()
    for line in jsonl_lines(store):
        out.write(line + "\n")
        lines += 1
        keys.add(json.loads(line)["key"])
    return JsonlReport(lines=lines, keys=len(keys))


MAX_BAD_LINES_SHOWN = 5
_PICKLE_HINT = "if it is an authors' cache pickle, import it with --format pkl (and --task, --model, --temperature)"


def _read_lines(source: IO[str] | IO[bytes], name: str) -> Iterator[tuple[int, str | None, str | None]]:
    """``(number, text, None)`` for each line of ``source`` (text or bytes), or ``(number, None,
    why)`` for a line that cannot be read: longer than :data:`MAX_LINE_BYTES` (never held in
    memory whole) or not UTF-8."""
    number = 0
    while True:
        try:
            chunk: str | bytes = source.readline(MAX_LINE_BYTES + 1)
            if not chunk:
                return
            number += 1
            if number == 1 and isinstance(chunk, bytes) and chunk[:1] == b"\x80":
                raise StoreError(f"{name} is a pickle (binary data starting with byte 0x80), not JSONL; {_PICKLE_HINT}")
            newline: str | bytes = b"\n" if isinstance(chunk, bytes) else "\n"
            if len(chunk) > MAX_LINE_BYTES and not chunk.endswith(newline):  # type: ignore[arg-type]
                rest = chunk
                while rest and not rest.endswith(newline):  # type: ignore[arg-type]
                    rest = source.readline(1 << 16)
                yield number, None, f"longer than {MAX_LINE_BYTES} bytes (the longest line read); a line holds one answer"
                continue
        except UnicodeDecodeError as exc:
            raise StoreError(
                f"{name}: not UTF-8 text (line {number + 1}: {exc.reason}); a JSONL export is UTF-8; {_PICKLE_HINT}"
            ) from None
        if isinstance(chunk, bytes):
            try:
                text = chunk.decode("utf-8")
            except UnicodeDecodeError as exc:
                yield number, None, f"not UTF-8 (byte 0x{chunk[exc.start]:02x} at byte {exc.start + 1})"
                continue
        else:
            text = chunk
        yield number, text.removeprefix("\ufeff") if number == 1 else text, None


def _check_line(text: str) -> tuple[dict[str, Any] | None, str | None]:
    """A JSONL line as ``(record, None)`` (checked, numbers normalised) or ``(None, why)``."""
    try:
        record = json.loads(text)
    except json.JSONDecodeError as exc:
        return None, f"not JSON ({exc.msg} at column {exc.colno})"
    except RecursionError:
        return None, "not a record (JSON nested too deeply)"
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        return None, f"not JSON ({str(exc)[:80]})"
    if not isinstance(record, dict):
        return None, f"expected a {JSONL_FORMAT!r} record (a JSON object), found {describe(record)}"
    if record.get("format") != JSONL_FORMAT:
        return None, f"expected a {JSONL_FORMAT!r} record, found format {describe(record.get('format'))}"
    found = problems(record, RECORD_SCHEMA, limit=4)
    if found:
        more = f" (and {len(found) - 3} more)" if len(found) > 3 else ""
        return None, "; ".join(found[:3]) + more
    record["request"] = normalise_request(record["request"])
    record["sample"] = normalise_sample(record["sample"])
    return record, None


def _check_jsonl(
    source: IO[str] | IO[bytes], name: str, spool: IO[str], reporter: Reporter
) -> tuple[int, int]:
    """Pass one of an import: check every line, writing the checked records to ``spool``;
    raise one :class:`StoreError` listing the bad lines (nothing is written to the store).
    Returns (records, distinct keys)."""
    bad: list[str] = []
    bad_count = 0
    not_utf8 = False
    records = 0
    keys: set[str] = set()
    mismatched: list[str] = []
    for number, text, why in _read_lines(source, name):
        record = None
        if text is not None:
            if not text.strip():
                continue
            record, why = _check_line(text)
        if record is None:
            bad_count += 1
            not_utf8 = not_utf8 or (why or "").startswith("not UTF-8")
            if len(bad) < MAX_BAD_LINES_SHOWN:
                bad.append(f"line {number}: {why}")
            continue
        records += 1
        request = record["request"]
        key = key_of_request(request)
        keys.add(key)
        if "key" in record and record["key"] != key and len(mismatched) <= MAX_BAD_LINES_SHOWN:
            mismatched.append(f"{name} line {number}: key {record['key'][:12]} does not match its request; filed under {key[:12]}")
        task = record.get("task")
        if not bad_count:
            spool.write(json.dumps([key, task, request, record["sample"]]) + "\n")
    if bad_count:
        shown = f" (first {MAX_BAD_LINES_SHOWN} shown)" if bad_count > len(bad) else ""
        hint = f"; {_PICKLE_HINT}" if not_utf8 else ""
        raise StoreError(
            f"{name}: {bad_count} bad line{'s' if bad_count != 1 else ''} of {records + bad_count}, nothing "
            f"imported: {'; '.join(bad)}{shown}{hint}"
        )
    for message in mismatched[:MAX_BAD_LINES_SHOWN]:
        reporter.warn(message)
    if len(mismatched) > MAX_BAD_LINES_SHOWN:
        reporter.warn(f"{name}: more keys that do not match their request (first {MAX_BAD_LINES_SHOWN} shown)")
    return records, len(keys)


def _write_checked(spool: IO[str], store: RecordStore, batch_size: int = 1000) -> int:
    """Pass two of an import: add the checked records to ``store``, ``batch_size`` lines per
    transaction; return how many samples were new."""
    added = 0
    batch: dict[str, tuple[dict[str, Any], str | None, list[Sample]]] = {}
    pending = 0
    for line in spool:
        key, task, request, sample = json.loads(line)
        batch.setdefault(key, (request, task, []))[2].append(Sample.from_json(sample))
        pending += 1
        if pending >= batch_size:
            added += store.add_many(batch, checked=True)
            batch, pending = {}, 0
    if batch:
        added += store.add_many(batch, checked=True)
    return added


def import_jsonl(
    source: IO[str] | IO[bytes],
    store: RecordStore | str | Path,
    name: str = "JSONL",
    reporter: Reporter | None = None,
) -> JsonlReport:
    """Add every sample of a JSONL export to ``store`` (samples already there are skipped).

    Every line is checked (:mod:`lagrseq.llm.records`) before anything is written: one bad line
    rejects the file with a :class:`StoreError` naming the bad lines and what is wrong with them,
    and the store is left as it was. ``source`` may be text or bytes; lines are read one at a
    time (at most :data:`MAX_LINE_BYTES` each), so a large file needs little memory. ``store`` may
    be a directory, opened (and created) only once the file has passed.

    The key of each line is recomputed from its request, which is the truth: a hand-edited request
    files its samples under the new key (with a warning to ``reporter`` naming the line; None:
    no warning)."""
    try:
        with tempfile.TemporaryFile(mode="w+", encoding="utf-8") as spool:
            records, keys = _check_jsonl(source, name, spool, reporter or Reporter.silent())
            spool.flush()
            spool.seek(0)
            if isinstance(store, RecordStore):
                added = _write_checked(spool, store)
            else:
                with RecordStore(store) as opened:
                    added = _write_checked(spool, opened)
    except OSError as exc:  # reading the file, or the temporary copy of its checked lines
        raise StoreError(f"cannot import {name}: {exc.strerror or exc}") from None
    return JsonlReport(lines=records, keys=keys, added=added, already_present=records - added)


JSONL_IN_MEMORY_MAX_BYTES = 64 * 2**20
"""The largest JSONL export :class:`JsonlStore` reads into memory (the recorded open-model files
are at most 1.7 MB); a larger file is refused with the command that imports it into a store."""
JSONL_OPENED_MAX = 16
"""How many JSONL exports a process keeps read (least recently opened dropped first), and at
most :data:`JSONL_OPENED_MAX_BYTES` of them (their files' sizes)."""
JSONL_OPENED_MAX_BYTES = 128 * 2**20
_jsonl_opened: dict[tuple[Any, ...], tuple[dict[str, Entry], frozenset[Any]]] = {}
_jsonl_lock = threading.Lock()


class JsonlStore:
    """A JSONL export, read only, held in memory: what ``recorded:FILE.jsonl`` answers from.

    Every line is checked as :func:`import_jsonl` checks it (a bad line: one :class:`StoreError`
    naming it) and a key's samples merge as an import into an empty store merges them (a sample
    id the key already holds is skipped; the first request and task stand), so a run gets the
    answers it would get from the file imported with ``lagrseq cache import``. A process reads
    a file once: opening the same unchanged file again (same device, inode, size and
    modification time) shares its entries, as every trial of a run in one worker does (the file
    was imported into a temporary store per trial before: 40-55 ms a cube trial, 0.2 s an image
    trial). Files over :data:`JSONL_IN_MEMORY_MAX_BYTES` are refused."""

    def __init__(self, path: str | Path, name: str | None = None) -> None:
        self.directory = Path(path)
        """The file (named ``directory`` as :class:`RecordStore`'s, for the messages that name a store)."""
        name = name or str(path)
        if self.directory.is_dir():
            raise StoreError(f"{path} is a directory; expected a JSONL file (a lagrseq export)")
        handle = open_input(self.directory, "JSONL file", StoreError)  # a FIFO or device is refused
        with handle:
            try:
                info = os.fstat(handle.fileno())
            except OSError as exc:
                raise StoreError(f"cannot read {name}: {exc.strerror or exc}") from None
            if info.st_size > JSONL_IN_MEMORY_MAX_BYTES:
                raise StoreError(
                    f"{name} is {info.st_size / 2**20:.0f} MiB, over the {JSONL_IN_MEMORY_MAX_BYTES // 2**20} MiB a JSONL "
                    "export is replayed from; import it into a store (lagrseq cache import FILE STORE) and run "
                    "with --provider recorded:STORE"
                )
            identity = (str(self.directory.resolve()), info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)
            with _jsonl_lock:
                opened = _jsonl_opened.pop(identity, None)
            if opened is None:
                opened = _read_jsonl(handle, name)
            with _jsonl_lock:
                _jsonl_opened[identity] = opened  # most recently opened last
                while len(_jsonl_opened) > JSONL_OPENED_MAX or (
                    len(_jsonl_opened) > 1 and sum(kept[3] for kept in _jsonl_opened) > JSONL_OPENED_MAX_BYTES
                ):
                    del _jsonl_opened[next(iter(_jsonl_opened))]
        self._entries, self.endpoints = opened

    def entry(self, key: str) -> Entry | None:
        return self._entries.get(key)

    def keys(self) -> list[str]:
        return list(self._entries)

    def entries(self) -> Iterator[Entry]:
        """Every entry, in key order."""
        return iter(self._entries.values())

    def __len__(self) -> int:
        return len(self._entries)

    def nearest(self, request: dict[str, Any], task: str | None = None, limit: int = 3) -> list[tuple[Entry, str]]:
        """The recorded entries most like ``request`` (:func:`nearest_entries`)."""
        return nearest_entries(self.entries(), request, task, limit)

    def close(self) -> None:
        """Nothing to release: the entries stay with the process for the next open."""

    def __enter__(self) -> JsonlStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"JsonlStore({str(self.directory)!r})"


def _read_jsonl(handle: IO[bytes], name: str) -> tuple[dict[str, Entry], frozenset[Any]]:
    """The entries of a JSONL export in key order, and the endpoints their requests name."""
    spool = io.StringIO()
    try:
        _check_jsonl(handle, name, spool, Reporter.silent())
    except OSError as exc:
        raise StoreError(f"cannot import {name}: {exc.strerror or exc}") from None
    merged: dict[str, tuple[dict[str, Any], list[str | None], dict[str, Sample]]] = {}
    for line in spool.getvalue().splitlines():
        key, task, request, data = json.loads(line)
        sample = Sample.from_json(data)
        request_of, task_of, samples = merged.setdefault(key, (request, [None], {}))
        if sample.id not in samples:
            samples[sample.id] = sample
            if task_of[0] is None:
                task_of[0] = task
    entries = {
        key: Entry(key, request, task_of[0], tuple(samples.values()))
        for key, (request, task_of, samples) in sorted(merged.items())
    }
    return entries, frozenset(entry.request.get("endpoint") for entry in entries.values())


def import_jsonl_file(
    path: str | Path,
    store: RecordStore | str | Path,
    name: str | None = None,
    reporter: Reporter | None = None,
) -> JsonlReport:
    """:func:`import_jsonl` of the file at ``path`` (read as bytes, so a line that is not UTF-8
    is named with its number). Every failure is one :class:`StoreError` line: a missing or
    unreadable file, a directory, a pickle given as JSONL, bad lines. ``store`` may be a directory,
    which is opened (and created) only once the whole file has passed."""
    path = Path(path)
    name = name or str(path)
    if path.is_dir():
        raise StoreError(f"{path} is a directory; expected a JSONL file (a lagrseq export)")
    handle = open_input(path, "JSONL file", StoreError)  # a FIFO or device is refused, not read for ever
    with handle:
        return import_jsonl(handle, store, name, reporter)
