"""Interrupted runs: Ctrl-C (once or twice), SIGKILL and a full disk leave only complete logs and
``.partial`` files that recover, the flushed episodes kept, and a rerun gives the bytes of an
uninterrupted run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lagrseq.logs.reader import is_complete, read_info
from tests.support.cli import lagrseq, one_line

ROOT = Path(__file__).resolve().parents[2]




# ------------------------------------------------------------------------------------------ Ctrl-C and SIGKILL
RUN_8 = ["run", "cube-stacking", "--method", "lagr-seq", "--trials", "8", "--set", "run.episodes=3000", "--quiet"]


def _interrupt(extra: list[str], tmp_path: Path, twice: bool = False, command: list[str] = RUN_8, settle_s: float = 1.0) -> tuple[int, float, str]:
    args = [sys.executable, "-m", "lagrseq", *command, "--out", str(tmp_path), *extra]
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    process = subprocess.Popen(
        args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        # a shell that started this test in the background may have left SIGINT ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    while not list(tmp_path.rglob("*.partial")) and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(settle_s)  # some episodes flushed
    started = time.monotonic()
    os.killpg(process.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole process group
    if twice:
        time.sleep(0.05)
        os.killpg(process.pid, signal.SIGINT)
    try:
        _, err = process.communicate(timeout=60)  # also waits for every helper that holds stderr
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    return process.returncode, time.monotonic() - started, err


def _left_only_complete_logs_and_partials(tmp_path: Path, trials: int) -> None:
    finished = list(tmp_path.rglob("trial-*.mcap"))
    partials = list(tmp_path.rglob("*.mcap.partial"))
    assert partials, "the running trials leave their .partial files"
    assert all(is_complete(p) for p in finished), "no half-made log under a final name"
    assert len(finished) < trials, "pending trials were cancelled"
    from lagrseq.logs.recover import recover

    recovered = recover(partials[0])
    assert read_info(recovered.path).status["status"] == "recovered"


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_one_ctrl_c_stops_promptly_leaving_complete_logs_and_partials(tmp_path: Path, jobs: str) -> None:
    code, seconds, err = _interrupt(["--jobs", jobs], tmp_path)
    assert code == 130, err
    assert seconds < 10, f"took {seconds:.1f} s to stop"
    line = err.strip()
    assert "\n" not in line and line.startswith("lagrseq run: interrupted;"), err  # no resource-tracker warning after it
    _left_only_complete_logs_and_partials(tmp_path, 8)


def test_one_ctrl_c_stops_dqn_trials_in_lockstep_each_keeping_its_finished_episodes(tmp_path: Path) -> None:
    """--jobs 1 runs the 3 image-completion trials in lockstep (threads of this process): a
    Ctrl-C stops all three, and each .partial keeps the episodes it finished (recover)."""
    pytest.importorskip("torch")
    from lagrseq.logs.reader import read_topic
    from lagrseq.logs.recover import recover

    command = ["run", "image-completion", "--method", "lagr-seq", "--trials", "3", "--set", "run.max_steps=1000000",
               "--set", "env.scans=1", "--quiet"]  # fmt: skip
    code, seconds, err = _interrupt(["--jobs", "1"], tmp_path, command=command, settle_s=3.0)
    assert code == 130 and seconds < 10, (code, seconds, err)
    assert err.strip().startswith("lagrseq run: interrupted;") and "\n" not in err.strip(), err
    partials = sorted(tmp_path.rglob("*.mcap.partial"))
    assert len(partials) == 3 and not list(tmp_path.rglob("trial-*.mcap"))
    for partial in partials:
        episodes = read_topic(recover(partial).path, "/episode")
        assert episodes and [e["episode"] for e in episodes] == list(range(len(episodes)))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "trials"),
    [
        (["frontier", "cube-stacking", "--trials", "4", "--set", "run.episodes=3000", "--quiet"], 20),
        (["audit", "cube-stacking", "--trials", "3", "--episodes", "3000", "--quiet"], 9),
        (["reproduce", "--quick", "--items", "table2", "--quiet"], 100),
    ],
    ids=["frontier", "audit", "reproduce"],
)
def test_one_ctrl_c_stops_the_sweep_commands_too(tmp_path: Path, command: list[str], trials: int) -> None:
    code, seconds, err = _interrupt(["--jobs", "2"], tmp_path, command=command)
    assert code == 130 and seconds < 10, (code, seconds, err)
    line = err.strip()
    assert "\n" not in line and line.startswith(f"lagrseq {command[0]}: interrupted; finished trial logs are kept"), err
    _left_only_complete_logs_and_partials(tmp_path, trials)


def test_a_second_ctrl_c_exits_at_once(tmp_path: Path) -> None:
    code, seconds, _ = _interrupt(["--jobs", "2"], tmp_path, twice=True)
    assert code == 130 and seconds < 10


@pytest.mark.slow
def test_sigkill_mid_run_then_a_rerun_gives_the_same_bytes_as_an_uninterrupted_run(tmp_path: Path) -> None:
    """The whole process group killed (no cleanup at all) while two trials run in the pool: the
    rerun runs the cut trials again and every log equals an uninterrupted run's, byte for byte."""
    command = ["run", "cube-stacking", "--method", "lagr-seq", "--trials", "3", "--set", "run.episodes=400", "--quiet", "--jobs", "2"]
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    reference = tmp_path / "reference"
    assert lagrseq(*command, "--out", str(reference)).returncode == 0
    out = tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, "-m", "lagrseq", *command, "--out", str(out)], env=env, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        while not list(out.rglob("*.partial")) and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
    assert list(out.rglob("*.partial")), "killed while trials ran"
    again = lagrseq(*command, "--out", str(out))
    assert again.returncode == 0 and "resuming:" in again.stdout, again.stderr
    logs = {p.relative_to(reference): p.read_bytes() for p in reference.rglob("trial-*")}
    assert len(logs) == 3
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("trial-*")} == logs


def test_leaving_at_once_after_a_pool_adds_no_resource_tracker_warning(tmp_path: Path) -> None:
    """After a Ctrl-C the process ends with ``os._exit`` (its pool's semaphores unreleased): the
    resource tracker releases them without two lines of ``UserWarning`` after the one line."""
    script = (
        "import os\n"
        "from lagrseq.running.executors import LocalExecutor\n"
        "if __name__ == '__main__':\n"
        "    pool = LocalExecutor(1)\n"
        "    assert pool.submit(abs, -1).result() == 1\n"
        "    pool.interrupt()\n"
        "    os._exit(130)\n"
    )
    (tmp_path / "leave.py").write_text(script)
    done = subprocess.run(
        [sys.executable, str(tmp_path / "leave.py")], capture_output=True, text=True, timeout=60,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert done.returncode == 130 and done.stderr == ""


# ------------------------------------------------------------------------------------------ full disk
LIMITED_ENV = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "PYTHONDONTWRITEBYTECODE": "1"}
"""No bytecode cache from a process under a file-size limit: Python writes ``.pyc`` files with one
raw write, and a write cut short by the limit would leave a truncated one for every later import."""


def _file_size_limit(limit: int) -> None:
    """In the child: files may grow to ``limit`` bytes, then a write fails with EFBIG (as ENOSPC
    on a full disk), not with the SIGXFSZ that would kill the process."""
    import resource

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_a_full_disk_while_logging_is_one_line_and_keeps_the_flushed_episodes(tmp_path: Path, jobs: str) -> None:
    out = tmp_path / "runs"
    done = subprocess.run(
        [sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr-seq", "--trials", "1",
         "--set", "run.episodes=100", "--out", str(out), "--quiet", "--jobs", jobs],
        capture_output=True, text=True, timeout=300, env=LIMITED_ENV, preexec_fn=lambda: _file_size_limit(60_000),
    )
    line = one_line(done)
    (partial,) = out.rglob("*.mcap.partial")
    assert f"{partial}: cannot write the log (File too large)" in line and "free some space" in line
    assert not list(out.rglob("*.mcap")), "no half-written log under a final name"
    from lagrseq.logs.recover import recover

    recovered = recover(partial)
    assert recovered.episodes > 3, "the episodes flushed before the disk filled are kept"
    assert read_info(recovered.path).status["status"] == "recovered"


def test_a_full_disk_while_recovering_in_place_leaves_the_original_and_no_temporary_file(tmp_path: Path) -> None:
    golden = ROOT / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"
    cut = tmp_path / "my logs" / "trial-000.mcap"
    cut.parent.mkdir()
    data = golden.read_bytes()[:-1]
    cut.write_bytes(data)
    done = subprocess.run(
        [sys.executable, "-m", "lagrseq", "recover", str(cut)], capture_output=True, text=True, timeout=120,
        env=LIMITED_ENV, preexec_fn=lambda: _file_size_limit(len(data) // 2),
    )
    line = one_line(done)
    assert "cannot write the recovered log (File too large)" in line and f"{cut} was left as it was" in line
    assert sorted(p.name for p in cut.parent.iterdir()) == ["trial-000.mcap"]
    assert cut.read_bytes() == data
