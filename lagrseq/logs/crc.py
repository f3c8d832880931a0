"""CRC-32 (the IEEE 802.3 polynomial of MCAP's checksums and ``zlib.crc32``), from zlib-ng.

zlib-ng computes it with the CPU's carry-less multiply (PCLMULQDQ, ARMv8 PMULL) where there is
one. Timed with ``timeit`` on 0.7 MB (about a cube LaGR trial's chunks): 0.26 ms with
``zlib.crc32``, 0.012 ms with zlib-ng's; the difference is about a point of the logging overhead
that ``benchmarks/bench_cube.py`` measures. A CRC is exact, so every machine writes the same bytes
either way; where zlib-ng is not installed the standard library's is used.
"""

from __future__ import annotations

try:
    from zlib_ng.zlib_ng import crc32
except ImportError:  # pragma: no cover - a platform zlib-ng publishes no wheel for
    from zlib import crc32

__all__ = ["crc32"]
