"""Outputs under a canary API key and hostile files: a suite run whose plugin task's env raises
(with the key in its message, in every form the key guard knows) is one failed item, and no
report file, error log or terminal line holds the key; the error log never lands on a link, a
folder or a FIFO; ``config --set llm.model=<key>`` never prints it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
KEY = "sk-canaryQ7x9Lm2Pz4Rt8Vw3Yb6Nc1Df5Gh0Jk"
BODY = KEY[3:]
ZW = "\u200b"
FORMS = (KEY, BODY, BODY.upper(), BODY[-12:], ZW.join(BODY[i : i + 3] for i in range(0, len(BODY), 3)))

PLUGIN = '''
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from lagrseq.config import CubeTaskConfig
from lagrseq.registry import TASKS

HERE = Path(__file__).parent


@dataclass(frozen=True)
class BrokenTaskConfig(CubeTaskConfig):
    name: Literal["broken-cube"] = "broken-cube"


def make_env(config, render_dir):
    key = os.environ["OPENAI_API_KEY"]
    body = key[3:]
    spaced = "\\u200b".join(body[i : i + 3] for i in range(0, len(body), 3))
    raise RuntimeError(f"the env cannot start: {key} {body} {body.upper()} {body[-12:]} {spaced}")


@dataclass(frozen=True)
class KeyedTaskConfig(CubeTaskConfig):
    name: Literal["keyed-cube"] = "keyed-cube"


class Keyed:
    """The cube's env, logging the key (without sk-, zero-width spaced) as its own field."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        body = os.environ["OPENAI_API_KEY"][3:]
        info = dict(info)
        info["log_episode"] = {"remark": "\u200b".join(body[i : i + 3] for i in range(0, len(body), 3))}
        return observation, reward, terminated, truncated, info


def keyed_env(config, render_dir):
    from lagrseq.builtin_tasks.cube_stacking import make_env as cube_env

    return Keyed(cube_env(config, render_dir))


def keyed():
    cube = TASKS.get("cube-stacking")
    return replace(
        cube, name="keyed-cube", sections={**cube.sections, "task": KeyedTaskConfig}, presets=HERE / "keyed_presets",
        make_env=keyed_env, episode_fields={"remark": "string"}, description="cube logging a key",
    )


def spec():
    cube = TASKS.get("cube-stacking")
    return replace(
        cube, name="broken-cube", sections={**cube.sections, "task": BrokenTaskConfig}, presets=HERE / "broken_presets",
        make_env=make_env, description="cube whose env raises",
    )
'''

SUITE = """
[suite]
seed = 0
provider = "mock"

[[items]]
id = "broken"
title = "An env that raises"
render = "returns"
task = "broken-cube"
preset = "upstream"
quick_trials = 1
quick_episodes = 2

[[items.runs]]
label = "Q-learning"
method = "baseline"
"""


def leaks(text: str) -> list[str]:
    """The forms of the key ``text`` holds (zero-width spaces ignored, any case)."""
    plain = text.replace(ZW, "").lower()
    return [form for form in (BODY[:12], BODY[-12:]) if form.lower() in plain]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("site")
    (root / "brokenplug.py").write_text(PLUGIN)
    presets = root / "broken_presets"
    presets.mkdir()
    (root / "keyed_presets").mkdir()
    for preset in ("upstream", "paper"):
        text = (ROOT / "lagrseq" / "experiments" / "cube-stacking" / f"{preset}.toml").read_text()
        (presets / f"{preset}.toml").write_text(text.replace('name = "cube-stacking"', 'name = "broken-cube"'))
        (root / "keyed_presets" / f"{preset}.toml").write_text(text.replace('name = "cube-stacking"', 'name = "keyed-cube"'))
    info = root / "broken_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[lagrseq.tasks]\nbroken = brokenplug:spec\nkeyed = brokenplug:keyed\n")
    return root


def lagrseq(*args: str, cwd: Path, site: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["OPENAI_API_KEY"] = KEY
    env["PYTHONPATH"] = os.pathsep.join([*([str(site)] if site else []), str(ROOT)])
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=timeout)


@pytest.fixture(scope="module")
def failed_suite(site: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, subprocess.CompletedProcess[str]]:
    root = tmp_path_factory.mktemp("elsewhere")  # not the checkout: its path must not be written
    (root / "suite.toml").write_text(SUITE)
    done = lagrseq("reproduce", "--quick", "--suite", "suite.toml", "--out", "out", "--jobs", "1", "--quiet", cwd=root, site=site)
    return root, done


def test_a_trial_that_raises_in_the_time_estimate_is_one_failed_item(failed_suite: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    root, done = failed_suite
    assert done.returncode == 3, done.stderr
    assert "Traceback" not in done.stderr
    assert "1 of 1 items failed: broken" in done.stderr.splitlines()[-1]
    index = (root / "out" / "reports" / "index.md").read_text(encoding="utf-8")
    assert "(FAILED)" in index and "the env cannot start" in index
    assert "the env cannot start" in (root / "out" / "reproduce-errors.log").read_text(encoding="utf-8")


def test_no_output_of_a_failed_suite_holds_the_key_or_the_checkouts_path(failed_suite: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    root, done = failed_suite
    assert not leaks(done.stdout + done.stderr)
    written = [p for p in (root / "out").rglob("*") if p.is_file() and p.suffix in (".md", ".html", ".csv", ".log")]
    assert any(p.name == "reproduce-errors.log" for p in written) and any(p.name == "index.html" for p in written)
    for path in written:
        text = path.read_text(encoding="utf-8")
        assert not leaks(text), path
        assert str(ROOT) not in text, path


@pytest.mark.parametrize("name", ["reproduce-errors.log", "reports/index.html", "reports/index.md"])
@pytest.mark.parametrize("kind", ["directory", "fifo", "symlink"])
def test_a_report_path_that_is_no_file_is_refused_before_anything_runs(tmp_path: Path, kind: str, name: str) -> None:
    from lagrseq.errors import UsageError
    from lagrseq.study import reproduce
    (tmp_path / "suite.toml").write_text(SUITE.replace("broken-cube", "cube-stacking"))
    out = tmp_path / "out"
    log = out / name
    log.parent.mkdir(parents=True)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    {"directory": log.mkdir, "fifo": lambda: os.mkfifo(log), "symlink": lambda: log.symlink_to(victim)}[kind]()
    with pytest.raises(UsageError, match=name):
        reproduce.reproduce(reproduce.Request(tmp_path / "suite.toml", None, True, None, out, 1), reproduce.Reporter.silent())
    assert not (out / "runs").exists() and victim.read_text() == "precious"


def test_an_error_log_path_that_turns_into_a_folder_during_the_runs_loses_no_report(tmp_path: Path) -> None:
    from lagrseq.study import reproduce

    failure = reproduce.RunFailure("a run", tmp_path / "runs" / "x", 1, 1, ("trial 0 failed: boom",), "boom", "fix it", ("item",))
    (tmp_path / reproduce.ERRORS_LOG).mkdir()
    from lagrseq.errors import UsageError

    with pytest.raises(UsageError, match="is a directory"):
        reproduce.write_errors_log(tmp_path, [failure])
    reproduce.write_errors_log(tmp_path, [])  # nothing failed: a folder there is left alone
    assert (tmp_path / reproduce.ERRORS_LOG).is_dir()


def test_config_never_prints_a_key_given_as_a_value(tmp_path: Path) -> None:
    for value in (BODY, BODY.upper(), KEY):
        done = lagrseq("config", "cube-stacking", "--method", "lagr", "--set", f'llm.model="{value}"', cwd=tmp_path, timeout=120)
        assert done.returncode == 0, done.stderr
        assert "[REDACTED]" in done.stdout and not leaks(done.stdout + done.stderr)


def test_an_unforeseen_errors_traceback_holds_no_key(tmp_path: Path) -> None:
    program = (
        "import os, sys\n"
        "from lagrseq import cli\n"
        "key = os.environ['OPENAI_API_KEY']\n"
        "def broken(args):\n"
        "    raise RuntimeError(f'{key} {key[3:].upper()} {key[-12:]}')\n"
        "cli.COMMANDS['config'] = broken\n"
        "sys.argv = ['lagrseq', 'config', 'cube-stacking']\n"
        "sys.exit(cli.main())\n"
    )
    env = {**os.environ, "OPENAI_API_KEY": KEY, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert done.returncode == 1 and "RuntimeError" in done.stderr and "[REDACTED]" in done.stderr
    assert not leaks(done.stdout + done.stderr)


def test_a_task_field_holding_the_key_reaches_no_report_file(site: Path, tmp_path: Path) -> None:
    ran = lagrseq("run", "keyed-cube", "--method", "baseline", "--trials", "1", "--set", "run.episodes=2", "--quiet",
                  "--out", "runs", cwd=tmp_path, site=site)
    assert ran.returncode == 0, ran.stderr
    done = lagrseq("replay", "runs", "--out", "report", cwd=tmp_path, site=site)
    assert done.returncode == 0, done.stderr
    assert not leaks(ran.stdout + ran.stderr + done.stdout + done.stderr)
    written = [p for p in (tmp_path / "report").rglob("*") if p.is_file() and p.suffix in (".md", ".html", ".csv")]
    assert any(p.name == "runs.md" for p in written)
    assert "remark" in (tmp_path / "report" / "tables" / "runs.md").read_text(encoding="utf-8")
    for path in written:
        assert not leaks(path.read_text(encoding="utf-8")), path


def test_a_trial_that_raises_in_a_workers_time_estimate_is_one_failed_item(site: Path, tmp_path: Path) -> None:
    (tmp_path / "suite.toml").write_text(SUITE + SUITE[SUITE.index("[[items]]"):].replace('id = "broken"', 'id = "broken-too"').replace("baseline", "lagr-seq"))
    done = lagrseq("reproduce", "--quick", "--suite", "suite.toml", "--out", "out", "--jobs", "2", "--quiet", cwd=tmp_path, site=site)
    assert done.returncode == 3 and "Traceback" not in done.stderr, done.stderr
    assert "2 of 2 items failed" in done.stderr.splitlines()[-1]
    assert not leaks(done.stdout + done.stderr + (tmp_path / "out" / "reproduce-errors.log").read_text(encoding="utf-8"))
