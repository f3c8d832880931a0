"""Every number from outside is bounded where it enters: each numeric command-line option (the
parser is walked, so a new option cannot slip through) and each numeric configuration field has
both a lower and an upper limit, and a value past either is one line, exit status 2, at once."""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lagrseq import cli
from lagrseq import config as cfg

ROOT = Path(__file__).resolve().parents[1]
HUGE = "1" + "0" * 40


def numeric_options() -> list[tuple[str, str, argparse.Action]]:
    """(command, option, action) of every option whose type reads a number."""
    found = []

    def walk(parser: argparse.ArgumentParser, name: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, child in action.choices.items():
                    walk(child, f"{name} {sub}".strip())
            elif callable(action.type) and action.type not in (Path, str):
                try:
                    action.type("1")
                except (argparse.ArgumentTypeError, ValueError, TypeError):
                    continue  # not a number type (figure formats)
                found.append((name, action.option_strings[0] if action.option_strings else action.dest, action))

    walk(cli.build_parser(), "")
    return found


def test_every_numeric_option_has_an_upper_bound() -> None:
    options = numeric_options()
    assert len(options) > 20 and any(option == "--retries" for _, option, _ in options)
    unbounded = []
    for command, option, action in options:
        try:
            action.type(HUGE)  # type: ignore[misc]
            unbounded.append(f"{command} {option}")
        except argparse.ArgumentTypeError as error:
            assert "\n" not in str(error)
    assert unbounded == []


@pytest.mark.parametrize("option", [["--retries", "1000000"], ["--max-queries", HUGE], ["--max-cost-usd", "1e300"]])
def test_the_probes_unbounded_options_are_one_line(option: list[str]) -> None:
    done = subprocess.run([sys.executable, "-m", "lagrseq", "run", "cube-stacking", *option, "--trials", "1"],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and option[0] in done.stderr, done.stderr


def sections() -> list[type]:
    return [obj for obj in vars(cfg).values() if isinstance(obj, type) and issubclass(obj, cfg._Section) and obj is not cfg._Section]


def test_every_numeric_config_field_is_bounded_both_ways() -> None:
    loose = []
    for section in sections():
        for field in cfg.numeric_fields(section):
            bound = field.metadata.get("range")
            if bound is None or (bound.le is None and bound.lt is None) or (bound.ge is None and bound.gt is None):
                loose.append(f"{section.__name__}.{field.name}")
    assert len(sections()) >= 10 and loose == []


@pytest.mark.parametrize(("override", "expected"), [
    ("env.scans=1000000", "env.scans"),
    ("env.horizon=100000000", "env.horizon"),
    ("primary.batch_size=1000000", "primary.batch_size"),
    ("secondary.reward_wrong=-1e300", "secondary.reward_wrong"),
])
def test_values_past_the_new_limits_are_refused_before_any_trial(override: str, expected: str, tmp_path: Path) -> None:
    task = "image-completion" if override.startswith("env.scans") else "cube-stacking" if "horizon" in override else "object-arrangement"
    method = ["--method", "lagr-seq"] if override.startswith("secondary") else []
    done = subprocess.run([sys.executable, "-m", "lagrseq", "run", task, *method, "--set", override, "--trials", "1", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and expected in done.stderr, done.stderr
    assert not list(tmp_path.rglob("*.mcap*"))


def test_defaults_and_presets_stay_inside_the_limits() -> None:
    for task in cfg.tasks():
        for preset in cfg.PRESETS:
            for method in ("lagr-seq", "lagr", "rl"):
                try:
                    resolved = cfg.load(task, method, preset)
                except cfg.ConfigError as error:
                    assert "method" in str(error), error
                    continue
                assert dataclasses.is_dataclass(resolved)


def test_cpu_threads_at_its_limit_is_capped_at_the_usable_cores() -> None:
    """The probe's hanging ``--set`` value: primary.cpu_threads = 1024 (inside its range) gave
    torch 1024 threads on a 2-core machine, and every update became 65 times slower (1.9 against
    121 updates/s, benchmarked with the DQN's network shape under load): a run seemed to hang.
    The agent now gives torch at most the cores the process may use."""
    torch = pytest.importorskip("torch")
    from lagrseq.agents.dqn import DQN, usable_cores

    before = torch.get_num_threads()
    try:
        DQN(observation_size=4, n_actions=2, hidden_sizes=(8,), learning_rate=1e-3, discount=0.9, batch_size=4,
                 buffer_size=16, target_update_interval=0, seed=0, cpu_threads=1024)
        assert torch.get_num_threads() == min(1024, usable_cores()) <= (os.cpu_count() or 1)
    finally:
        torch.set_num_threads(before)
