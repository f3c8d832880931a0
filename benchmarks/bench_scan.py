"""Scan benchmark: how long a log padded with zeros takes to be judged (issue 37).

    PYTHONPATH=. python benchmarks/bench_scan.py                  # 300 MB of zeros, 3 repeats
    PYTHONPATH=. python benchmarks/bench_scan.py --mb 1000 --repeat 5

Writes the golden log's first records (its magic and header; and, for the second case, its
first 13,000 bytes, which hold flushed episodes) followed by zeros up to ``--mb`` megabytes, as
a file on disk (made with ``truncate``: sparse where the file system allows, which reads as fast
as the page cache), then times, each in a fresh process (``python -m lagrseq``, so the figures
include start-up):

1. ``lagrseq recover`` of the bare start (nothing to keep: one line);
2. ``lagrseq recover`` of the partial log (its flushed episodes kept: one line saying how many);
3. ``lagrseq replay`` of a folder holding the bare start (one line).

Each figure is the median wall and CPU time of ``--repeat`` runs (n given). Target: 300 MB in
well under 10 s (before the fix: about 2 s a MB, so 10 minutes).

Then floods of small valid records (``--flood-mb`` megabytes, default 50) after the golden log's
data up to a flushed chunk, each judged by ``lagrseq recover`` (its flushed episodes kept):

4. message index records (15 bytes each) after a chunk: refused at the 65th after it;
5. statistics records: refused at the second;
6. metadata records (17 bytes each): walked up to the record cap (``MAX_SCAN_RECORDS``);
7. empty chunks (49 bytes) each followed by a message index: the worst the bounds allow, each
   chunk opened, up to the record cap.

Before the bounds, a flood was walked to its end at about 0.23 s a MB (50 MB: about 12 s).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"


def _padded(path: Path, start: bytes, size: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as handle:
        handle.write(start)
        handle.truncate(size)
    return path


def _timed(args: list[str]) -> tuple[float, float, int, str]:
    """Wall seconds, CPU seconds of the child, its exit status, its last stderr line."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "lagrseq", *args],
        capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600, check=False,
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = (done.stderr or done.stdout).strip().splitlines()
    return wall, cpu, done.returncode, lines[-1] if lines else ""


_INDEX = struct.pack("<BQHI", 0x07, 6, 1, 0)
_STATISTICS = struct.pack("<BQ", 0x0B, 46) + bytes(46)
_METADATA = struct.pack("<BQII", 0x0C, 8, 0, 0)
_EMPTY_CHUNK = struct.pack("<BQQQQIIQ", 0x06, 40, 0, 0, 0, 0, 0, 0)
_FLUSHED = 12635  # the golden log up to a chunk and its message indexes


def _flood(path: Path, start: bytes, unit: bytes, size: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(start + unit * max(size // len(unit), 1))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mb", type=int, default=300, help="the file's size in megabytes (10^6 bytes)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per case (the median is printed)")
    parser.add_argument("--flood-mb", type=int, default=50, help="the size of each flood of small records, in megabytes")
    args = parser.parse_args()
    data = GOLDEN.read_bytes()
    header_end = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    size = args.mb * 1_000_000
    with tempfile.TemporaryDirectory(prefix="bench-scan-") as scratch:
        root = Path(scratch)
        bare = _padded(root / "bare" / "trial-000.mcap", data[:header_end], size)
        partial = _padded(root / "partial" / "trial-000.mcap.partial", data[:13000], size)
        cases = {
            "recover, nothing to keep": lambda i: ["recover", str(bare), "--out", str(root / f"bare-{i}.mcap")],
            "recover, flushed episodes kept": lambda i: ["recover", str(partial), "--out", str(root / f"partial-{i}.mcap")],
            "replay": lambda i: ["replay", str(bare.parent), "--out", str(root / f"reports-{i}")],
        }
        print(f"{args.mb} MB of zeros after a valid MCAP start; median of n = {args.repeat} runs per case, "
              f"each a fresh `python -m lagrseq` (start-up included)")
        for name, command in cases.items():
            runs = [_timed(command(i)) for i in range(args.repeat)]
            wall = statistics.median(r[0] for r in runs)
            cpu = statistics.median(r[1] for r in runs)
            print(f"  {name:<32} wall {wall:6.2f} s (range {min(r[0] for r in runs):.2f}-{max(r[0] for r in runs):.2f}), "
                  f"CPU {cpu:6.2f} s, exit {runs[-1][2]}")
            print(f"    {runs[-1][3][:300]}")
        floods = {
            "message indexes after a chunk": _INDEX,
            "statistics records": _STATISTICS,
            "metadata records": _METADATA,
            "empty chunks, each indexed": _EMPTY_CHUNK + _INDEX,
        }
        print(f"{args.flood_mb} MB floods of small valid records after the golden log's first flushed episodes; "
              f"`lagrseq recover`, median of n = {args.repeat} runs each")
        for name, unit in floods.items():
            flood = _flood(root / "flood" / f"{len(unit)}-{unit[0]}" / "trial-000.mcap.partial", data[:_FLUSHED], unit, args.flood_mb * 1_000_000)
            runs = [_timed(["recover", str(flood), "--out", str(flood.parent / f"out-{i}.mcap")]) for i in range(args.repeat)]
            wall = statistics.median(r[0] for r in runs)
            cpu = statistics.median(r[1] for r in runs)
            print(f"  {name:<32} wall {wall:6.2f} s (range {min(r[0] for r in runs):.2f}-{max(r[0] for r in runs):.2f}), "
                  f"CPU {cpu:6.2f} s, exit {runs[-1][2]}")
            print(f"    {runs[-1][3][:300]}")


if __name__ == "__main__":
    main()
