"""LAGRSEQ_NUMERICS: another CPU simulated (lagrseq/agents/numerics.py, docs/reproduce.md).

Under ``perturbed`` a DQN trial's trajectory parts from the native one once the network steers
the agent, both trials still finish with valid logs, the log says it was made perturbed, the same
seed gives the same bytes again, a tabular (cube) trial is unchanged to the byte, and a run made
under one setting is not resumed under the other. Anything but native or perturbed: one line,
exit status 2.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.agents.numerics import NATIVE, PERTURBED, VARIABLE, numerics
from lagrseq.cli import main
from lagrseq.errors import UsageError
from lagrseq.logs.reader import read_info, read_topic
from lagrseq.running import runner

STEPS = 700
"""An image-completion baseline trial (upstream preset, seed 0, trial 0) first acts otherwise
under perturbed numerics at step 513 on the machine the test was written on."""


@pytest.mark.parametrize(("value", "expected"), [(None, NATIVE), ("", NATIVE), ("native", NATIVE), ("perturbed", PERTURBED)])
def test_the_settings(value: str | None, expected: str) -> None:
    assert numerics({} if value is None else {VARIABLE: value}) == expected


@pytest.mark.parametrize("value", ["Perturbed", "fast", " native", "x" * 500])
def test_anything_else_is_refused_in_one_line(value: str) -> None:
    with pytest.raises(UsageError) as refused:
        numerics({VARIABLE: value})
    message = str(refused.value)
    assert "\n" not in message and len(message) < 300
    assert "expected one of native, perturbed" in message and VARIABLE in message


def test_the_command_line_refuses_a_bad_setting_before_it_runs_anything(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setenv(VARIABLE, "avx512")
    out = tmp_path / "runs"
    assert main(["run", "cube-stacking", "--method", "baseline", "--trials", "1", "--out", str(out), "--set", "run.episodes=2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "LAGRSEQ_NUMERICS='avx512' is not a numerics setting" in err[0]
    assert not out.exists()


def test_info_names_the_setting(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv(VARIABLE, PERTURBED)
    assert main(["info"]) == 0
    assert "numerics: perturbed (LAGRSEQ_NUMERICS;" in capsys.readouterr().out


def _trial(directory: Path, monkeypatch: pytest.MonkeyPatch, setting: str, task: str = "image-completion",
           method: str = "baseline", overrides: tuple[str, ...] = (f"run.max_steps={STEPS}",)) -> Path:
    monkeypatch.setenv(VARIABLE, setting)
    config = cfg.load(task, method, "upstream", overrides=list(overrides))
    result = runner.run_one(config, 0, 0, "mock", directory / "trial-000.mcap")
    monkeypatch.delenv(VARIABLE)
    return result.path


@pytest.mark.torch
def test_perturbed_numerics_part_the_trajectory_and_say_so(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    native = _trial(tmp_path / "native", monkeypatch, NATIVE)
    perturbed = _trial(tmp_path / "perturbed", monkeypatch, PERTURBED)
    again = _trial(tmp_path / "again", monkeypatch, PERTURBED)
    # both finish, with complete logs of the whole budget
    for path in (native, perturbed):
        info = read_info(path)
        assert info.complete and info.run["task"] == "image-completion"
        assert len(read_topic(path, "/transition")) == STEPS
    a, b = read_topic(native, "/transition"), read_topic(perturbed, "/transition")
    parted = [i for i, (x, y) in enumerate(zip(a, b)) if (x["action"], x["state"]) != (y["action"], y["state"])]
    assert parted, "perturbed numerics left the trajectory as it was"
    assert a[: parted[0]] == b[: parted[0]]  # the same trial until the network's numbers tell
    # the log says how it was made; native logs carry no such entry (their bytes are unchanged)
    assert read_info(perturbed).run["numerics"] == PERTURBED
    assert "numerics" not in read_info(native).run
    # one machine, one setting, one seed: the same bytes
    assert again.read_bytes() == perturbed.read_bytes()


def test_a_tabular_trial_is_the_same_bytes_under_either_setting(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    args = ("cube-stacking", "lagr-seq", ("run.episodes=15",))
    native = _trial(tmp_path / "native", monkeypatch, NATIVE, *args)
    perturbed = _trial(tmp_path / "perturbed", monkeypatch, PERTURBED, *args)
    assert native.read_bytes() == perturbed.read_bytes()


@pytest.mark.torch
def test_a_run_is_not_resumed_under_other_numerics(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    config = cfg.load("object-arrangement", "baseline", "upstream", overrides=["run.max_steps=40"])
    directory = runner.run_directory(tmp_path, config, "mock", 0)
    monkeypatch.setenv(VARIABLE, PERTURBED)
    runner.run_trials(config, 1, 0, "mock", directory)
    made = runner.trial_path(directory, 0).read_bytes()
    monkeypatch.setenv(VARIABLE, NATIVE)
    with pytest.raises(UsageError) as refused:
        runner.run_trials(config, 1, 0, "mock", directory)
    assert 'numerics: "perturbed" -> "native"' in str(refused.value) and "LAGRSEQ_NUMERICS=perturbed" in str(refused.value)
    assert runner.trial_path(directory, 0).read_bytes() == made  # nothing written is lost
    monkeypatch.setenv(VARIABLE, PERTURBED)
    runner.run_trials(config, 1, 0, "mock", directory)  # the same setting: resumed (nothing to do)
    assert runner.trial_path(directory, 0).read_bytes() == made
