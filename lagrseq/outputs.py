"""The one writer of every file a command writes: reports, tables, figures, indexes, error logs,
manifests.

:func:`write_text` and :func:`write_bytes` put a whole file in place or refuse in one line
(:class:`~lagrseq.errors.UsageError`, exit status 2), before anything is written and with nothing
already there lost. They refuse a target that is

- a symbolic link (never written through: a link planted in a report folder would put the report
  over someone's file), a directory, a FIFO, a socket or a device (a FIFO would block the writer);
- outside the command's output folder (a suite item id ``../../x`` or ``/abs/x`` names no file of
  the report);
- one of the command's own inputs, or inside an input folder (``compare --csv`` naming a table of
  a report it reads);
- already claimed by another output of the same command (``--csv`` and ``--markdown`` one path).

The output folder, the inputs and the claims belong to the command: it opens an
:func:`outputs` session (the innermost one applies; inputs of the outer ones still count), and
every write inside it is checked against them. A write outside any session is checked for links
and kinds only.

A file is written to a new temporary file beside the target (``mkstemp``: created new, never
through a link) and moved into place with ``os.replace`` (which replaces the name, never what a
link points at), so a failure leaves the old file whole. Text, and bytes written to a text file
(:data:`TEXT_SUFFIXES`), pass through the key guard (:func:`lagrseq.keys.scrub`) first: no output
holds a guarded API key in any form the guard knows. Text files have their control characters (an
ANSI escape, a bell) written as escapes (``\\x1b``): printing a report never drives a terminal.
:func:`file_digest` gives a file's SHA-256, for a manifest that must prove which files a command
wrote before it deletes any.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import io
import os
import re
import stat
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lagrseq.errors import UsageError
from lagrseq.text import kind_of


@dataclass
class Session:
    """What one command may write: under ``root`` (None: anywhere), never onto ``inputs``."""

    root: Path | None
    inputs: list[Path] = field(default_factory=list)
    claims: dict[str, str] = field(default_factory=dict)
    """Real path -> the flag that claimed it."""


_current: contextvars.ContextVar[tuple[Session, ...]] = contextvars.ContextVar("lagrseq_outputs", default=())


@contextlib.contextmanager
def outputs(root: str | os.PathLike[str] | None = None, inputs: Iterable[str | os.PathLike[str]] = ()) -> Iterator[Session]:
    """A session for one command writing under ``root`` and reading ``inputs`` (files or folders)."""
    session = Session(None if root is None else Path(root), [Path(p) for p in inputs])
    token = _current.set((*_current.get(), session))
    try:
        yield session
    finally:
        _current.reset(token)


def _real(path: Path) -> str:
    """``path`` with its folder resolved (the last part kept: a link there is refused, not followed)."""
    return os.path.join(os.path.realpath(path.parent if str(path.parent) else "."), path.name)


def _within(child: str, parent: str) -> bool:
    return child == parent or child.startswith(parent.rstrip(os.sep) + os.sep)


def check(path: str | os.PathLike[str], flag: str = "output") -> Path:
    """Every refusal of :func:`write_text` for ``path``, and ``path`` claimed for ``flag``:
    call it for every output before the first is written, so a refusal loses nothing."""
    target = Path(path)
    try:
        real = _real(target)
    except (OSError, ValueError):
        raise UsageError(f"{flag} {target}: not a usable path; give another path") from None
    _check_kind(target, flag)
    sessions = _current.get()
    if sessions:
        _check_session(target, real, flag, sessions)
    return target


def _check_kind(target: Path, flag: str) -> None:
    try:
        mode = os.lstat(target).st_mode
    except FileNotFoundError:
        return
    except NotADirectoryError:
        raise UsageError(f"cannot write {flag} {target}: a part of its folder is a file; give another path") from None
    except (OSError, ValueError) as exc:
        raise UsageError(f"cannot write {flag} {target}: {getattr(exc, 'strerror', None) or exc}") from None
    if stat.S_ISLNK(mode):
        raise UsageError(f"{flag} {target} is a symbolic link; lagrseq never writes through a link: remove the link or give another path")
    if not stat.S_ISREG(mode):
        raise UsageError(f"{flag} {target} is {kind_of(mode)}; move it away or give the path of a file to write")


def _check_session(target: Path, real: str, flag: str, sessions: tuple[Session, ...]) -> None:
    session = sessions[-1]
    if session.root is not None and not _within(real, os.path.realpath(session.root)):
        raise UsageError(f"{flag} {target} lies outside the output folder {session.root}; name a file inside it")
    for outer in sessions:
        for source in outer.inputs:
            if _same_file(target, source) or real == os.path.realpath(source):
                raise UsageError(f"{flag} {target} is an input of this command; lagrseq never writes over what it reads: give another path")
            if _within(real, os.path.realpath(source)):
                raise UsageError(f"{flag} {target} lies inside {source}, an input of this command; lagrseq never writes into what it reads: give another path")
    owner = session.claims.setdefault(real, flag)
    if owner != flag:
        raise UsageError(f"{flag} {target} is also the path of {owner}; give each output its own path")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def write_text(path: str | os.PathLike[str], text: str, flag: str = "output") -> Path:
    """Write ``text`` (UTF-8, ``\\n`` line ends kept as given) at ``path``: checked, key-guarded, atomic."""
    from lagrseq.keys import scrub

    return _place(Path(path), _CONTROLS.sub(_shown_control, scrub(text)).encode("utf-8", "backslashreplace"), flag)


_CONTROLS = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f]")
"""Control characters no text file of a report holds (a tab, a newline and a carriage return are
kept): an ANSI escape would act on the terminal of whoever prints the file."""


def _shown_control(match: re.Match[str]) -> str:
    return f"\\x{ord(match.group()):02x}"


TEXT_SUFFIXES = frozenset((".svg", ".csv", ".md", ".html", ".txt", ".log", ".json", ".jsonl", ".toml"))
"""Files written as bytes that are text, and so pass through the key guard."""


def write_bytes(path: str | os.PathLike[str], data: bytes, flag: str = "output") -> Path:
    """Write ``data`` at ``path``: checked, atomic; key-guarded when it is text (:data:`TEXT_SUFFIXES`)."""
    from lagrseq.keys import active, scrub

    if Path(path).suffix.lower() in TEXT_SUFFIXES and active():
        with contextlib.suppress(UnicodeDecodeError):
            data = scrub(data.decode("utf-8")).encode("utf-8")
    return _place(Path(path), data, flag)


def save_figure(figure: Any, path: str | os.PathLike[str], flag: str = "output", **savefig: Any) -> Path:
    """A matplotlib figure drawn to memory (``figure.savefig(buffer, **savefig)``), then written."""
    buffer = io.BytesIO()
    figure.savefig(buffer, **savefig)
    return write_bytes(path, buffer.getvalue(), flag)


def _place(target: Path, data: bytes, flag: str) -> Path:
    check(target, flag)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        descriptor, scratch = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name[:64]}.", suffix=".partial")
    except OSError as exc:
        raise UsageError(f"cannot write {flag} {target}: {exc.strerror or exc}") from None
    try:
        os.fchmod(descriptor, 0o644)
        with os.fdopen(descriptor, "wb") as handle:
            handle.write(data)
        _check_kind(target, flag)  # planted while writing
        os.replace(scratch, target)  # replaces the name; never writes through a link
    except OSError as exc:
        raise UsageError(f"cannot write {flag} {target}: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(scratch)
    return target


def file_digest(path: str | os.PathLike[str]) -> str | None:
    """The SHA-256 of the regular file at ``path`` (never through a link); None if there is none."""
    try:
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    with os.fdopen(descriptor, "rb") as handle:
        if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            return None
        digest = hashlib.sha256()
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
        return digest.hexdigest()
