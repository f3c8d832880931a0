"""Lockstep: several trials in one process, their network updates computed as one batched call.

Each trial runs its own, unchanged code as a greenlet (a coroutine with its own stack, the
``greenlet`` package; switching is a few microseconds and no thread or OS call): a trial runs
until it asks for a batched operation (:func:`request`) or ends, then the conductor resumes the
next. When every trial still running is waiting, the conductor serves the waiting requests of
one operation in one call and resumes those trials. Which operation it serves first is a question
of speed only: the operations of lagrseq's network groups give every member the same numbers
whoever else is in the batch (``lagrseq.agents.dqn``), so a trial's results never depend on the
other trials. (Threads, tried first, cost 12 to 37 µs a request and several OS context switches.)

Without a conductor (a trial run on its own), :func:`request` runs the operation at once, as a
batch of one: the same code.

Errors: a trial that raises ends (its error is its outcome) and the others go on; an operation
that raises raises in every trial that asked for it. Ctrl-C: the KeyboardInterrupt is raised in
whichever trial (or the conductor) runs at that moment; then every other trial gets a
KeyboardInterrupt where it waits, so each runs its own clean-up (a trial's log keeps its finished
episodes), and :meth:`Conductor.run` raises KeyboardInterrupt.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Hashable, Sequence
from typing import Any

Operation = Callable[[Sequence[Any]], Sequence[Any]]
"""A batched operation: one payload per requesting trial in, one result per payload out."""


class _Slot:
    """One trial: its greenlet, its pending request and its outcome."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.greenlet: Any = None
        self.operation: Operation | None = None
        self.payload: Any = None
        self.result: Any = None
        self.error: BaseException | None = None
        self.done = False
        self.outcome: Any = None


_local = threading.local()  # per OS thread: the conductor running in it


def available() -> bool:
    """Whether lockstep can run here (the ``greenlet`` package, part of the ``dqn`` extra)."""
    import importlib.util

    return importlib.util.find_spec("greenlet") is not None


def current() -> Conductor | None:
    """The conductor of the trial running now, if any."""
    conductor: Conductor | None = getattr(_local, "conductor", None)
    if conductor is None or conductor._slot() is None:
        return None
    return conductor


def request(operation: Operation, payload: Any) -> Any:
    """``operation([payload])[0]``, batched with the other trials' requests of the same
    operation when a trial of a conductor asks."""
    conductor = current()
    if conductor is None:
        return operation([payload])[0]
    slot = conductor._slot()
    assert slot is not None
    return conductor._wait(slot, operation, payload)


class Conductor:
    """Runs trials in lockstep (see the module's docstring). ``shared(key, make)`` gives the
    trials one object per key (a network group) made by the first trial that asks."""

    def __init__(self) -> None:
        self._shared: dict[Hashable, Any] = {}
        self._by_greenlet: dict[Any, _Slot] = {}
        self._hub: Any = None
        self.rounds = 0
        """Batched calls made (for benchmarks and tests)."""

    def shared(self, key: Hashable, make: Callable[[], Any]) -> Any:
        if key not in self._shared:
            self._shared[key] = make()
        return self._shared[key]

    def _slot(self) -> _Slot | None:
        import greenlet

        return self._by_greenlet.get(greenlet.getcurrent())

    def run(self, trials: Sequence[Callable[[], Any]], on_interrupt: Callable[[], None] | None = None) -> list[Any]:
        """Run every trial; returns each one's return value, or the exception it raised.
        ``on_interrupt`` is called first thing after a Ctrl-C (the runner makes a second Ctrl-C
        end the process at once)."""
        import greenlet

        self._hub = greenlet.getcurrent()
        slots = [_Slot(i) for i in range(len(trials))]
        for slot, trial in zip(slots, trials, strict=True):
            slot.greenlet = greenlet.greenlet(functools.partial(self._trial, slot, trial), parent=self._hub)
            self._by_greenlet[slot.greenlet] = slot
        previous = getattr(_local, "conductor", None)
        _local.conductor = self
        try:
            ready = list(slots)  # resumed in this order; each then waits or ends
            while True:
                for slot in ready:
                    slot.greenlet.switch()
                    if isinstance(slot.outcome, KeyboardInterrupt):  # a Ctrl-C inside that trial
                        raise KeyboardInterrupt
                waiting = [slot for slot in slots if not slot.done]
                if not waiting:
                    break
                ready = self._serve(waiting)
        except KeyboardInterrupt:
            if on_interrupt is not None:
                on_interrupt()
            for slot in slots:  # each waiting trial raises where it waits and cleans up
                if not slot.done and slot.greenlet:
                    slot.greenlet.throw(KeyboardInterrupt)
                slot.done = True
            raise
        finally:
            _local.conductor = previous
            self._by_greenlet.clear()
        return [slot.outcome for slot in slots]

    def _serve(self, waiting: list[_Slot]) -> list[_Slot]:
        """Serve the operation fewest trials wait for (the others wait on: those trials catch
        up with them, so the next call is a full batch); returns the trials served."""
        by_operation: dict[Operation, list[_Slot]] = {}
        for slot in waiting:
            assert slot.operation is not None
            by_operation.setdefault(slot.operation, []).append(slot)
        operation, served = min(by_operation.items(), key=lambda item: len(item[1]))
        self.rounds += 1
        try:
            results = operation([slot.payload for slot in served])
        except Exception as exc:  # noqa: BLE001 - reaches every trial that asked
            for slot in served:
                slot.error = exc
        else:
            for slot, result in zip(served, results, strict=True):
                slot.result = result
        return served

    def _trial(self, slot: _Slot, trial: Callable[[], Any]) -> None:
        try:
            slot.outcome = trial()
        except BaseException as exc:  # noqa: BLE001 - the trial's outcome, reported by the caller
            slot.outcome = exc
        finally:
            slot.done = True

    def _wait(self, slot: _Slot, operation: Operation, payload: Any) -> Any:
        slot.operation, slot.payload, slot.result, slot.error = operation, payload, None, None
        self._hub.switch()  # back to the conductor; a Ctrl-C elsewhere is thrown in here
        slot.operation = slot.payload = None
        if slot.error is not None:
            raise slot.error
        return slot.result
