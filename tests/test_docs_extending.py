"""docs/extending.md is tested: its example plugin is built from the page's own code blocks (each
block whose first line is ``# example plugin: FILE``; blocks naming one file are joined in order),
installed as a throw-away distribution (a ``.dist-info`` whose entry points are the page's
``pyproject.toml`` block's), and run through the command line in fresh interpreters."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq.tomlfile import loads as toml_loads

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "extending.md"
MARK = "# example plugin: "
PACKAGE = "countdown_plugin"


def example_files(page: str) -> dict[str, str]:
    """FILE -> its text, from the page's marked code blocks (python and toml)."""
    files: dict[str, str] = {}
    for body in re.findall(r"^```(?:python|toml)\n(.*?)^```$", page, flags=re.DOTALL | re.MULTILINE):
        first, _, rest = body.partition("\n")
        if first.startswith(MARK):
            name = first[len(MARK) :].strip()
            files[name] = files[name] + "\n\n" + rest if name in files else rest
    return files


def install(site: Path, files: dict[str, str]) -> dict[str, dict[str, str]]:
    """Write the package and its dist-info under ``site``; the entry points, by group."""
    project = toml_loads(files["pyproject.toml"], "pyproject.toml")["project"]
    package = site / PACKAGE
    for name, text in files.items():
        if name == "pyproject.toml":
            continue
        (package / name).parent.mkdir(parents=True, exist_ok=True)
        (package / name).write_text(text, encoding="utf-8")
    info = site / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    groups = project["entry-points"]
    (info / "entry_points.txt").write_text(
        "".join(f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in points.items()) + "\n" for group, points in groups.items())
    )
    return groups


@pytest.fixture(scope="module")
def plugin(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict[str, str]]]:
    site = tmp_path_factory.mktemp("site")
    return site, install(site, example_files(PAGE.read_text(encoding="utf-8")))


def lagrseq(site: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def test_the_page_holds_a_whole_plugin() -> None:
    files = example_files(PAGE.read_text(encoding="utf-8"))
    assert sorted(files) == ["__init__.py", "config.py", "env.py", "presets/upstream.toml", "pyproject.toml", "suite.toml", "task.py"]
    assert "paper.toml" not in " ".join(files)  # a task with no paper ships upstream.toml alone
    groups = toml_loads(files["pyproject.toml"], "pyproject.toml")["project"]["entry-points"]
    assert sorted(groups) == ["lagrseq.executors", "lagrseq.policies", "lagrseq.providers", "lagrseq.tasks"]


def test_the_pages_example_plugin_registers_runs_and_replays(plugin: tuple[Path, dict[str, dict[str, str]]], tmp_path: Path) -> None:
    site, groups = plugin
    listed = lagrseq(site, "plugins", cwd=tmp_path)
    assert listed.returncode == 0 and "skipped" not in listed.stdout + listed.stderr, listed.stdout + listed.stderr
    for points in groups.values():
        for name in points:
            assert re.search(rf"^  {re.escape(name)}\s+countdown-plugin 0\.1\.0 \[", listed.stdout, flags=re.MULTILINE), listed.stdout
    # a run with every part of the plugin: its task, provider (and the provider's own flag), policy knob and executor
    run = lagrseq(
        site, "run", "countdown", "--method", "lagr-seq", "--provider", "echo", "--echo-profile", "lazy",
        "--set", "secondary.every_k=2", "--executor", "serial", "--trials", "2", "--quiet", "--out", str(tmp_path / "runs"), cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    assert len(list((tmp_path / "runs").rglob("trial-*.mcap"))) == 2
    # no paper, no paper.toml: --preset paper is one line naming the presets the task has
    paper = lagrseq(site, "run", "countdown", "--preset", "paper", "--trials", "1", "--out", str(tmp_path / "paper"), cwd=tmp_path)
    assert paper.returncode == 2 and paper.stderr.count("\n") == 1, paper.stderr
    assert "has no 'paper' preset" in paper.stderr and "expected one of upstream" in paper.stderr, paper.stderr
    assert not (tmp_path / "paper").exists()
    # replay finds the task's own suite: both items drawn, no --suite, the paper's items one line
    replayed = lagrseq(site, "replay", str(tmp_path / "runs"), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert replayed.returncode == 0, replayed.stderr
    assert "2 of 2 suite items made from 2 logs" in replayed.stdout, replayed.stdout
    assert "not run" not in replayed.stdout and replayed.stdout.count("the paper's suite") == 1, replayed.stdout
    for item in ("countdown-returns", "countdown-queries"):
        assert (tmp_path / "report" / "figures" / f"{item}.png").stat().st_size > 0
