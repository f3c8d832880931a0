"""Output paths given on the command line, checked before anything is written.

``run``, ``reproduce`` and ``replay`` check their output directory here first, so a path that
is a file, lies below a file, or cannot be written ends in one line naming the flag, the path and
the fix, instead of a traceback halfway through (``recover`` and ``cache export`` check their own
targets where they write).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from lagrseq.errors import UsageError


def writable_directory(path: str | Path, flag: str = "--out") -> Path:
    """``path`` as a directory this process can write into (created if missing)."""
    path = Path(path)
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

