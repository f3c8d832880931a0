"""Paths given from outside, checked before anything is opened or written.

Output directories (``run``, ``reproduce`` and ``replay`` check theirs here first, so a path
that is a file, lies below a file, or cannot be written ends in one line naming the flag, the
path and the fix, instead of a traceback halfway through; ``recover`` and ``cache export`` check
their own targets where they write).

Input paths (logs, stores, JSONL exports, pickles, TOML files, GGUF models, token and TLS files):
:func:`input_path` checks one BEFORE it is opened: ``~`` is expanded (HOME unset is one line, not
``RuntimeError``), a symlink loop is one line, and the path must be a regular file (or a
directory where one is expected): a FIFO, a socket or a device would block the reader forever or
hand it endless bytes. :func:`open_input` opens a file without blocking and checks what it opened
(a file swapped for a FIFO between the check and the open is still refused).
:func:`walk_files` lists a directory tree without ever following a symlink loop: every real
directory is entered once.

Output files (``cache export --out``, ``screen --answers``): :func:`write_output` writes through
the one writer, :mod:`lagrseq.outputs` (a new file beside the target, never through a planted
link, moved into place); where the target may not be replaced, an existing file is refused too
(linked into place: an existing name, a link included, is never overwritten). MCAP logs do the same in :mod:`lagrseq.logs.sink`, and ``recover`` with
:func:`refuse_link`, :func:`open_new` and :func:`place_new` (its own temporary file and backup).

Every failure is a :class:`~lagrseq.errors.LagrseqError` (one line, exit status 2); callers pass
the subclass their layer uses (LogError, StoreError, ConfigError).
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, Literal, TextIO, TypeVar

from lagrseq.errors import LagrseqError, UsageError
from lagrseq.text import kind_of

Expect = Literal["file", "directory", "any"]
T = TypeVar("T")


def source_checkout() -> Path:
    """The folder holding the lagrseq package: the clone for an editable install (where the
    packaged suite's ``recorded_llm/`` lies), site-packages otherwise."""
    import lagrseq

    return Path(lagrseq.__file__).resolve().parents[1]


def writable_directory(path: str | Path, flag: str = "--out") -> Path:
    """``path`` as a directory this process can write into (created if missing)."""
    path = expand_user(path, flag)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{flag} {path} is a file, not a directory; give a directory path")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".lagrseq-write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise UsageError(f"{flag} {path}: cannot write there ({reason}); give a writable directory") from None
    return path


def expand_user(path: str | os.PathLike[str], what: str = "path", error: type[LagrseqError] = UsageError) -> Path:
    """``path`` with a leading ``~`` expanded; one line when it cannot be (HOME unset and no
    home directory known for the user)."""
    text = os.fspath(path)
    if not text.startswith("~"):
        return Path(text)
    try:
        return Path(text).expanduser()
    except RuntimeError:
        raise error(f"{what} {text}: '~' cannot be expanded (HOME is not set and the user has no home directory); give the full path") from None


def _stat(path: Path, what: str, error: type[LagrseqError]) -> os.stat_result:
    try:
        return os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{what} {path}: a symlink loop (the link points back at itself); fix or remove the link") from None
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            raise error(f"cannot read {what} {path}: no such file or directory") from None
        if exc.errno == errno.EACCES:
            raise error(f"cannot read {what} {path}: permission denied; make it readable or give another path") from None
        raise error(f"{what} {path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    except ValueError:  # a NUL byte in the path
        raise error(f"{what} {str(path)!r}: not a valid path (it holds a NUL byte)") from None


def input_path(
    path: str | os.PathLike[str], what: str = "input", expect: Expect = "file", error: type[LagrseqError] = UsageError,
) -> Path:
    """``path`` (``~`` expanded) after checking, without opening it, that it is a regular file
    (``expect="file"``), a directory (``"directory"``) or either (``"any"``)."""
    resolved = expand_user(path, what, error)
    mode = _stat(resolved, what, error).st_mode
    is_file, is_dir = stat.S_ISREG(mode), stat.S_ISDIR(mode)
    wanted = {"file": is_file, "directory": is_dir, "any": is_file or is_dir}[expect]
    if not wanted:
        expected = {"file": "a regular file", "directory": "a directory", "any": "a regular file or a directory"}[expect]
        raise error(f"{what} {resolved} is {kind_of(mode)}; expected {expected}")
    return resolved


def open_input(path: str | os.PathLike[str], what: str = "input", error: type[LagrseqError] = UsageError) -> BinaryIO:
    """A regular file opened for binary reading: checked first (:func:`input_path`), opened
    with ``O_NONBLOCK`` (a FIFO does not block the open) and checked again on the descriptor."""
    checked = input_path(path, what, "file", error)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        descriptor = os.open(checked, flags)
    except OSError as exc:
        raise error(f"{what} {checked}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    try:
        mode = os.fstat(descriptor).st_mode
        if not stat.S_ISREG(mode):
            raise error(f"{what} {checked} is {kind_of(mode)}; expected a regular file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(descriptor, True)
        return os.fdopen(descriptor, "rb")
    except BaseException:
        os.close(descriptor)
        raise


def walk_files(root: str | os.PathLike[str], match: Callable[[str], bool]) -> list[Path]:
    """Every entry under the directory ``root`` whose name ``match`` accepts (whatever it is: the
    caller checks it with :func:`input_path`), sorted. Symlinked directories are followed, but
    every real directory is entered once, so a symlink loop ends the walk instead of recursing;
    a link that loops onto itself is listed when its name matches (and refused by the check)."""
    found: list[Path] = []
    seen: set[tuple[int, int]] = set()
    pending = [Path(root)]
    while pending:
        directory = pending.pop()
        try:
            info = os.stat(directory)
            entries = list(os.scandir(directory))
        except OSError:
            continue  # a loop or an unreadable directory: nothing to list there
        if (info.st_dev, info.st_ino) in seen:
            continue
        seen.add((info.st_dev, info.st_ino))
        for entry in entries:
            try:
                is_dir = entry.is_dir(follow_symlinks=True)
            except OSError:
                is_dir = False  # a symlink loop: not a directory to enter
            if is_dir:
                pending.append(Path(entry.path))
            elif match(entry.name):
                found.append(Path(entry.path))
    return sorted(found)


def refuse_link(path: str | os.PathLike[str], flag: str, error: type[LagrseqError] = UsageError) -> None:
    """One line when ``path`` is a symbolic link: an output is never written through one (a link
    planted in a shared folder would put it over someone's file)."""
    if os.path.islink(path):
        raise error(f"{flag} {os.fspath(path)} is a symbolic link; lagrseq never writes through a link: remove the link or give another path")


def write_output(
    path: str | os.PathLike[str], write: Callable[[TextIO], T], flag: str, replace: bool, error: type[LagrseqError] = UsageError,
) -> T:
    """Write a UTF-8 text file at ``path`` with ``write(handle)`` and return what it returns.
    ``replace``: an existing regular file is replaced (:func:`lagrseq.outputs.write_text`, the
    one writer: atomic, never through a link, key-guarded); else an existing name of any kind is
    refused, checked before writing and again atomically when the file is put in place (a hard
    link, which never overwrites)."""
    from lagrseq import outputs
    from lagrseq.keys import scrub

    target = Path(path)
    check_output(target, flag, replace, error)
    buffer = io.StringIO()
    result = write(buffer)
    text = scrub(buffer.getvalue())
    if replace:
        outputs.write_text(target, text, flag)
        return result
    outputs.check(target, flag)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        descriptor, scratch = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name[:64]}.", suffix=".partial")
    except OSError as exc:
        raise error(f"cannot write {flag} {target}: {exc.strerror or exc}") from None
    try:
        os.fchmod(descriptor, 0o644)
        with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
            handle.write(text)
        _link_new(Path(scratch), target, flag, error)
        return result
    except OSError as exc:
        raise error(f"cannot write {flag} {target}: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(scratch)


def check_output(target: Path, flag: str, replace: bool, error: type[LagrseqError] = UsageError) -> None:
    """The checks of :func:`write_output` made before anything is asked or written (a command that
    pays for its answers refuses before it pays)."""
    refuse_link(target, flag, error)
    try:
        mode = os.lstat(target).st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise error(f"cannot write {flag} {target}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(mode):
        raise error(f"{flag} {target} is {kind_of(mode)}; give the path of a file to write")
    if not replace:
        raise error(f"{flag} {target} exists; lagrseq never writes over it: give a new path or move the file away")


NEW_FILE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
"""Flags that create a new file and nothing else: any name already there, a symbolic link
included, fails (``FileExistsError``) instead of being opened or followed."""


def open_new(path: str | os.PathLike[str], mode: int = 0o644) -> int:
    """A descriptor of a new file at ``path`` (:data:`NEW_FILE_FLAGS`); ``OSError`` as ``os.open``
    raises it (``FileExistsError`` when any name is there)."""
    return os.open(path, NEW_FILE_FLAGS, mode)


def place_new(scratch: Path, target: Path, flag: str, error: type[LagrseqError] = UsageError) -> None:
    """Give the finished file ``scratch`` the name ``target`` only if no name is there (a link
    planted meanwhile included): one line otherwise. ``scratch`` keeps its name too (where hard
    links work): the caller removes it."""
    _link_new(scratch, target, flag, error)


def _link_new(scratch: Path, target: Path, flag: str, error: type[LagrseqError]) -> None:
    """Put ``scratch`` in place at ``target`` only if no name is there (a hard link fails on any
    existing name, a symbolic link included); where hard links are not supported, a rename
    after a check (a small window)."""
    try:
        os.link(scratch, target, follow_symlinks=False)
        return
    except FileExistsError:
        raise error(f"{flag} {target} exists; lagrseq never writes over it: give a new path or move the file away") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
    check_output(target, flag, False, error)
    os.rename(scratch, target)
