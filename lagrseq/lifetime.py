"""Helper processes that end with the process that started them.

Worker processes (the run's trial pool, replay's log readers and its figure painter) call
:func:`die_with_parent` first thing, so that a parent killed with SIGKILL (which no handler sees)
leaves nothing behind: the workers end, and with them multiprocessing's resource tracker, which
reads until every holder of its pipe is gone. Standard library only: every layer may use it
(``lagrseq replay`` never imports :mod:`lagrseq.running`).

:class:`ProcessWindow` stops the processes that code run inside it left behind (a plugin that
starts a child or a daemon while it loads: :mod:`lagrseq.registry`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Mapping
from typing import Any

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



PR_SET_CHILD_SUBREAPER = 36
"""``prctl`` option: orphans among this process's descendants are reparented to it (not to init)."""
PR_GET_CHILD_SUBREAPER = 37
"""``prctl`` option: read that setting (into an ``int``)."""
REAP_WAIT_S = 2.0
"""How long :meth:`ProcessWindow.close` waits for the processes it killed to be reaped."""
_KILL_ROUNDS = 4
"""Scans for new processes (each followed by SIGKILL to all it found) before giving up: a process
may fork between a scan and its kill."""


def _proc_stat(pid: int) -> tuple[str, int, int] | None:
    """``(state, ppid, start time in clock ticks)`` of ``pid`` from ``/proc/PID/stat``, None if
    it is gone. The fields are read after the last ``)``: the command name (field 2) may hold
    spaces and parentheses."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as file:
            data = file.read()
    except OSError:
        return None
    fields = data[data.rfind(b")") + 2 :].split()
    try:  # fields[0] is field 3 (state), fields[1] field 4 (ppid), fields[19] field 22 (start time)
        return fields[0].decode("ascii", "replace"), int(fields[1]), int(fields[19])
    except (IndexError, ValueError):
        return None


def descendants(root: int | None = None, skip: Mapping[int, int] | None = None) -> dict[int, int]:
    """Every process whose parent chain reaches ``root`` (default: this process), as
    ``{pid: start time}``, from one walk of ``/proc`` (Linux; elsewhere empty). A process in
    ``skip`` (same pid and start time) is left out with its whole subtree."""
    root = os.getpid() if root is None else root
    skip = skip or {}
    try:
        names = os.listdir("/proc")
    except OSError:
        return {}
    children: dict[int, list[tuple[int, int]]] = {}
    for name in names:
        if not name.isdigit():
            continue
        stat = _proc_stat(int(name))
        if stat is not None:
            children.setdefault(stat[1], []).append((int(name), stat[2]))
    found: dict[int, int] = {}
    pending = [root]
    while pending:
        for pid, start in children.get(pending.pop(), ()):
            if pid in found or pid == root or skip.get(pid) == start:
                continue
            found[pid] = start
            pending.append(pid)
    return found


def _prctl() -> Any:
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl.restype = ctypes.c_int
    return libc.prctl


class ProcessWindow:
    """The processes code run between :meth:`open` and :meth:`close` leaves behind, stopped.

    ``open`` makes this process a child subreaper (``prctl(PR_SET_CHILD_SUBREAPER)``: a daemon
    that double-forks is reparented to this process, not to init, so it stays a descendant) and
    records this process's descendants. ``close`` finds the descendants that were not there (pid
    and start time, so a reused pid is not taken for an old process), sends them all SIGKILL at
    once (all collected first: a parent's death then cannot carry a child out of reach), reaps
    them (zombies too) for at most :data:`REAP_WAIT_S`, restores the earlier subreaper setting and
    returns how many were still running. A process that existed at ``open``, and its subtree, is
    never touched. Linux only: elsewhere (no ``prctl``, no ``/proc``) ``close`` returns 0 and stops nothing."""

    def __init__(self) -> None:
        self._before: dict[int, int] | None = None
        self._previous: int | None = None

    def open(self) -> ProcessWindow:
        if not sys.platform.startswith("linux"):
            return self
        try:
            import ctypes

            prctl = _prctl()
            previous = ctypes.c_int(0)
            if prctl(PR_GET_CHILD_SUBREAPER, ctypes.byref(previous), 0, 0, 0) != 0:
                return self
            if prctl(PR_SET_CHILD_SUBREAPER, ctypes.c_ulong(1), 0, 0, 0) != 0:
                return self
            self._previous = previous.value
        except (OSError, AttributeError):
            return self
        self._before = descendants()
        return self

    def close(self) -> int:
        if self._before is None:
            return 0
        before, self._before = self._before, None
        stopped: dict[int, int] = {}
        running = 0
        try:
            for _ in range(_KILL_ROUNDS):
                new = {pid: start for pid, start in descendants(skip=before).items() if stopped.get(pid) != start}
                if not new:
                    break
                for pid in new:  # all found first, then all killed
                    stat = _proc_stat(pid)
                    running += stat is not None and stat[0] != "Z"  # a zombie has ended already
                    with contextlib.suppress(OSError):
                        os.kill(pid, signal.SIGKILL)
                stopped.update(new)
            self._reap(stopped)
        finally:
            with contextlib.suppress(OSError, AttributeError):
                import ctypes

                _prctl()(PR_SET_CHILD_SUBREAPER, ctypes.c_ulong(self._previous or 0), 0, 0, 0)
        return running

    @staticmethod
    def _reap(stopped: Mapping[int, int]) -> None:
        """Wait (without blocking, for at most :data:`REAP_WAIT_S`) until each stopped process is
        reaped or gone: the killed ones are this process's children, directly or reparented to
        it as the subreaper, so their zombies are this process's to collect."""
        left = dict(stopped)
        deadline = time.monotonic() + REAP_WAIT_S
        while left and time.monotonic() < deadline:
            for pid, start in list(left.items()):
                try:
                    if os.waitpid(pid, os.WNOHANG)[0] == pid:
                        del left[pid]
                        continue
                except ChildProcessError:
                    stat = _proc_stat(pid)
                    if stat is None or stat[2] != start:  # gone (reaped by its own parent)
                        del left[pid]
                        continue
                except OSError:
                    del left[pid]
                    continue
            if left:
                time.sleep(0.01)
