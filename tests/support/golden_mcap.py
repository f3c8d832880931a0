"""The golden MCAP log's bytes, and where every length, size and offset field of its records is
(the fields a flipped bit must never turn into a hang or a huge allocation)."""

from __future__ import annotations

import struct
from pathlib import Path

from mcap.opcode import Opcode

GOLDEN = Path(__file__).resolve().parents[2] / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"
DATA = GOLDEN.read_bytes()


MEMORY_BOUND = 32 << 20  # the file is 21 kB; any read of a damaged length would ask for far more


def _str_end(data: bytes, at: int) -> int:
    """End of the length-prefixed string at ``at``."""
    return at + 4 + struct.unpack_from("<I", data, at)[0]


CHUNK_DATA_LENGTHS: list[int] = []


def length_fields(data: bytes) -> list[tuple[int, int]]:
    """``(offset, width)`` of every length, size and offset field of the file's records (and,
    in :data:`CHUNK_DATA_LENGTHS`, where each chunk's data length is)."""
    fields: list[tuple[int, int]] = []
    CHUNK_DATA_LENGTHS.clear()
    pos = 8
    while pos < len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        fields.append((pos + 1, 8))
        b = pos + 9
        if opcode == Opcode.HEADER:
            fields += [(b, 4), (_str_end(data, b), 4)]
        elif opcode == Opcode.SCHEMA:
            name = b + 2
            encoding = _str_end(data, name)
            fields += [(name, 4), (encoding, 4), (_str_end(data, encoding), 4)]
        elif opcode == Opcode.CHANNEL:
            topic = b + 4
            encoding = _str_end(data, topic)
            fields += [(topic, 4), (encoding, 4), (_str_end(data, encoding), 4)]
        elif opcode == Opcode.CHUNK:
            clen = struct.unpack_from("<I", data, b + 28)[0]
            fields += [(b + 16, 8), (b + 28, 4), (b + 32 + clen, 8)]
            CHUNK_DATA_LENGTHS.append(b + 32 + clen)
        elif opcode == Opcode.MESSAGE_INDEX:
            fields.append((b + 2, 4))
        elif opcode == Opcode.CHUNK_INDEX:
            fields += [(b + 16, 8), (b + 24, 8), (b + 32, 4)]
            count = struct.unpack_from("<I", data, b + 32)[0] // 10
            fields += [(b + 36 + 10 * i + 2, 8) for i in range(count)]
            after = b + 36 + 10 * count
            compression = after + 8
            end = _str_end(data, compression)
            fields += [(after, 8), (compression, 4), (end, 8), (end + 8, 8)]
        elif opcode == Opcode.METADATA:
            fields += [(b, 4), (_str_end(data, b), 4)]
        elif opcode == Opcode.METADATA_INDEX:
            fields += [(b, 8), (b + 8, 8), (b + 16, 4)]
        elif opcode == Opcode.STATISTICS:
            fields.append((b + 42, 4))
        elif opcode == Opcode.SUMMARY_OFFSET:
            fields += [(b + 1, 8), (b + 9, 8)]
        elif opcode == Opcode.FOOTER:
            fields += [(b, 8), (b + 8, 8)]
            break
        pos = b + length
    return fields
