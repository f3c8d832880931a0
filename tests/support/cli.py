"""The command line run in this process or in a fresh interpreter: its exit status and output,
and the one line of a refused command."""

from __future__ import annotations

import io
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from lagrseq.cli import main


def cli(*argv: str) -> tuple[int, str, str]:
    """``lagrseq ARGV`` in this process: (exit status, stdout, stderr); argparse's exits count."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            status = main(list(argv))
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else 1
    return status, out.getvalue(), err.getvalue()


def refused(*argv: str) -> str:
    """The one stderr line of a refused command (exit status 2, no traceback)."""
    status, _, err = cli(*argv)
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1, (status, err)
    assert "Traceback" not in err
    return lines[0]


def files_under(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


ROOT = Path(__file__).resolve().parents[2]
"""The checkout whose lagrseq the fresh interpreters run."""


def lagrseq(*args: str, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``python -m lagrseq ARGS`` in a fresh interpreter with a bare environment (and ``env``)."""
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", **(env or {})},
        timeout=timeout,
    )


def one_line(done: subprocess.CompletedProcess[str]) -> str:
    """The one stderr line of a fresh interpreter's refused command (exit status 2, no traceback)."""
    assert done.returncode == 2, (done.returncode, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert "Traceback" not in done.stderr
    return lines[0]
