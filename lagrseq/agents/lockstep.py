"""Lockstep: several trials in one process, their network updates computed as one batched call.

Each trial runs its own, unchanged code in a thread of its own, but only one thread runs at a
time: a trial runs until it asks for a batched operation (:func:`request`) or ends, then hands
on to the next. When every trial still running is waiting, the last to ask serves the waiting
requests of one operation in one call and resumes those trials. Which operation it serves first is a question of speed only: the operations of
lagrseq's network groups give every member the same numbers whoever else is in the batch
(``lagrseq.agents.dqn``), so a trial's results never depend on the other trials.

Without a conductor (a trial run on its own), :func:`request` runs the operation at once, as a
batch of one: the same code.

Errors: a trial that raises ends (its error is its outcome) and the others go on; an operation
that raises raises in every trial that asked for it. Ctrl-C (KeyboardInterrupt in the thread
that called :meth:`Conductor.run`, which only waits): every trial raises KeyboardInterrupt at its next request (or at once if it is
waiting), so each runs its own clean-up (a trial's log keeps its finished episodes), and then
the conductor raises KeyboardInterrupt.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable, Sequence
from typing import Any

Operation = Callable[[Sequence[Any]], Sequence[Any]]
"""A batched operation: one payload per requesting trial in, one result per payload out."""


class _Slot:
    """One trial: its thread, the lock it waits on, its pending request and its outcome."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.go = threading.Lock()
        self.go.acquire()  # held until the conductor resumes the trial
        self.operation: Operation | None = None
        self.payload: Any = None
        self.result: Any = None
        self.error: BaseException | None = None
        self.done = False
        self.outcome: Any = None
        self.thread: threading.Thread | None = None


_local = threading.local()


def current() -> Conductor | None:
    """The conductor of the trial this thread runs, if any."""
    return getattr(_local, "conductor", None)


def request(operation: Operation, payload: Any) -> Any:
    """``operation([payload])[0]``, batched with the other trials' requests of the same
    operation when this thread is a trial of a conductor."""
    conductor = current()
    if conductor is None:
        return operation([payload])[0]
    return conductor._wait(_local.slot, operation, payload)


class Conductor:
    """Runs trials in lockstep (see the module's docstring). ``shared(key, make)`` gives the
    trials one object per key (a network group) made by the first trial that asks.

    The trials pass a baton: a trial that asks for an operation resumes the next trial of the
    round and waits; the last one to ask serves the waiting requests (in its own thread) and
    resumes the trials it served. One thread switch per request; the calling thread only
    waits for the end (or a Ctrl-C)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()  # the baton's state: queue, interrupted
        self._finished = threading.Lock()
        self._finished.acquire()  # released when the last trial ends
        self._interrupted = False
        self._slots: list[_Slot] = []
        self._queue: list[_Slot] = []
        """The trials still to resume in this round, in order."""
        self._shared: dict[Hashable, Any] = {}
        self._shared_lock = threading.Lock()
        self.rounds = 0
        """Batched calls made (for benchmarks and tests)."""

    def shared(self, key: Hashable, make: Callable[[], Any]) -> Any:
        with self._shared_lock:
            if key not in self._shared:
                self._shared[key] = make()
            return self._shared[key]

    def run(self, trials: Sequence[Callable[[], Any]], on_interrupt: Callable[[], None] | None = None) -> list[Any]:
        """Run every trial; returns each one's return value, or the exception it raised.
        ``on_interrupt`` is called first thing after a Ctrl-C (the runner makes a second Ctrl-C
        end the process at once)."""
        slots = self._slots = [_Slot(i) for i in range(len(trials))]
        if not slots:
            return []
        self._queue = slots[1:]
        for slot, trial in zip(slots, trials, strict=True):
            slot.thread = threading.Thread(target=self._trial, args=(slot, trial), name=f"lagrseq-trial-{slot.index}", daemon=True)
            slot.thread.start()
        slots[0].go.release()
        try:
            self._finished.acquire()
        except KeyboardInterrupt:
            if on_interrupt is not None:
                on_interrupt()
            with self._lock:
                self._interrupted = True
                for slot in slots:  # a waiting trial wakes and raises; a running one at its next request
                    if not slot.done and slot.go.locked():
                        slot.go.release()
            self._join()
            raise
        self._join()
        return [slot.outcome for slot in slots]

    def _join(self) -> None:
        for slot in self._slots:
            assert slot.thread is not None
            slot.thread.join()

    def _serve(self, waiting: list[_Slot], current: _Slot) -> list[_Slot]:
        """Serve the operation fewest trials wait for (the others wait on: those trials catch
        up with them, so the next call is a full batch); returns the trials served, ``current``
        (the serving trial) first when it is one of them."""
        by_operation: dict[Operation, list[_Slot]] = {}
        for slot in waiting:
            assert slot.operation is not None
            by_operation.setdefault(slot.operation, []).append(slot)
        operation, served = min(by_operation.items(), key=lambda item: len(item[1]))
        self.rounds += 1
        try:
            results = operation([slot.payload for slot in served])
        except BaseException as exc:  # noqa: BLE001 - reaches every trial that asked
            for slot in served:
                slot.error = exc
        else:
            for slot, result in zip(served, results, strict=True):
                slot.result = result
        if current in served:
            served.remove(current)
            served.insert(0, current)
        return served

    def _pass(self, slot: _Slot) -> bool:
        """``slot`` waits for an operation or has ended: resume the next trial of the round, or,
        at the end of a round, serve the waiting trials first. Returns whether ``slot`` must
        wait for its turn (False: it is the next to run, or it ended)."""
        while True:
            with self._lock:
                if self._interrupted:
                    return False
                if self._queue:
                    following = self._queue.pop(0)
                    if following is slot:
                        return False
                    following.go.release()
                    return not slot.done
                waiting = [s for s in self._slots if not s.done]
                if not waiting:
                    self._finished.release()
                    return False
            self._queue = self._serve(waiting, slot)

    def _trial(self, slot: _Slot, trial: Callable[[], Any]) -> None:
        _local.conductor = self
        _local.slot = slot
        slot.go.acquire()
        try:
            if self._interrupted:
                raise KeyboardInterrupt
            slot.outcome = trial()
        except BaseException as exc:  # noqa: BLE001 - the trial's outcome, reported by the caller
            slot.outcome = exc
        finally:
            slot.done = True
            _local.conductor = None
            self._pass(slot)

    def _wait(self, slot: _Slot, operation: Operation, payload: Any) -> Any:
        if self._interrupted:
            raise KeyboardInterrupt
        slot.operation, slot.payload, slot.result, slot.error = operation, payload, None, None
        if self._pass(slot):
            slot.go.acquire()
        slot.operation = slot.payload = None
        if self._interrupted:
            raise KeyboardInterrupt
        if slot.error is not None:
            raise slot.error
        return slot.result
