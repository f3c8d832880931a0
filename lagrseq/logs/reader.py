"""Read lagrseq MCAP logs back: metadata, configuration and decoded messages.

Only the ``mcap`` library and the standard library: replay needs neither gymnasium nor torch.
Foreign errors (mcap, struct, json) become one-line :class:`~lagrseq.errors.LogError` messages.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader

from lagrseq.errors import LogError
from lagrseq.logs.sink import RUN_METADATA, STATUS_METADATA

_READ_ERRORS = (McapError, struct.error, EOFError, ValueError, KeyError, IndexError, OSError)


@dataclass(frozen=True)
class LogInfo:
    """What a log says about itself (from its metadata records)."""

    path: Path
    run: dict[str, str]
    status: dict[str, str] = field(default_factory=dict)

    @property
    def config(self) -> dict[str, Any]:
        return json.loads(self.run["config"])

    @property
    def complete(self) -> bool:
        return self.status.get("status") == "complete"


def _broken(path: Path, exc: BaseException) -> LogError:
    return LogError(
        f"{path}: not a readable MCAP log ({type(exc).__name__}: {exc}); "
        f"if a crash cut it short, run `lagrseq recover {path}`"
    )


def read_info(path: str | Path) -> LogInfo:
    """Metadata of a finished log (uses the summary section, no message data is read)."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            reader = make_reader(handle)
            records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except _READ_ERRORS as exc:
        raise _broken(path, exc) from None
    if RUN_METADATA not in records:
        raise LogError(f"{path}: MCAP file has no {RUN_METADATA!r} metadata; not a lagrseq log")
    return LogInfo(path, records[RUN_METADATA], records.get(STATUS_METADATA, {}))


def is_complete(path: str | Path) -> bool:
    """True when ``path`` is a readable log of a trial that ran to its end."""
    try:
        return read_info(path).complete
    except LogError:
        return False


def iter_messages(
    path: str | Path, topics: Sequence[str] | None = None
) -> Iterator[tuple[str, dict[str, Any]]]:
    """Decoded ``(topic, record)`` pairs in log-time order; ``topics`` restricts what is read
    (chunks holding none of them are not decompressed)."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            reader = make_reader(handle)
            for _schema, channel, message in reader.iter_messages(
                topics=list(topics) if topics else None, log_time_order=True
            ):
                yield channel.topic, json.loads(message.data)
    except _READ_ERRORS as exc:
        raise _broken(path, exc) from None


def read_topic(path: str | Path, topic: str) -> list[dict[str, Any]]:
    """Every record of one topic."""
    return [record for _, record in iter_messages(path, [topic])]


def find_logs(paths: Sequence[str | Path]) -> list[Path]:
    """Every ``*.mcap`` file under the given files and directories, sorted."""
    found: list[Path] = []
    for item in paths:
        item = Path(item)
        if item.is_dir():
            found.extend(sorted(item.rglob("*.mcap")))
        elif item.suffix == ".mcap" and item.exists():
            found.append(item)
        else:
            raise LogError(f"{item}: no such MCAP file or directory")
    return sorted(set(found))
