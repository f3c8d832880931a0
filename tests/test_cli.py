"""The command line: runs write readable logs; bad input gives one line and exit status 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from lagrseq.cli import main
from lagrseq.logs.reader import iter_messages

ROOT = Path(__file__).resolve().parents[1]


def lagrseq(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run the real command in a fresh interpreter."""
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
        timeout=300,
    )


def test_run_writes_one_readable_mcap_per_trial(tmp_path: Path) -> None:
    done = lagrseq(
        "run", "cube-stacking", "--method", "lagr-seq", "--preset", "upstream", "--provider", "mock",
        "--trials", "3", "--seed", "0", "--out", str(tmp_path / "runs"), "--set", "run.episodes=10",
    )
    assert done.returncode == 0, done.stderr
    files = sorted((tmp_path / "runs" / "cube-stacking" / "lagr-seq").glob("*/trial-*.mcap"))
    assert [f.name for f in files] == ["trial-000.mcap", "trial-001.mcap", "trial-002.mcap"]
    for path in files:
        with path.open("rb") as handle:
            topics = {c.topic for _, c, _ in make_reader(handle).iter_messages()}
        assert topics == {"/transitions", "/query", "/no_query", "/episode"}  # log format 3
        assert {topic for topic, _ in iter_messages(path)} == {"/transition", "/query", "/episode"}
    assert "3 trial logs in" in done.stdout and "queries per trial" in done.stdout


def test_rerun_skips_complete_trials(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["run", "cube-stacking", "--method", "baseline", "--trials", "2", "--out", str(tmp_path), "--quiet", "--set", "run.episodes=5"]
    assert main(args) == 0
    first = sorted(tmp_path.rglob("*.mcap"))
    stamps = [p.stat().st_mtime_ns for p in first]
    assert main([*args[:5], "3", *args[6:]]) == 0
    out = capsys.readouterr().out
    assert "2 already complete, skipped" in out
    assert [p.stat().st_mtime_ns for p in first] == stamps
    assert len(list(tmp_path.rglob("*.mcap"))) == 3


def test_jobs_run_trials_in_parallel_processes(tmp_path: Path) -> None:
    args = ["run", "cube-stacking", "--method", "lagr", "--trials", "2", "--quiet", "--set", "run.episodes=5"]
    assert main([*args, "--out", str(tmp_path / "serial")]) == 0
    assert main([*args, "--out", str(tmp_path / "parallel"), "--jobs", "2"]) == 0
    serial = sorted((tmp_path / "serial").rglob("*.mcap"))
    parallel = sorted((tmp_path / "parallel").rglob("*.mcap"))
    from lagrseq.logs.reader import iter_messages

    assert [list(iter_messages(p)) for p in serial] == [list(iter_messages(p)) for p in parallel]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "cubes"], "argument TASK: invalid choice: 'cubes'"),
        (["run", "cube-stacking", "--method", "seq"], "argument --method: invalid choice: 'seq'"),
        (["run", "cube-stacking", "--preset", "mine"], "argument --preset: invalid choice: 'mine'"),
        (["run", "cube-stacking", "--provider", "gpt"], "unknown provider 'gpt'"),
        (["run", "cube-stacking", "--set", "env.horizn=3"], "unknown field env.horizn"),
        (["run", "cube-stacking", "--set", "lagr.trigger=never"], "lagr.trigger = 'never' is not allowed"),
        (["run", "cube-stacking", "--trials", "0"], "argument --trials: expected an integer in [1, 100000]"),
        (["run", "cube-stacking", "--config", "/nonexistent.toml"], "does not exist"),
        (["run", "cube-stacking", "--provider", "live:gpt-4o"], "OPENAI_API_KEY is not set"),
        (["run", "cube-stacking", "--provider", "recorded:/nonexistent-store"], "no recorded store at /nonexistent-store"),
        (["frobnicate"], "invalid choice: 'frobnicate'"),
    ],
)
def test_bad_input_is_one_line_and_status_2(tmp_path: Path, args: list[str], message: str) -> None:
    done = lagrseq(*args, "--out", str(tmp_path)) if args[0] == "run" else lagrseq(*args)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert message in lines[0]
    assert not list(tmp_path.rglob("*.mcap"))


def test_help_lists_commands_and_examples() -> None:
    done = lagrseq("run", "--help")
    assert done.returncode == 0
    for word in ("--method", "--preset", "--provider", "--set", "SECTION.FIELD=VALUE", "examples:"):
        assert word in done.stdout


def test_config_command_prints_every_field_with_its_meaning(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "cube-stacking", "--preset", "paper", "--set", "env.horizon=7"]) == 0
    out = capsys.readouterr().out
    assert "[env]\nhorizon = 7  # Steps per episode (H). Paper: 100; released code: 50." in out
    assert 'trigger = "positive-reward"' in out
