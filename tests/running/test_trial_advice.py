"""What a failed run says to do is true of its cause: "run the same command again" only for a
failure that may pass (a disk, a network, a lost worker); a trial's deterministic failure (a
record its task does not declare, a lone surrogate or NaN in a task's logged field, an
exception of the task's own code) says what to fix. Real runs of a plugin task whose env logs
what ``NOTED_MODE`` says."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq.errors import LogError, ProviderError, RecordError, StoreError
from lagrseq.running import runner
from tests.support.plugins import ROOT, install, lagrseq

PLUGIN = '''
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from lagrseq.config import CubeTaskConfig
from lagrseq.registry import TASKS

HERE = Path(__file__).parent
VALUES = {
    "undeclared": {"mood": "fine"},
    "surrogate": {"note": "half \\ud800 of a pair"},
    "nan": {"score": float("nan")},
    "fine": {"note": "ok", "score": 1.5},
}


@dataclass(frozen=True)
class NotedTaskConfig(CubeTaskConfig):
    name: Literal["noted-cube"] = "noted-cube"


class Noted:
    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        mode = os.environ.get("NOTED_MODE", "fine")
        if mode == "raise":
            raise ZeroDivisionError("the env divided by zero")
        return observation, reward, terminated, truncated, {**info, "log_episode": VALUES[mode]}


def make_env(config, render_dir):
    from lagrseq.builtin_tasks.cube_stacking import make_env as cube_env

    return Noted(cube_env(config, render_dir))


def task():
    cube = TASKS.get("cube-stacking")
    return replace(
        cube, name="noted-cube", sections={**cube.sections, "task": NotedTaskConfig}, presets=HERE / "noted_presets",
        make_env=make_env, episode_fields={"note": "string", "score": "number"}, description="cube, noted",
    )
'''


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("site")
    install(root, "noted-plugin", "0.1", "notedplug", PLUGIN, "[lagrseq.tasks]\nnoted = notedplug:task\n")
    presets = root / "noted_presets"
    presets.mkdir()
    for preset in ("upstream", "paper"):
        text = (ROOT / "lagrseq" / "experiments" / "cube-stacking" / f"{preset}.toml").read_text()
        (presets / f"{preset}.toml").write_text(text.replace('name = "cube-stacking"', 'name = "noted-cube"'))
    return root


@pytest.mark.parametrize(
    ("mode", "named"),
    [
        ("undeclared", "info['log_episode'] has the field 'mood', which the task does not declare"),
        ("surrogate", "not valid UTF-8 text (a lone surrogate)"),
        ("nan", "not a finite number"),
        ("raise", "ZeroDivisionError: the env divided by zero"),
    ],
)
def test_a_deterministic_trial_failure_is_never_told_to_run_again(site: Path, tmp_path: Path, mode: str, named: str) -> None:
    done = lagrseq(site, "run", "noted-cube", "--trials", "1", "--set", "run.episodes=2", "--quiet", "--jobs", "1",
                   "--out", str(tmp_path / "runs"), cwd=tmp_path, env={"NOTED_MODE": mode})
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr
    assert runner.RERUN_ADVICE not in done.stderr
    assert (runner.CODE_ADVICE if mode == "raise" else runner.FIX_ADVICE) in done.stderr


def test_a_task_that_logs_what_it_declares_runs(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "run", "noted-cube", "--trials", "1", "--set", "run.episodes=2", "--quiet", "--jobs", "1",
                   "--out", str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr


def test_rerun_advice_by_cause() -> None:
    from concurrent.futures.process import BrokenProcessPool

    assert runner.rerun_advice(RecordError("undeclared")) == runner.FIX_ADVICE
    assert runner.rerun_advice(StoreError("unreadable")) == runner.FIX_ADVICE
    for transient in (OSError(28, "No space left on device"), ProviderError("the server did not answer"),
                      LogError("cannot write the log"), BrokenProcessPool("a worker died"), MemoryError()):
        assert runner.rerun_advice(transient) == runner.RERUN_ADVICE, transient
    assert runner.rerun_advice(KeyError("cells")) == runner.CODE_ADVICE
