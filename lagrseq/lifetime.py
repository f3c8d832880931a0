"""Helper processes that end with the process that started them.

Worker processes (the run's trial pool, replay's log readers and its figure painter) call
:func:`die_with_parent` first thing, so that a parent killed with SIGKILL (which no handler sees)
leaves nothing behind: the workers end, and with them multiprocessing's resource tracker, which
reads until every holder of its pipe is gone. Standard library only: every layer may use it
(``lagrseq replay`` never imports :mod:`lagrseq.running`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1
"""``prctl`` option: the signal the kernel sends this process when its parent thread ends."""


def die_with_parent(poll_s: float = 1.0) -> None:
    """End this process when the process that started it dies, however it dies (SIGKILL
    included), so no worker outlives a stopped run.

    Linux: the kernel sends SIGKILL at the parent's death (``prctl(PR_SET_PDEATHSIG)``); the
    parent may have died before the call, so the parent is checked once after it. Elsewhere, and
    as a second line on Linux, a daemon thread polls ``os.getppid()`` every ``poll_s``."""
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent or parent == 1:
        os._exit(143)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(143)

    threading.Thread(target=watch, name="lagrseq-parent-watch", daemon=True).start()
