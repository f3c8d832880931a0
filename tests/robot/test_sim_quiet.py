"""The simulated arm prints nothing of pybullet's own: its C "build time" banner would land in the
middle of ``lagrseq reproduce``'s progress bars."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pybullet")

ROOT = Path(__file__).resolve().parents[2]

PROGRAM = """
import sys
print("before", flush=True)
from lagrseq.envs.arm_arrangement import make_robot
robot = make_robot("sim")
print("after", flush=True)
print("python's stderr still works", file=sys.stderr, flush=True)
"""


def test_building_the_simulated_arm_writes_only_what_python_prints() -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", PROGRAM], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "before\nafter\n"
    assert result.stderr == "python's stderr still works\n"


def test_without_silencing_pybullet_does_print_its_banner() -> None:
    """The check above is not vacuous: the same pybullet, imported and connected plainly, prints."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    program = "import pybullet as p; p.connect(p.DIRECT)"
    result = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=300, env=env)
    assert "pybullet" in result.stdout + result.stderr
