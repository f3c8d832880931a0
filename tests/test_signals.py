"""SIGTERM (what ``kill``, ``timeout`` and batch schedulers send) stops every command that starts
processes as Ctrl-C does: a clean stop, the logs kept, one line, exit status 143; and no process
it started survives it, nor a SIGKILL of lagrseq itself (pool workers die with their parent
through PR_SET_PDEATHSIG or a watchdog thread, and multiprocessing's resource tracker ends once
they are gone). Real commands as child processes; their descendants are found in /proc."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def children_of(pid: int) -> set[int]:
    """Every living descendant of ``pid`` (not zombies)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z":
            parents[int(stat.parent.name)] = int(fields[1])
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def all_gone(pids: set[int], within_s: float = 30.0) -> set[int]:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        left = {pid for pid in pids if alive(pid)}
        if not left:
            return set()
        time.sleep(0.1)
    return left


def start(args: list[str], cwd: Path, wanted_children: int, within_s: float = 120.0) -> tuple[subprocess.Popen[str], set[int]]:
    """Start ``lagrseq ARGS`` and wait until it has ``wanted_children`` descendants."""
    process = subprocess.Popen([sys.executable, "-m", "lagrseq", *args], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, env={**os.environ, "MPLBACKEND": "Agg"})
    deadline = time.monotonic() + within_s
    children: set[int] = set()
    while time.monotonic() < deadline and process.poll() is None:
        children = children_of(process.pid)
        if len(children) >= wanted_children:
            time.sleep(2.0)  # trials under way
            return process, children_of(process.pid) | children
        time.sleep(0.2)
    process.kill()
    raise AssertionError(f"{args[0]} did not start {wanted_children} processes: {process.communicate()}")


RUN = ["run", "cube-stacking", "--method", "lagr", "--trials", "4", "--jobs", "2", "--set", "run.episodes=100000", "--quiet"]
COMMANDS = {
    "run": RUN,
    "frontier": ["frontier", "cube-stacking", "--policies", "always,never", "--trials", "2", "--jobs", "2", "--set", "run.episodes=100000", "--quiet"],
    "reproduce": ["reproduce", "--quick", "--items", "fig5a", "--jobs", "2", "--quiet"],
    "audit": ["audit", "cube-stacking", "--jobs", "2", "--episodes", "100000", "--trials", "2", "--quiet"],
}


def test_sigterm_stops_a_run_like_ctrl_c_and_leaves_no_process(tmp_path: Path) -> None:
    process, children = start([*RUN, "--out", str(tmp_path / "runs")], tmp_path, wanted_children=3)  # 2 workers, 1 tracker
    deadline = time.monotonic() + 90
    while not list((tmp_path / "runs").rglob("*.mcap.partial")) and time.monotonic() < deadline:
        time.sleep(0.2)  # the workers have imported everything and begun their trials
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    assert "lagrseq run: stopped by SIGTERM; finished trial logs are kept" in err and "Traceback" not in err
    assert all_gone(children) == set()
    assert list((tmp_path / "runs").rglob("*.mcap.partial"))  # the unfinished trials' logs are kept


def test_sigterm_to_a_single_process_run_leaves_the_unfinished_trial_as_partial(tmp_path: Path) -> None:
    """The stop line says unfinished trials are left as ``.partial``; so they are (a SIGTERM
    once made the trial a finished log with status failed)."""
    runs = tmp_path / "runs"
    process = subprocess.Popen([sys.executable, "-m", "lagrseq", *RUN, "--jobs", "1", "--out", str(runs)], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while not list(runs.rglob("*.mcap.partial")) and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.2)
    time.sleep(1.0)  # episodes under way
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143 and "unfinished ones left as .partial" in err and "Traceback" not in err, err
    assert list(runs.rglob("trial-000.mcap.partial")) and not list(runs.rglob("trial-000.mcap")), sorted(runs.rglob("*"))


def test_sigkill_of_a_run_takes_its_workers_and_tracker_along(tmp_path: Path) -> None:
    process, children = start([*RUN, "--out", str(tmp_path / "runs")], tmp_path, wanted_children=3)
    process.kill()
    process.communicate(timeout=60)
    assert all_gone(children) == set(), "processes left after SIGKILL of lagrseq run"


@pytest.mark.slow
@pytest.mark.parametrize("command", ["frontier", "reproduce", "audit"])
def test_sigterm_and_sigkill_leave_no_process_of_any_command(tmp_path: Path, command: str) -> None:
    args = [*COMMANDS[command], "--out", str(tmp_path / "out")]
    process, children = start(args, tmp_path, wanted_children=3, within_s=300)  # reproduce resolves its suite first
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=90)
    assert process.returncode == 143 and f"lagrseq {command}: stopped by SIGTERM" in err and "Traceback" not in err, err
    assert all_gone(children) == set()
    process, children = start(args, tmp_path, wanted_children=3, within_s=300)
    process.kill()
    process.communicate(timeout=60)
    assert all_gone(children) == set()


def test_sigterm_stops_robot_serve(tmp_path: Path) -> None:
    pytest.importorskip("grpc")
    pytest.importorskip("pybullet")
    process = subprocess.Popen([sys.executable, "-m", "lagrseq", "robot", "serve", "--sim", "--port", "0"], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None
    assert "serving a simulated UR5e" in process.stdout.readline()
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143 and "lagrseq robot: stopped by SIGTERM; the service is stopped" in err, err


def test_sigterm_is_honoured_when_the_parent_ignored_it(tmp_path: Path) -> None:
    """A wrapper that ignores SIGTERM (or blocks it) hands that to its children across exec;
    lagrseq installs its own handler and unblocks the signal, so it still stops (the old
    default action did not: the child of such a wrapper ran on)."""
    code = (
        "import signal, subprocess, sys\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})\n"
        "sys.exit(subprocess.call([sys.executable, '-m', 'lagrseq', *sys.argv[1:]]))\n"
    )
    wrapper = subprocess.Popen([sys.executable, "-c", code, *RUN, "--jobs", "1", "--out", str(tmp_path / "runs")], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    child: set[int] = set()
    while not child and time.monotonic() < deadline:
        child = children_of(wrapper.pid)
        time.sleep(0.2)
    time.sleep(3.0)  # lagrseq's handler is installed once its command starts
    lagrseq_pid = min(child)
    os.kill(lagrseq_pid, signal.SIGTERM)
    _, err = wrapper.communicate(timeout=60)
    assert wrapper.returncode == 143 and "stopped by SIGTERM" in err, err


def test_sigint_is_honoured_when_started_with_it_ignored(tmp_path: Path) -> None:
    """A shell starts background jobs with SIGINT ignored, and Python then installs no Ctrl-C
    handler, so ``kill -INT`` would do nothing while SIGTERM works; lagrseq installs its own."""
    code = (
        "import signal, subprocess, sys\n"
        "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
        "sys.exit(subprocess.call([sys.executable, '-m', 'lagrseq', *sys.argv[1:]]))\n"
    )
    wrapper = subprocess.Popen([sys.executable, "-c", code, *RUN, "--jobs", "1", "--out", str(tmp_path / "runs")], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while not list((tmp_path / "runs").rglob("*.mcap.partial")) and time.monotonic() < deadline:
        time.sleep(0.2)  # the command runs (its handlers are installed before the first trial)
    lagrseq_pid = min(children_of(wrapper.pid))  # the command itself (its helpers start later)
    os.kill(lagrseq_pid, signal.SIGINT)
    _, err = wrapper.communicate(timeout=60)
    assert wrapper.returncode == 130 and "lagrseq run: interrupted" in err and "Traceback" not in err, err


def _session(sid: int) -> set[int]:
    """The living processes of session ``sid`` (not zombies)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z" and int(fields[3]) == sid:
            found.add(int(stat.parent.name))
    return found


def test_sigkill_of_replay_leaves_no_process_of_its_session(tmp_path: Path) -> None:
    """``replay --jobs 2`` killed with SIGKILL leaves neither its spawn workers nor the resource
    tracker alive: they die with it."""
    golden = ROOT / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"
    runs = tmp_path / "runs"
    runs.mkdir()
    for i in range(3000):  # hard links: 3,000 logs to read, no disk used
        os.link(golden, runs / f"trial-{i:04d}.mcap")
    process = subprocess.Popen([sys.executable, "-m", "lagrseq", "replay", str(runs), "--jobs", "2", "--out", str(tmp_path / "reports")],
                               cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                               env={**os.environ, "MPLBACKEND": "Agg"})
    deadline = time.monotonic() + 120
    while len(_session(process.pid)) < 4 and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.1)  # the parent, the resource tracker and the two readers
    assert len(_session(process.pid)) >= 4, "replay --jobs 2 did not start its workers"
    time.sleep(0.5)
    process.kill()
    process.wait(timeout=30)
    deadline = time.monotonic() + 20
    while _session(process.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = _session(process.pid)
    for pid in left:  # whatever the outcome, this test leaves nothing running
        os.kill(pid, signal.SIGKILL)
    assert left == set(), "processes of replay's session left after SIGKILL"
