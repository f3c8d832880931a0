"""Bad paths and values end in one line and exit status 2 before anything is written, a reused
name never passes another run's logs off as its own, and a damaged log is skipped with a warning."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.cli import main
from lagrseq.logs.reader import is_complete, read_info
from lagrseq.progress import Reporter
from tests.support.cli import lagrseq, one_line

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--set", "run.episodes=3", "--quiet"]




# ------------------------------------------------------------------------------------------ bad paths and values
@pytest.mark.parametrize("command", ["run", "reproduce", "replay"])
def test_out_that_is_a_file_or_below_one_or_in_proc_is_one_line(tmp_path: Path, command: str) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("keep me")
    head = {
        "run": ["run", "cube-stacking", "--method", "baseline", *SMALL],
        "reproduce": ["reproduce", "--quick", "--items", "table2", "--quiet"],
        "replay": ["replay", str(ROOT / "fixtures" / "golden")],
    }[command]
    for out in (a_file, a_file / "below", Path("/proc/lagrseq-x")):
        line = one_line(lagrseq(*head, "--out", str(out)))
        assert str(out) in line and "--out" in line
    assert a_file.read_text() == "keep me"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seed", "-1"], "argument --seed: expected an integer in [0, 9223372036854775807], found '-1'"),
        (["--seed", "1e3"], "argument --seed"),
        (["--set", "llm.temperature=nan"], "llm.temperature"),
        (["--set", "env.horizon=0"], "env.horizon = 0"),
        (["--max-cost-usd", "nan"], "argument --max-cost-usd"),
        (["--max-cost-usd", "-1"], "argument --max-cost-usd"),
        (["--max-queries", "-3"], "argument --max-queries"),
        (["--request-deadline", "inf"], "argument --request-deadline"),
        (["--jobs", "0"], "argument --jobs"),
        (["--name", "../../x"], "--name '../../x' is not a plain directory name"),
        (["--name", "/tmp/abs"], "is not a plain directory name"),
        (["--config", "/"], "is a directory"),
        (["--config", "/dev/null/x"], "/dev/null/x"),
    ],
)
def test_bad_values_are_one_line_and_write_nothing(tmp_path: Path, args: list[str], message: str) -> None:
    line = one_line(lagrseq("run", "cube-stacking", "--out", str(tmp_path / "runs"), *SMALL, *args))
    assert message in line
    assert not list(tmp_path.rglob("*.mcap*"))


def test_config_given_binary_bytes_is_one_line(tmp_path: Path) -> None:
    binary = tmp_path / "x.toml"
    binary.write_bytes(bytes(range(256)))
    assert str(binary) in one_line(lagrseq("run", "cube-stacking", "--config", str(binary), "--out", str(tmp_path)))


def test_a_non_ascii_api_key_is_one_line_and_never_printed(tmp_path: Path) -> None:
    done = lagrseq(
        "run", "cube-stacking", "--provider", "live:gpt-4o", "--out", str(tmp_path), *SMALL,
        env={"OPENAI_API_KEY": "sk-clé-secrète-0123456789"},
    )
    line = one_line(done)
    assert "OPENAI_API_KEY" in line and "secr" not in done.stderr + done.stdout


def test_an_oserror_anywhere_ends_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from lagrseq.running import runner

    def full(*_: object, **__: object) -> None:
        raise OSError(28, "No space left on device", str(tmp_path / "x.mcap.partial"))

    monkeypatch.setattr(runner, "run_trials", full)
    assert main(["run", "cube-stacking", "--out", str(tmp_path), *SMALL]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"lagrseq run: error: No space left on device ({tmp_path / 'x.mcap.partial'}); nothing finished is lost"]


# ------------------------------------------------------------------------------------------ reproduce
def test_reproduce_refuses_an_unknown_format_before_running_anything(tmp_path: Path) -> None:
    started = time.perf_counter()
    line = one_line(lagrseq("reproduce", "--quick", "--formats", "png,gif", "--out", str(tmp_path), "--quiet"))
    assert "--formats" in line and "gif" in line
    assert time.perf_counter() - started < 60 and not (tmp_path / "runs").exists()


# ------------------------------------------------------------------------------------------ --name reuse
def test_a_reused_name_with_another_configuration_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["run", "cube-stacking", "--method", "lagr", "--trials", "2", "--out", str(tmp_path), "--name", "mine", *SMALL]
    assert main(base) == 0
    logs = sorted(tmp_path.rglob("trial-*.mcap"))
    before = [p.read_bytes() for p in logs]
    capsys.readouterr()
    assert main([*base, "--set", "env.horizon=20"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "made by another run" in err[0] and "env.horizon: 50 -> 20" in err[0]
    assert main([*base, "--seed", "5"]) == 2
    assert 'seed: "0" -> "5"' in capsys.readouterr().err
    assert [p.read_bytes() for p in logs] == before, "nothing already written is touched"
    assert main(base) == 0 and "2 already complete, skipped" in capsys.readouterr().out


# ------------------------------------------------------------------------------------------ two runs at once
def test_two_identical_runs_at_once_never_tear_a_log(tmp_path: Path) -> None:
    args = [sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--method", "lagr-seq", "--trials", "3",
            "--out", str(tmp_path), "--set", "run.episodes=150", "--quiet"]
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    first = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    results = [p.communicate(timeout=300) + (p.returncode,) for p in (first, second)]
    for _out, err, code in results:
        assert code in (0, 2), err
        assert "Traceback" not in err
        if code == 2:
            assert len(err.strip().splitlines()) == 1 and "another lagrseq process" in err
    logs = sorted(tmp_path.rglob("trial-*.mcap"))
    assert len(logs) == 3 and all(is_complete(p) for p in logs)
    assert not list(tmp_path.rglob("*.partial"))


# ------------------------------------------------------------------------------------------ damaged logs
def test_record_from_runs_skips_a_damaged_log_with_a_warning(tmp_path: Path) -> None:
    from lagrseq.running.recording import record_patterns

    assert main(["run", "cube-stacking", "--method", "lagr", "--trials", "2", "--out", str(tmp_path), *SMALL]) == 0
    logs = sorted(tmp_path.rglob("trial-*.mcap"))
    logs[0].write_bytes(logs[0].read_bytes()[:300])
    warnings: list[str] = []
    config = cfg.load("cube-stacking", "lagr", "upstream")
    patterns = record_patterns(config, [tmp_path], reporter=Reporter(warn=warnings.append))
    assert patterns and len(warnings) == 1 and str(logs[0]) in warnings[0]


# ------------------------------------------------------------------------------------------ logged options
def test_logged_provider_options_never_hold_a_key(tmp_path: Path) -> None:
    assert main(["run", "cube-stacking", "--method", "baseline", "--trials", "1", "--out", str(tmp_path), *SMALL]) == 0
    info = read_info(next(tmp_path.rglob("trial-000.mcap")))
    options = json.loads(info.run["provider_options"])
    assert options["api_key_env"] == "OPENAI_API_KEY" and "key" not in {k for k in options if k != "api_key_env"}


