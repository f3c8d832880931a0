"""Profiles and knobs belong to their owner: a mock profile to its task, a knob to its policy
(refused in one line elsewhere); knobs' help shown by ``lagrseq config`` and ``lagrseq plugins``;
a plugin's config section range-checked from its field declarations; ``frontier`` checks every
variant before it makes ``--out`` and prints a console table sized to its labels."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.errors import ConfigError, UsageError

ROOT = Path(__file__).resolve().parents[1]

STRIDE = '''
from lagrseq.registry import Knob, PolicySpec


class Stride:
    """Ask at every k-th eligible decision (and at the first one when eager)."""

    def __init__(self, k, eager):
        self.k, self.eager, self.n = k, eager, 0

    def decide(self, context):
        self.n += 1
        return int((self.eager and self.n == 1) or self.n % self.k == 0)

    def update(self, context, asked, query_reward):
        pass


def policy():
    return PolicySpec(
        "stride", lambda section, seq_agent: Stride(section.knob("stride_k"), section.knob("eager")),
        ("min_progress", "budget", Knob("stride_k", 7, ge=1, le=1000, help="ask at every k-th eligible step"),
         Knob("eager", False, help="ask at the first eligible step too")),
        description="ask at every k-th eligible step",
    )
'''


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("site")
    (root / "strideplug.py").write_text(STRIDE)
    info = root / "stride_plugin-0.2.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: stride-plugin\nVersion: 0.2\n")
    (info / "entry_points.txt").write_text("[lagrseq.policies]\nstride = strideplug:policy\n")
    return root


def lagrseq(site: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def test_config_shows_the_policys_knobs_with_their_help_and_defaults(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "config", "cube-stacking", "--set", 'secondary.policy="stride"', "--set", "secondary.stride_k=3", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "stride_k = 3  # ask at every k-th eligible step; a knob of policy stride, set (default 7)" in lines
    assert "eager = false  # ask at the first eligible step too; a knob of policy stride, not set (default False)" in lines
    policy = next(line for line in lines if line.startswith("policy = "))
    assert "stride: ask at every k-th eligible step" in policy and "seq: the paper's SEQ bandit" in policy


def test_plugins_lists_each_policys_knobs(site: Path, tmp_path: Path) -> None:
    done = lagrseq(site, "plugins", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert re.search(r"\n  stride +stride-plugin 0\.2 .*\n      reads \[secondary\] min_progress, budget\n"
                     r"      knob stride_k = 7: ask at every k-th eligible step\n      knob eager = False: ask at the first eligible step too\n", done.stdout)
    assert "      knob ask_probability = 0.5: probability of asking when triggered\n" in done.stdout


def test_frontier_refuses_another_policys_knob_and_a_bad_variant_before_making_out(site: Path, tmp_path: Path) -> None:
    for policies, message in [
        ("always,stride:ask_probability=0.3", "not of stride, which would ignore it; stride's knobs: min_progress, budget, stride_k, eager"),
        ("always,stride:stride_k=0", "secondary.stride_k = 0 is out of range"),
        ("always,random:ask_probability=2", "secondary.ask_probability = 2.0; expected a finite number in [0, 1]"),
    ]:
        out = tmp_path / "fr"
        done = lagrseq(site, "frontier", "cube-stacking", "--policies", policies, "--trials", "1", "--out", str(out), cwd=tmp_path)
        assert done.returncode == 2 and done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
        assert not out.exists()  # checked before anything was made
        if "stride:ask" in policies:
            assert "ask_probability is a knob of random" in done.stderr


def test_frontier_console_table_sizes_its_labels_and_says_yes_for_true(site: Path, tmp_path: Path) -> None:
    done = lagrseq(
        site, "frontier", "cube-stacking", "--policies", "always,stride:eager=true", "--trials", "2", "--set", "run.episodes=3",
        "--no-matched-random", "--jobs", "1", "--quiet", "--out", str(tmp_path / "fr"), cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("  ") and " queries " in line]
    labels = [row[2:row.index(" queries ")].rstrip() for row in rows]
    assert "stride (eager yes)" in labels and "always" in labels
    assert {row.index(" queries ") for row in rows} == {2 + max(map(len, labels))}  # the longest label, then one space


def test_a_mock_profile_belongs_to_its_task() -> None:
    from lagrseq.running.wiring import check_provider, extrapolator

    grid = cfg.load("object-arrangement", "lagr", "upstream")
    with pytest.raises(UsageError, match=r"mock profile 'authors-t0' is not one of task object-arrangement's \(authors-t0 is another task's\); "
                                         r"expected --provider mock or mock:PROFILE with PROFILE one of: ideal, authors-gpt4, refuses"):
        check_provider("mock:authors-t0", grid)
    cube = cfg.load("cube-stacking", "lagr", "upstream")
    with pytest.raises(UsageError, match="one of: ideal, oracle, authors-t0, refuses"):
        extrapolator(cube, "authors-gpt4")
    assert callable(extrapolator(cube, "oracle")) and callable(extrapolator(grid, "refuses"))


@dataclasses.dataclass(frozen=True)
class PluginEnvConfig:
    """[env] of a plugin task: plain dataclass fields, one of them with a declared range."""

    horizon: int = cfg.ranged(40, ge=1, le=100_000)
    """Steps per episode."""
    bonus: float = 1.0
    """No range declared: not checked."""


def test_a_plugin_section_is_range_checked_from_its_declarations_without_a_call() -> None:
    assert cfg.build_section(PluginEnvConfig, "env", {"horizon": 12, "bonus": -5.0}) == PluginEnvConfig(12, -5.0)
    with pytest.raises(ConfigError, match=r"^env.horizon = 0; expected an integer in \[1, 100000\]$"):
        cfg.build_section(PluginEnvConfig, "env", {"horizon": 0})
