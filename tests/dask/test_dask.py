"""Trials on Dask distributed (a real LocalCluster on 127.0.0.1): the same events as the local
executors, resume after workers die mid-trial, a failing trial that does not stop the others,
Ctrl-C, and one budget and one store shared by 4 workers. ``tox -e dask``; skipped without the
``dask`` extra."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from lagrseq import cli  # noqa: E402
from lagrseq import config as cfg  # noqa: E402
from lagrseq.errors import TrialsFailed  # noqa: E402
from lagrseq.llm.store import RecordStore  # noqa: E402
from lagrseq.logs.reader import find_logs, is_complete, read_info, read_topic  # noqa: E402
from lagrseq.progress import Reporter, ignore
from lagrseq.running import runner, wiring  # noqa: E402
from lagrseq.running.dask_executor import DaskExecutor  # noqa: E402
from lagrseq.running.executors import LocalExecutor, make_executor  # noqa: E402
from tests.llm.conftest import KEY_ENV, FakeOpenAI  # noqa: E402

pytestmark = pytest.mark.dask

ROOT = Path(__file__).resolve().parents[2]
TOPICS = ("/transition", "/query", "/episode")
TRIALS = 4
OVERRIDES = ["run.episodes=150"]


def events(directory: Path) -> dict[str, dict[str, list[dict[str, object]]]]:
    logs = find_logs([directory])
    assert logs and all(is_complete(p) for p in logs)
    return {p.name: {topic: read_topic(p, topic) for topic in TOPICS} for p in logs}


def config() -> cfg.ExperimentConfig:
    return cfg.load("cube-stacking", "lagr-seq", "upstream", None, OVERRIDES)


@pytest.fixture(scope="module")
def pool() -> Iterator[DaskExecutor]:
    executor = make_executor("dask", 2)
    assert isinstance(executor, DaskExecutor)
    with executor:
        yield executor


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, list[dict[str, object]]]]:
    """The 4 trials run in this process, one after the other."""
    directory = tmp_path_factory.mktemp("reference")
    runner.run_trials(config(), TRIALS, 0, "mock", directory)
    return events(directory)


def test_the_same_events_on_dask_as_on_the_local_pool_and_in_process(
    tmp_path: Path, pool: DaskExecutor, reference: dict[str, object]
) -> None:
    results = runner.run_trials(config(), TRIALS, 0, "mock", tmp_path / "dask", pool=pool)
    assert [r.trial for r in results] == list(range(TRIALS)) and not any(r.skipped for r in results)
    assert all(r.episodes == 150 for r in results)  # a small plain record came back from each worker
    with LocalExecutor(2) as local:
        runner.run_trials(config(), TRIALS, 0, "mock", tmp_path / "local", pool=local)
    assert events(tmp_path / "dask") == reference
    assert events(tmp_path / "local") == reference


def test_dqn_trials_run_as_groups_on_dask_and_write_the_bytes_they_write_alone(tmp_path: Path, pool: DaskExecutor) -> None:
    """Seed-batched DQN on Dask: 3 image-completion trials go to the 2 workers as groups in
    lockstep (trials 0-1 and 2); each log equals, byte for byte, the trial run alone here."""
    pytest.importorskip("torch")
    image = cfg.load("image-completion", "lagr-seq", "paper", None, ["run.max_steps=300"])
    alone = tmp_path / "alone"
    alone.mkdir()
    for trial in range(3):
        runner.run_one(image, trial, 2, "mock", alone / f"trial-{trial:03d}.mcap")
    results = runner.run_trials(image, 3, 2, "mock", tmp_path / "dask", pool=pool)
    assert [r.steps for r in results] == [300] * 3
    for trial in range(3):
        name = f"trial-{trial:03d}.mcap"
        assert (tmp_path / "dask" / name).read_bytes() == (alone / name).read_bytes(), name


def test_the_command_line_with_executor_dask(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], pool: DaskExecutor, reference: dict[str, object]
) -> None:
    args = ["run", "cube-stacking", "--method", "lagr-seq", "--trials", str(TRIALS), "--set", OVERRIDES[0], "--quiet"]
    assert cli.main([*args, "--executor", "dask", "--jobs", "2", "--out", str(tmp_path / "local-cluster")]) == 0
    out = capsys.readouterr().out
    assert "dask: local cluster of 2 workers on 127.0.0.1" in out and f"{TRIALS} trial logs in" in out
    assert events(tmp_path / "local-cluster") == reference
    address = pool.client.scheduler.address  # an existing cluster, as dask scheduler / SLURMCluster give
    assert cli.main([*args, "--executor", "dask", "--scheduler", address, "--out", str(tmp_path / "existing")]) == 0
    assert f"dask: scheduler {address}, 2 workers now" in capsys.readouterr().out
    assert events(tmp_path / "existing") == reference
    assert cli.main([*args, "--executor", "dask", "--scheduler", "127.0.0.1:8786", "--out", str(tmp_path)]) == 2
    assert "give tcp://HOST:PORT" in capsys.readouterr().err
    assert cli.main([*args, "--scheduler", "tcp://127.0.0.1:1", "--out", str(tmp_path)]) == 2
    assert "--scheduler applies to --executor dask only" in capsys.readouterr().err


def test_a_failing_trial_is_named_and_the_others_go_on(tmp_path: Path, pool: DaskExecutor) -> None:
    directory = tmp_path / "run"
    blocker = directory / "trial-001.mcap.partial"
    blocker.mkdir(parents=True)  # trial 1 cannot open its log: a real OSError inside the worker
    warnings: list[str] = []
    with pytest.raises(TrialsFailed) as failed:
        runner.run_trials(config(), TRIALS, 0, "mock", directory, pool=pool, reporter=Reporter(ignore, warnings.append), retries=1)
    line = str(failed.value)
    digest = config().digest()
    assert "\n" not in line
    assert line.startswith(f"1 of {TRIALS} trials failed (trials 1; first: trial 1 (seed 0, config {digest}) failed: IsADirectoryError")
    assert warnings == [line.split("first: ")[1].split("); the other")[0]]
    assert sorted(p.name for p in directory.glob("*.mcap")) == ["trial-000.mcap", "trial-002.mcap", "trial-003.mcap"]
    blocker.rmdir()
    said: list[str] = []
    runner.run_trials(config(), TRIALS, 0, "mock", directory, pool=pool, reporter=Reporter(said.append, ignore))
    assert said == ["resuming: 3 trials complete (skipped), 1 missing and 0 unfinished (cut short, failed or recovered) to run"]


def _start(tmp_path: Path, *extra: str) -> subprocess.Popen[str]:
    args = [sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr-seq", "--trials", str(TRIALS),
            "--set", OVERRIDES[0], "--executor", "dask", "--jobs", "2", "--out", str(tmp_path), "--quiet", *extra]
    return subprocess.Popen(
        args, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _wait_for(tmp_path: Path, pattern: str, count: int = 1, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while len(list(tmp_path.rglob(pattern))) < count and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(list(tmp_path.rglob(pattern))) >= count, f"no {pattern} within {timeout} s"


def test_a_rerun_after_lagrseq_and_its_workers_died_mid_trial_runs_exactly_the_missing_trials(
    tmp_path: Path, pool: DaskExecutor, reference: dict[str, object]
) -> None:
    process = _start(tmp_path)
    try:
        _wait_for(tmp_path, "trial-*.mcap")
        _wait_for(tmp_path, "*.partial")
    finally:
        os.kill(process.pid, signal.SIGKILL)  # lagrseq, with the scheduler in it, dies at once
        process.communicate(timeout=60)
    deadline = time.monotonic() + 30
    orphans = True
    while orphans and time.monotonic() < deadline:
        try:
            os.killpg(process.pid, 0)  # the workers are still in its process group
            time.sleep(0.2)
        except ProcessLookupError:
            orphans = False
    if orphans:
        os.killpg(process.pid, signal.SIGKILL)
    assert not orphans, "the local cluster's workers outlived the lagrseq process"
    complete = {p.name: p.read_bytes() for p in tmp_path.rglob("trial-*.mcap") if is_complete(p)}
    # A trial cut short stays NAME.partial, unless its worker finished it in the moment before it
    # saw the scheduler die: then its log is complete.
    unfinished_logs = list(tmp_path.rglob("*.partial"))
    assert complete and len(complete) < TRIALS
    (directory,) = {p.parent for p in tmp_path.rglob("trial-*")}
    said: list[str] = []
    results = runner.run_trials(config(), TRIALS, 0, "mock", directory, pool=pool, reporter=Reporter(said.append, ignore))
    unfinished = len(unfinished_logs)
    missing = TRIALS - len(complete) - unfinished
    assert said == [f"resuming: {len(complete)} trial{'s' if len(complete) != 1 else ''} complete (skipped), {missing} missing and {unfinished} unfinished (cut short, failed or recovered) to run"]
    assert sorted(r.trial for r in results if not r.skipped) == sorted(
        int(n[6:9]) for n in {f"trial-{t:03d}.mcap" for t in range(TRIALS)} - set(complete)
    )
    assert {name: (directory / name).read_bytes() for name in complete} == complete  # untouched
    assert not list(directory.glob("*.partial"))
    assert events(directory) == reference


def test_a_worker_killed_mid_trial_is_replaced_and_its_trial_rerun_by_dask(
    tmp_path: Path, pool: DaskExecutor, reference: dict[str, object]
) -> None:
    outcome: list[object] = []
    thread = threading.Thread(target=lambda: outcome.append(runner.run_trials(config(), TRIALS, 0, "mock", tmp_path, pool=pool)))
    thread.start()
    _wait_for(tmp_path, "*.partial")
    pids = pool.client.run(os.getpid)
    os.kill(next(iter(pids.values())), signal.SIGKILL)
    thread.join(timeout=300)
    assert len(outcome) == 1 and len(outcome[0]) == TRIALS  # type: ignore[arg-type]
    assert events(tmp_path) == reference


def _interrupt(process: subprocess.Popen[str]) -> tuple[str, float]:
    """Ctrl-C to the process group, as a terminal sends it: stderr and the seconds to the exit."""
    started = time.monotonic()
    os.killpg(process.pid, signal.SIGINT)
    _, err = process.communicate(timeout=60)
    return err, time.monotonic() - started


def test_ctrl_c_leaves_complete_logs_and_partials_that_recover_repairs(tmp_path: Path) -> None:
    # long trials (about 10 s each since the cube loop got faster; 3000 episodes were short
    # enough to finish inside the cluster's shutdown), so that the Ctrl-C cuts them
    process = _start(tmp_path, "--set", "run.episodes=30000")
    try:
        _wait_for(tmp_path, "*.partial")
        time.sleep(1.0)  # some episodes flushed
        err, took = _interrupt(process)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, err
    assert took < 20
    assert "interrupted" in err and "Traceback" not in err
    finished = list(tmp_path.rglob("trial-*.mcap"))
    partials = list(tmp_path.rglob("*.mcap.partial"))
    assert partials and all(is_complete(p) for p in finished) and len(finished) < TRIALS
    from lagrseq.logs.recover import recover

    assert read_info(recover(partials[0]).path).status["status"] == "recovered"


def test_a_ctrl_c_while_the_workers_start_is_not_lost(tmp_path: Path) -> None:
    """Once the worker processes exist (they import and register for a second or more), a
    Ctrl-C stops lagrseq at once; it used to be ignored until the cluster was up, and the run
    went on to its end."""
    import psutil

    process = _start(tmp_path, "--set", "run.episodes=3000")
    try:
        me = psutil.Process(process.pid)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            with_spawn = 0
            for child in me.children():
                with contextlib.suppress(psutil.Error):
                    with_spawn += any("spawn_main" in part for part in child.cmdline())
            if with_spawn >= 2:
                break
            time.sleep(0.01)
        time.sleep(0.2)  # lagrseq's own check of its children (every 10 ms); the workers import for longer
        assert not list(tmp_path.rglob("*.partial")), "the workers started before the check"
        err, took = _interrupt(process)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, err
    assert took < 20
    assert err.strip().startswith("lagrseq run: interrupted;") and "\n" not in err.strip(), err
    assert not list(tmp_path.rglob("trial-*.mcap"))


# ------------------------------------------------------------------------ shared LLM state
@pytest.fixture(scope="module")
def server() -> Iterator[FakeOpenAI]:
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(KEY_ENV, "sk-test-dask-0123456789")  # the workers inherit it
        fake = FakeOpenAI()
        try:
            yield fake
        finally:
            fake.close()


@pytest.fixture(scope="module")
def four_workers(server: FakeOpenAI) -> Iterator[DaskExecutor]:
    """4 workers started after the key is set: workers take the environment they start with."""
    with DaskExecutor(4) as executor:
        yield executor


def _live_queries(directory: Path) -> list[dict[str, object]]:
    return [r for p in find_logs([directory]) for r in read_topic(p, "/query") if r["queried"] and r["source"] == "live"]


def test_four_workers_recording_into_one_store_lose_and_duplicate_nothing(
    tmp_path: Path, four_workers: DaskExecutor, server: FakeOpenAI
) -> None:
    store = tmp_path / "store"
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=20", "llm.model=gpt-4o-mini", "llm.temperature=1.0"])
    options = wiring.provider_options(f"recorded:{store}", {"base_url": server.url, "api_key_env": KEY_ENV, "on_miss": "live"})
    first = len(server.requests)
    runner.run_trials(config, 8, 0, f"recorded:{store}", tmp_path / "runs", pool=four_workers, provider_options=options)
    asked = server.requests[first:]
    assert asked and all(r.get("n", 1) == 1 for r in asked)
    with RecordStore(store, create=False) as recorded:
        samples = [s for entry in recorded.entries() for s in entry.samples]
    # each of the server's responses is in the store exactly once (no answer lost, none twice)
    assert len({s.id for s in samples}) == len(samples) == len(asked)
    assert sorted(str(s.provenance) for s in samples) == sorted(f"chatcmpl-{i}" for i in range(first + 1, first + len(asked) + 1))
    assert {str(r["answer"]) for r in _live_queries(tmp_path / "runs")} <= {s.text for s in samples}


def test_four_workers_share_one_query_budget(tmp_path: Path, four_workers: DaskExecutor, server: FakeOpenAI) -> None:
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=20"])
    options = wiring.provider_options("live:gpt-4o-mini", {"base_url": server.url, "api_key_env": KEY_ENV, "max_queries": 6})
    first = len(server.requests)
    with pytest.raises(TrialsFailed, match="--max-queries 6 reached"):
        runner.run_trials(config, 8, 0, "live:gpt-4o-mini", tmp_path, pool=four_workers, provider_options=options)
    assert len(server.requests) - first == 6  # the sweep's budget, not 6 per trial or per worker
    assert len(_live_queries(tmp_path)) <= 6


def test_four_workers_share_one_cost_budget(tmp_path: Path, four_workers: DaskExecutor, server: FakeOpenAI) -> None:
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["run.episodes=20"])
    limit = 0.002
    options = wiring.provider_options("live:gpt-4o-mini", {"base_url": server.url, "api_key_env": KEY_ENV, "max_cost_usd": limit})
    first = len(server.requests)
    with pytest.raises(TrialsFailed, match="--max-cost-usd 0.002 reached"):
        runner.run_trials(config, 8, 0, "live:gpt-4o-mini", tmp_path, pool=four_workers, provider_options=options)
    live = _live_queries(tmp_path)
    spent = sum(float(r["cost_usd"]) for r in live)  # type: ignore[arg-type]
    assert live and len(live) == len(server.requests) - first
    assert 0 < spent <= limit


def test_a_live_run_on_dask_writes_no_fragment_of_the_key(
    tmp_path: Path, server: FakeOpenAI, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """The key in OPENAI_API_KEY, a server that echoes it everywhere, trials on a Dask local
    cluster with a budget: no log, ledger, worker scratch file or output holds a fragment."""
    import dask

    from tests.support.redaction import ECHO_KEY, echo_completion, echoing, leaks, written

    monkeypatch.setenv("OPENAI_API_KEY", ECHO_KEY)
    server.script.extend(echoing(echo_completion) for _ in range(200))
    args = ["run", "cube-stacking", "--method", "lagr", "--provider", "live:gpt-4o-mini", "--trials", "2", "--set", "run.episodes=2",
            "--executor", "dask", "--jobs", "2", "--base-url", server.url, "--max-cost-usd", "5", "--quiet", "--out", str(tmp_path / "runs")]
    with dask.config.set({"temporary-directory": str(tmp_path / "dask-scratch")}):
        assert cli.main(args) == 0
    assert server.requests and len(find_logs([tmp_path / "runs"])) == 2
    found = {str(path): leaks(text) for path, text in written(tmp_path) if leaks(text)}
    assert found == {}, found
    captured = capfd.readouterr()
    assert leaks(captured.out + captured.err) == []
