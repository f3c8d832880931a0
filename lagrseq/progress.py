"""Progress bars on stderr, one way for every command (``run``, ``reproduce``, ``frontier``,
``audit``), and lines printed while a bar is shown.

A terminal that reports no size (0 columns: some containers, serial consoles, ``TERM=dumb``)
made tqdm's self-sizing bar print nothing but empty lines; there the bar is 80 columns wide
on a 24-row screen instead. A line printed while a bar is on screen goes through :func:`say`, which clears the
bar, prints the line and redraws the bar below it (a plain ``print`` was glued onto the bar's
line: ``0/1000 [00:00<?, ?ep/s]resuming: ...``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import Any

FALLBACK_COLUMNS, FALLBACK_ROWS = 80, 24
"""Bar width, and screen height, where the terminal does not say its own (tqdm hides every bar
below the screen's last row, and a 0-row screen has none)."""


def _columns() -> int:
    """The terminal's width, 0 when it does not report one."""
    try:
        return os.get_terminal_size(sys.stderr.fileno()).columns
    except (OSError, ValueError, AttributeError):
        return 0


def bar(total: float, unit: str = "it", desc: str | None = None, quiet: bool = False) -> Any:
    """A tqdm bar on stderr: sized by the terminal where it reports a size, else 80 columns."""
    from tqdm import tqdm

    sized = _columns() > 0
    if desc is not None:  # a model name or a path from outside: no key, no control characters
        from lagrseq.keys import scrub
        from lagrseq.text import printable

        desc = printable(scrub(desc))
    return tqdm(
        total=total, unit=unit, desc=desc, disable=quiet, file=sys.stderr,
        dynamic_ncols=sized, ncols=None if sized else FALLBACK_COLUMNS, nrows=None if sized else FALLBACK_ROWS,
    )


def say(line: str, stderr: bool = False) -> None:
    """Print ``line`` to stdout (``stderr``: to stderr) on a line of its own, above any progress
    bar on screen (every guarded API key blanked out of it: :func:`lagrseq.keys.scrub`)."""
    from lagrseq.keys import scrub

    line = scrub(line)
    stream = sys.stderr if stderr else sys.stdout
    if "tqdm" not in sys.modules:  # no bar was ever made: a plain line (what tqdm.write prints then)
        print(line, file=stream, flush=True)
        return
    from tqdm import tqdm

    tqdm.write(line, file=stream)
    stream.flush()


def ignore(_line: str) -> None:
    """A channel that drops its lines (``Reporter(say, warn=ignore)``: lines said, warnings not)."""


class Reporter:
    """What a long command tells its user, one object handed down its phases (the callback habit of
    Stable-Baselines3): lines (:meth:`say`), warnings (:meth:`warn`), the run starting
    (:meth:`on_run`), an experiment timed (:meth:`on_calibrated`), and the one progress bar they
    all move (:attr:`bar`, None until the command shows one)."""

    def __init__(
        self, say: Callable[[str], None] = print, warn: Callable[[str], None] | None = None, quiet: bool = False
    ) -> None:
        self._say = say
        self._warn = warn
        self.quiet = quiet
        """No bar on screen (lines are still said)."""
        self.bar: Any = None

    @classmethod
    def silent(cls) -> Reporter:
        """A reporter that says nothing and shows no bar."""
        return cls(ignore, quiet=True)

    def say(self, line: str) -> None:
        """A line of the command's own output (stdout in the command line)."""
        self._say(line)

    def warn(self, line: str) -> None:
        """A line about something that went wrong (a failed run), or a helper process's own line
        (a llama.cpp server starting): stderr in the command line; said where no warning channel
        was given (``warn=ignore``: dropped)."""
        (self._warn or self._say)(line)

    def on_run(self, description: str) -> None:
        """A run starts in this process: the bar says which."""
        if self.bar is not None and hasattr(self.bar, "set_description"):
            self.bar.set_description(description)

    def on_calibrated(self) -> None:
        """One experiment timed: the calibration bar moves by one."""
        if self.bar is not None:
            self.bar.update(1)


def duration(seconds: float) -> str:
    """A duration as people read it: seconds, minutes or hours."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
