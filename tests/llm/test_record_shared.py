"""Several ``lagrseq record`` processes into one store share what they record.

Four ``record --samples 3`` processes started at once into one store could end with up to 12
answers per key, if each read the store before any of them had stored anything and each paid for
the whole set. A recorder claims a key (``RecordStore.claim``) and reads it again before it
pays; the fake server on 127.0.0.1 counts the requests.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from lagrseq.llm.store import CLAIMS_DIR, RecordStore
from tests.llm.conftest import KEY_ENV, FakeOpenAI

ROOT = Path(__file__).resolve().parents[2]
PREFIXES = 8
"""The cube task's default prompt set (8 prefixes; one request per sample on an ollama server)."""


def _hold_until(server: FakeOpenAI, first: int) -> None:
    """The first ``first`` requests are answered only once all of them have arrived (at most
    10 s): the recorders are certainly asking at the same time."""
    together = threading.Event()
    count = 0
    lock = threading.Lock()
    answer = server.responder

    def held(prompt: str, temperature: float) -> str:
        nonlocal count
        with lock:
            count += 1
            mine = count
        if mine <= first:
            if mine == first:
                together.set()
            together.wait(10.0)
        return answer(prompt, temperature)

    server.responder = held


def _recorders(server: FakeOpenAI, store: Path, processes: int, *extra: str) -> list[subprocess.CompletedProcess[str]]:
    args = [sys.executable, "-m", "lagrseq", "record", "cube-stacking", "--model", "gpt-4o-mini", "--temperature", "1",
            "--store", str(store), "--base-url", server.url, "--api-key-env", KEY_ENV, "--server", "ollama", "--quiet",
            "--samples", "3", *extra]
    env = {"PYTHONPATH": str(ROOT), "PATH": os.environ.get("PATH", "/usr/bin:/bin"), KEY_ENV: "sk-test-shared-0123456789"}
    started = [subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(processes)]
    done = []
    for process in started:
        out, err = process.communicate(timeout=180)
        done.append(subprocess.CompletedProcess(args, process.returncode, out, err))
    return done


@pytest.mark.parametrize(("processes", "extra"), [(3, ()), (4, ("--concurrency", "2"))], ids=["one-at-a-time", "concurrency-2"])
def test_recorders_into_one_store_pay_for_each_answer_once(tmp_path: Path, server: FakeOpenAI, processes: int, extra: tuple[str, ...]) -> None:
    store = tmp_path / "store"
    RecordStore(store).close()  # the store exists before they start (as a shared one does)
    _hold_until(server, processes)
    done = _recorders(server, store, processes, *extra)
    for result in done:
        assert result.returncode == 0, result.stderr
    with RecordStore(store, create=False) as opened:
        held = {entry.key: len(entry.samples) for entry in opened.entries()}
    assert len(held) == PREFIXES and set(held.values()) == {3}, held
    assert len(server.requests) == 3 * PREFIXES  # no answer paid twice
    assert not list((store / CLAIMS_DIR).iterdir())  # every claim let go


def test_a_claim_excludes_other_holders_until_released(tmp_path: Path) -> None:
    key = "ab" * 32
    with RecordStore(tmp_path / "s") as first, RecordStore(tmp_path / "s") as second:
        claim = first.claim(key)
        assert claim is not None
        assert second.claim(key) is None  # another holder (a separate open file: as another process)
        assert second.claim("cd" * 32) is not None  # other keys are free
        claim.release()
        claim.release()  # idempotent
        again = second.claim(key, wait_s=1.0)
        assert again is not None
        again.release()


def test_a_claim_of_a_killed_holder_is_free(tmp_path: Path) -> None:
    """The kernel lets a flock go when its holder dies: no stale claim after a SIGKILL."""
    key = "ef" * 32
    store = tmp_path / "s"
    RecordStore(store).close()
    code = (
        "import sys, time\n"
        "from lagrseq.llm.store import RecordStore\n"
        f"claim = RecordStore({str(store)!r}).claim({key!r})\n"
        "print('held', flush=True)\n"
        "time.sleep(600)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with RecordStore(store) as opened:
            assert opened.claim(key) is None
            holder.kill()
            holder.wait(timeout=30)
            claim = opened.claim(key, wait_s=10.0)
            assert claim is not None
            claim.release()
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait(timeout=30)
