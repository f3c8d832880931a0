"""The stand-in llama.cpp server (``tests/llm/fake_llama``), a model file it accepts, and what
tells a test that a process it started is gone."""

from __future__ import annotations

import re
import time
from pathlib import Path

FAKE = Path(__file__).resolve().parents[1] / "llm" / "fake_llama"
GGUF = b"GGUF\x03\x00\x00\x00" + bytes(56)


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def gone(pid: int, within_s: float = 20.0) -> bool:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        if not alive(pid):
            return True
        time.sleep(0.05)
    return False


def start_line(text: str) -> tuple[int, Path]:
    match = re.search(r"\(pid (\d+), .*; log (\S+)\)", text)
    assert match, text
    return int(match.group(1)), Path(match.group(2))
