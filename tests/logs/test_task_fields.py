"""A task's own logged fields (``TaskSpec.episode_fields``, ``step_fields``): a plugin task's env
puts ``wrong_bits`` in ``info["log_episode"]`` and ``parity`` in ``info["log_step"]``; the MCAP
holds them under schemas that name them (read with the plain ``mcap`` library), ``lagrseq
replay`` puts them in the runs table and its CSV; an undeclared field or a value of the wrong
type stops the trial in one line naming the field and the declaration."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from lagrseq.errors import LogError
from lagrseq.logs.events import EpisodeEvent, Transition
from lagrseq.logs.task_fields import builtin_episode, builtin_step, task_fields
from lagrseq.registry import LOGGED_EPISODE_FIELDS, LOGGED_STEP_FIELDS, TaskSpec

ROOT = Path(__file__).resolve().parents[2]

PLUGIN = '''
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from lagrseq.config import CubeTaskConfig
from lagrseq.registry import TASKS, TaskSpec

HERE = Path(__file__).parent
FIELDS = {"wrong_bits": "integer"}


@dataclass(frozen=True)
class CountedTaskConfig(CubeTaskConfig):
    name: Literal["counted-cube"] = "counted-cube"


class Counted:
    """The cube's env, counting its unpaid steps as wrong bits (per episode) and logging each
    action's parity (per step)."""

    def __init__(self, env, extra):
        self.env, self.extra, self.wrong = env, extra, 0

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, **kwargs):
        self.wrong = 0
        return self.env.reset(**kwargs)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.wrong += reward <= 0
        info = dict(info)
        info["log_episode"] = {"wrong_bits": self.wrong, **self.extra}
        info["log_step"] = {"parity": int(action) % 2 == 1}
        return observation, reward, terminated, truncated, info


def make_env(config, render_dir):
    from lagrseq.builtin_tasks.cube_stacking import make_env as cube_env

    sloppy = os.environ.get("COUNTED_SLOPPY")  # an env that logs a field its task does not declare
    return Counted(cube_env(config, render_dir), {"mood": sloppy} if sloppy else {})


def good():
    cube = TASKS.get("cube-stacking")
    return replace(
        cube, name="counted-cube", sections={**cube.sections, "task": CountedTaskConfig}, presets=HERE / "counted_presets",
        make_env=make_env, episode_fields=FIELDS, step_fields={"parity": "boolean"}, description="cube, counted",
    )
'''


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("site")
    (root / "countedplug.py").write_text(PLUGIN)
    presets = root / "counted_presets"
    presets.mkdir()
    for preset in ("upstream", "paper"):
        text = (ROOT / "lagrseq" / "experiments" / "cube-stacking" / f"{preset}.toml").read_text()
        (presets / f"{preset}.toml").write_text(text.replace('name = "cube-stacking"', 'name = "counted-cube"'))
    info = root / "counted_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: counted-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[lagrseq.tasks]\ncounted = countedplug:good\n")
    return root


def lagrseq(site: Path, *args: str, cwd: Path, sloppy: str = "") -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "COUNTED_SLOPPY")}
    if sloppy:
        env["COUNTED_SLOPPY"] = sloppy
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


SMALL = ("--method", "lagr-seq", "--trials", "2", "--set", "run.episodes=4", "--quiet", "--jobs", "1")


def test_a_plugin_tasks_own_fields_are_logged_under_its_schema_and_replayed(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "run", "counted-cube", *SMALL, "--out", str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    logs = sorted((tmp_path / "runs").rglob("trial-*.mcap"))
    assert len(logs) == 2
    with logs[0].open("rb") as stream:  # the plain mcap library: what Foxglove reads
        reader = make_reader(stream)
        schemas = {channel.topic: reader.get_summary().schemas[channel.schema_id] for channel in reader.get_summary().channels.values()}  # type: ignore[union-attr]
        episodes = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/episode"])]
        steps = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/transitions"])]
    episode_schema = json.loads(schemas["/episode"].data)
    assert episode_schema["properties"]["wrong_bits"]["type"] == ["integer", "null"]
    assert episode_schema["x-lagrseq-task-fields"] == {"wrong_bits": "integer"}
    assert json.loads(schemas["/transitions"].data)["properties"]["parity"]["items"]["type"] == ["boolean", "null"]
    assert len(episodes) == 4 and all(type(e["wrong_bits"]) is int and 0 <= e["wrong_bits"] <= e["length"] for e in episodes)
    assert sum(e["wrong_bits"] for e in episodes) > 0  # epsilon-greedy cube trials place wrong cubes
    assert all(len(s["parity"]) == len(s["action"]) and s["parity"] == [a % 2 == 1 for a in s["action"]] for s in steps)

    replayed = lagrseq(site, "replay", str(tmp_path / "runs"), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert replayed.returncode == 0, replayed.stderr
    with (tmp_path / "report" / "tables" / "runs.csv").open() as file:
        (row,) = list(csv.DictReader(file))
    per_trial = []
    for log in logs:
        with log.open("rb") as stream:
            counts = [json.loads(m.data)["wrong_bits"] for _, _, m in make_reader(stream).iter_messages(topics=["/episode"])]
        per_trial.append(sum(counts) / len(counts))
    assert float(row["wrong_bits_per_episode_mean"]) == pytest.approx(sum(per_trial) / 2, rel=1e-4)
    assert int(row["wrong_bits_trials"]) == 2 and float(row["wrong_bits_per_episode_se"]) >= 0
    markdown = (tmp_path / "report" / "tables" / "runs.md").read_text()
    assert "wrong_bits per episode (mean ± s.e. over trials)" in markdown and "(n = 2)" in markdown
    # the step field too: the share of steps with an odd action, per trial, averaged over the trials
    from lagrseq.logs.reader import read_topic

    shares = [sum(s["parity"] for s in read_topic(log, "/transition")) / len(read_topic(log, "/transition")) for log in logs]
    assert float(row["parity_per_step_mean"]) == pytest.approx(sum(shares) / 2, rel=1e-4) and int(row["parity_trials"]) == 2
    assert "parity (share of steps, mean ± s.e. over trials)" in markdown


def test_an_undeclared_field_stops_the_run_in_one_line_naming_it(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "run", "counted-cube", *SMALL, "--out", str(tmp_path / "runs"), cwd=tmp_path, sloppy="fine")
    assert done.returncode != 0
    assert "info['log_episode'] has the field 'mood', which the task does not declare" in done.stderr
    assert "episode_fields={'mood': 'string'}" in done.stderr
    assert "Traceback" not in done.stderr


def test_task_records_check_the_declared_types_and_leave_out_what_no_env_logged() -> None:
    own = task_fields("t", (("wrong_bits", "integer"), ("rate", "number")), (("parity", "boolean"),))
    assert own is not None and issubclass(own.episode, EpisodeEvent) and issubclass(own.transition, Transition)
    event = own.episode_event({"wrong_bits": 3}, trial=0, episode=1, return_=1.0)
    assert (event.wrong_bits, event.rate) == (3, None)  # type: ignore[attr-defined]
    with pytest.raises(LogError, match=r"info\['log_episode'\]\['wrong_bits'\] = 2.5: an integer was declared, found float"):
        own.episode_event({"wrong_bits": 2.5}, trial=0, episode=1, return_=1.0)
    with pytest.raises(LogError, match="not a finite number"):
        own.episode_event({"rate": float("nan")}, trial=0, episode=1, return_=1.0)
    with pytest.raises(LogError, match=r"field 'colour'.*step_fields=\{'colour': 'string'\}"):
        own.step((0, 0, 0, 0, (), 1, 0.0, False, False, False), {"colour": "red"})
    assert task_fields("t", (), ()) is None
    with pytest.raises(LogError, match=r"the run's task: info\['log_episode'\] has the field 'x'"):
        builtin_episode({"x": 1}, trial=0, episode=0, return_=0.0)
    with pytest.raises(LogError, match=r"info\['log_step'\] has the field 'y'"):
        builtin_step((0, 0, 0, 0, (), 1, 0.0, False, False, False), {"y": 1})


def test_a_task_spec_refuses_bad_declarations_and_the_reserved_names_are_lagrseqs() -> None:
    import msgspec

    from lagrseq.logs.events import ArmEpisodeEvent

    base = {"name": "t", "sections": {}, "presets": Path("."), "make_task": print, "make_env": print, "extrapolator": print}
    with pytest.raises(ValueError, match="expected one of integer, number, boolean, string"):
        TaskSpec(**base, episode_fields={"a": "float"})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="is a field lagrseq logs itself"):
        TaskSpec(**base, step_fields={"reward": "number"})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="not an identifier"):
        TaskSpec(**base, episode_fields={"a b": "integer"})  # type: ignore[arg-type]
    episode = {f.encode_name for f in msgspec.structs.fields(ArmEpisodeEvent)} | {"return_"}
    assert episode == LOGGED_EPISODE_FIELDS
    assert {f.encode_name for f in msgspec.structs.fields(Transition)} == LOGGED_STEP_FIELDS


@pytest.mark.parametrize("log_format", ["2", "3"])
def test_both_log_formats_write_and_read_back_a_tasks_own_fields(tmp_path: Path, log_format: str) -> None:
    from lagrseq.logs.reader import read_rows, read_topic
    from lagrseq.logs.sink import McapSink

    own = task_fields("t", (("wrong_bits", "integer"),), (("parity", "boolean"),))
    assert own is not None
    path = tmp_path / "trial-000.mcap"
    with McapSink(path, {"task": "t"}, log_format=log_format, task_fields=own) as sink:
        sink.write(own.step((0, 0, 0, 0, (), 1, 1.0, False, False, False), {"parity": True}))
        sink.write(own.transition(0, 0, 1, 1, (1,), 2, 0.0, True, False, False))
        sink.write(own.episode_event({"wrong_bits": 1}, trial=0, episode=0, return_=1.0, length=2, global_step=2))
        sink.write(own.episode_event(None, trial=0, episode=1, return_=0.0, length=0, global_step=2))
    steps = read_topic(path, "/transition")
    assert [s.get("parity") for s in steps] == [True, None] and "parity" not in steps[1]
    assert [e["wrong_bits"] for e in read_topic(path, "/episode")] == [1, None]
    rows = read_rows(path, {"/episode": ("episode", "return")}, task_fields=True)
    assert rows.task_fields == {"/episode": (("wrong_bits", "integer"),)}
    assert rows.rows["/episode"] == [(0, 1.0, 1), (1, 0.0, None)]
