"""Lockstep: trials in threads, one running at a time, their requests served in batched calls.

Plain Python operations stand in for the networks here (tests/agents/test_dqn.py checks that
the network group's batched calls give each member its own numbers; tests/running/test_grid_runs.py
runs whole trials in lockstep)."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Sequence

import pytest

pytest.importorskip("greenlet")

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from lagrseq.agents import lockstep  # noqa: E402
from lagrseq.agents.lockstep import Conductor  # noqa: E402


class Recorder:
    """An operation that adds ``add`` to each payload and records every call's batch."""

    def __init__(self, add: int) -> None:
        self.add = add
        self.calls: list[list[int]] = []
        self.threads: set[int] = set()

    def __call__(self, payloads: Sequence[int]) -> list[int]:
        self.calls.append(list(payloads))
        self.threads.add(threading.get_ident())
        return [p + self.add for p in payloads]


def test_without_a_conductor_a_request_is_a_batch_of_one() -> None:
    op = Recorder(1)
    assert lockstep.current() is None
    assert lockstep.request(op, 41) == 42
    assert op.calls == [[41]]


def test_trials_that_ask_alike_are_served_in_one_call_per_step() -> None:
    op = Recorder(100)
    conductor = Conductor()

    def trial(k: int) -> list[int]:
        assert lockstep.current() is conductor
        return [lockstep.request(op, 10 * k + step) for step in range(5)]

    outcomes = conductor.run([lambda k=k: trial(k) for k in range(4)])  # type: ignore[misc]
    assert outcomes == [[100 + 10 * k + step for step in range(5)] for k in range(4)]
    assert op.calls == [[10 * k + step for k in range(4)] for step in range(5)]
    assert conductor.rounds == 5
    assert op.threads == {threading.get_ident()}  # greenlets: no other thread


def test_the_rarer_operation_is_served_first_so_the_others_catch_up() -> None:
    """Trial 0 asks the secondary operation at its second step, then the primary one: the
    primary's batches stay whole (the rarer request is served first)."""
    primary, secondary = Recorder(1), Recorder(2)
    conductor = Conductor()

    def trial(k: int) -> list[int]:
        out = []
        for step in range(3):
            if k == 0 and step == 1:
                out.append(lockstep.request(secondary, -1))
            out.append(lockstep.request(primary, step))
        return out

    outcomes = conductor.run([lambda k=k: trial(k) for k in range(3)])  # type: ignore[misc]
    assert outcomes == [[1, 1, 2, 3], [1, 2, 3], [1, 2, 3]]
    assert secondary.calls == [[-1]]
    assert primary.calls == [[0, 0, 0], [1, 1, 1], [2, 2, 2]]


def test_a_trial_that_raises_ends_alone_and_the_others_go_on() -> None:
    op = Recorder(0)

    def trial(k: int) -> int:
        for step in range(4):
            lockstep.request(op, step)
            if k == 1 and step == 1:
                raise ValueError("trial 1 broke")
        return k

    outcomes = Conductor().run([lambda k=k: trial(k) for k in range(3)])  # type: ignore[misc]
    assert outcomes[0] == 0 and outcomes[2] == 2
    assert isinstance(outcomes[1], ValueError) and str(outcomes[1]) == "trial 1 broke"
    assert [len(call) for call in op.calls] == [3, 3, 2, 2]


def test_an_operation_that_raises_raises_in_every_trial_that_asked() -> None:
    def broken(payloads: Sequence[int]) -> list[int]:
        raise RuntimeError(f"cannot serve {len(payloads)}")

    def trial() -> str:
        try:
            lockstep.request(broken, 0)
        except RuntimeError as exc:
            return str(exc)
        return "served"

    assert Conductor().run([trial, trial, trial]) == ["cannot serve 3"] * 3


def test_ctrl_c_raises_in_every_trial_at_its_request_then_in_the_caller() -> None:
    """A real SIGINT (sent by the third batched call) interrupts the conductor; every trial then
    raises KeyboardInterrupt where it waits, so each cleans up, and ``run`` raises it;
    ``on_interrupt`` runs first."""
    cleaned: list[int] = []
    told: list[str] = []
    calls = 0

    def interrupting(payloads: Sequence[int]) -> list[int]:
        nonlocal calls
        calls += 1
        if calls == 3:
            os.kill(os.getpid(), signal.SIGINT)  # what a terminal's Ctrl-C sends
        return list(payloads)

    def trial(k: int) -> None:
        try:
            while True:
                lockstep.request(interrupting, k)
        finally:
            cleaned.append(k)

    conductor = Conductor()
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # even under a shell that ignores it
    try:
        with pytest.raises(KeyboardInterrupt):
            conductor.run([lambda k=k: trial(k) for k in range(3)], on_interrupt=lambda: told.append("first"))  # type: ignore[misc]
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sorted(cleaned) == [0, 1, 2] and told == ["first"]
    assert lockstep.current() is None


def test_ctrl_c_inside_a_trial_stops_the_others_too() -> None:
    """The Ctrl-C lands in the trial that runs at that moment: it cleans up, then every other
    trial gets KeyboardInterrupt where it waits, and ``run`` raises it."""
    cleaned: list[int] = []
    op = Recorder(0)

    def trial(k: int) -> None:
        try:
            for step in range(10):
                if k == 1 and step == 2:
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(5)  # the handler raises KeyboardInterrupt here
                lockstep.request(op, step)
        finally:
            cleaned.append(k)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            Conductor().run([lambda k=k: trial(k) for k in range(3)])  # type: ignore[misc]
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sorted(cleaned) == [0, 1, 2]
    assert [len(call) for call in op.calls] == [3, 3]


def test_trials_share_one_object_per_key() -> None:
    conductor = Conductor()
    made: list[str] = []

    def make() -> list[int]:
        made.append("x")
        return []

    def trial(k: int) -> int:
        shared = conductor.shared(("group", 1), make)
        shared.append(k)
        return len(shared)

    assert sorted(conductor.run([lambda k=k: trial(k) for k in range(3)])) == [1, 2, 3]  # type: ignore[misc]
    assert made == ["x"]


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.sampled_from("ab"), max_size=8), min_size=1, max_size=5))
def test_any_pattern_of_requests_gets_what_the_trials_get_alone(plans: list[list[str]]) -> None:
    """Whatever each trial asks and in whatever order, its results are those it gets without a
    conductor, and every request is served exactly once."""
    ops = {"a": Recorder(1), "b": Recorder(1000)}

    def trial(k: int) -> list[int]:
        return [lockstep.request(ops[name], 100 * k + i) for i, name in enumerate(plans[k])]

    alone = [trial(k) for k in range(len(plans))]
    for op in ops.values():
        op.calls.clear()
    assert Conductor().run([lambda k=k: trial(k) for k in range(len(plans))]) == alone  # type: ignore[misc]
    served = sorted(p for op in ops.values() for call in op.calls for p in call)
    assert served == sorted(100 * k + i for k, plan in enumerate(plans) for i in range(len(plan)))
