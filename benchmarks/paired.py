"""``--vs REF`` for the benchmarks: the same workload from this tree and from a git worktree of
REF, in alternating runs, compared in CPU time.

A workload is a command line (``python -c CODE`` or ``python -m lagrseq ...``) run in a fresh
process with ``PYTHONPATH`` set to one tree, so each run pays its own imports and start-up, as a
user's process does. Its CPU time is the user + system time of that process and of every
process it waited for (its worker pool), from ``os.wait4``. Runs alternate (HEAD, REF, REF,
HEAD, ...), so a machine whose load drifts slows both alike; each pair gives one ratio
REF / HEAD (above 1: this tree is faster), and the median ratio is the figure reported.

The worktree is made with ``git worktree add --detach`` under a temporary directory, byte-compiled
once (``compileall``: runs do not write bytecode, so each tree runs from what is compiled before
the pairs start; compile this tree too, ``python -m compileall -q lagrseq``, for the same footing),
and removed at the end (``git worktree prune`` cleans up after a run that was killed).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def add_vs_argument(parser: object) -> None:
    parser.add_argument(  # type: ignore[attr-defined]
        "--vs",
        metavar="REF",
        default=None,
        help="also run the same workload from a git worktree of REF (e.g. f2d2ceb), alternating "
        "with this tree, and print paired CPU-time ratios REF / this tree",
    )
    parser.add_argument(  # type: ignore[attr-defined]
        "--pairs", type=int, default=3, help="with --vs: alternating pairs of runs (default 3)"
    )


@contextlib.contextmanager
def worktree(ref: str) -> Iterator[Path]:
    """A detached git worktree of ``ref`` under a temporary directory (removed afterwards)."""
    commit = subprocess.run(
        ["git", "rev-parse", "--verify", f"{ref}^{{commit}}"], cwd=HERE, capture_output=True, text=True
    )
    if commit.returncode != 0:
        sys.exit(f"--vs {ref}: not a commit of this repository ({commit.stderr.strip()})")
    scratch = Path(tempfile.mkdtemp(prefix="lagrseq-vs-"))
    tree = scratch / ref.replace("/", "-")
    subprocess.run(
        ["git", "worktree", "add", "--detach", "--quiet", str(tree), commit.stdout.strip()],
        cwd=HERE, check=True,
    )
    # byte-compiled once, as an installed package is and as this tree usually is (its tests write
    # __pycache__): an uncompiled REF would pay compiling its modules in every run, which made
    # short whole-process workloads (a cube run) look faster here than they are
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "lagrseq")], check=False, stdout=subprocess.DEVNULL)
    try:
        yield tree
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=HERE, check=False)
        shutil.rmtree(scratch, ignore_errors=True)


def cpu_seconds(command: Sequence[str], tree: Path, cwd: Path | None = None) -> tuple[float, float]:
    """Run ``command`` with ``tree`` first on the import path; user + system CPU seconds of the
    process and of the processes it waited for, and wall seconds. A failing command stops the
    benchmark."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}
    started = time.perf_counter()
    process = subprocess.Popen(list(command), cwd=cwd or tree, env=env, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        sys.exit(f"workload failed in {tree} (exit status {process.returncode}): {' '.join(command)[:300]}")
    return float(usage.ru_utime + usage.ru_stime), wall


@dataclass
class Paired:
    """CPU seconds of each run of the two trees, in pair order."""

    head: list[float] = field(default_factory=list)
    ref: list[float] = field(default_factory=list)
    head_wall: list[float] = field(default_factory=list)
    ref_wall: list[float] = field(default_factory=list)

    @property
    def ratios(self) -> list[float]:
        return [r / h for h, r in zip(self.head, self.ref, strict=True)]

    def line(self, what: str, ref: str) -> str:
        ratios = self.ratios
        return (
            f"{what}: CPU {statistics.median(self.head):.2f} s here vs {statistics.median(self.ref):.2f} s "
            f"at {ref} (medians of n={len(ratios)} alternating pairs); REF/HERE ratio median "
            f"{statistics.median(ratios):.2f}x (pairs: {', '.join(f'{r:.2f}' for r in ratios)}); "
            f"wall ratio median {statistics.median(r / h for h, r in zip(self.head_wall, self.ref_wall, strict=True)):.2f}x"
        )


def compare(
    make_command: Callable[[Path], Sequence[str]],
    ref_tree: Path,
    pairs: int,
    cwd: Path | None = None,
    here: Callable[[Path], Sequence[str]] | None = None,
) -> Paired:
    """Run the workload from this tree and from ``ref_tree`` in ``pairs`` alternating pairs (the
    order flips each pair: H R, R H, ...). ``make_command(scratch)`` gives the command line,
    writing whatever it writes under the empty directory ``scratch`` (a new one each run);
    ``here``, if given, gives this tree's (an option REF lacks)."""
    result = Paired()
    for i in range(pairs):
        order = (HERE, ref_tree) if i % 2 == 0 else (ref_tree, HERE)
        seconds, wall = {}, {}
        for tree in order:
            make = here if here is not None and tree == HERE else make_command
            with tempfile.TemporaryDirectory(prefix="lagrseq-vs-run-") as scratch:
                seconds[tree], wall[tree] = cpu_seconds(make(Path(scratch)), tree, cwd)
        result.head.append(seconds[HERE])
        result.ref.append(seconds[ref_tree])
        result.head_wall.append(wall[HERE])
        result.ref_wall.append(wall[ref_tree])
        print(
            f"  pair {i + 1}: here {seconds[HERE]:.2f} s CPU ({wall[HERE]:.1f} s wall), "
            f"ref {seconds[ref_tree]:.2f} s CPU ({wall[ref_tree]:.1f} s wall)",
            flush=True,
        )
    return result
