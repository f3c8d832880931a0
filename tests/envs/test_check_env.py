"""Every registered lagrseq environment passes gymnasium's env checker."""

from __future__ import annotations

import gymnasium as gym
import pytest
from gymnasium.utils.env_checker import check_env

import lagrseq.envs  # noqa: F401  (registers the environments)

IDS = sorted(env_id for env_id in gym.registry if env_id.startswith("lagrseq/"))


def test_environments_are_registered() -> None:
    assert "lagrseq/CubeStacking-v0" in IDS


@pytest.mark.parametrize("env_id", IDS)
def test_check_env(env_id: str) -> None:
    try:
        env = gym.make(env_id)
    except gym.error.DependencyNotInstalled as exc:  # an env of an extra that is not installed
        pytest.skip(str(exc))
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


@pytest.mark.parametrize(
    "code",
    [
        # the documented way: importing lagrseq.envs registers every id, as gymnasium_robotics does
        "import gymnasium as gym, lagrseq.envs; env = gym.make('lagrseq/CubeStacking-v0')",
        # gymnasium's own module:id syntax imports the module first, so nothing else is needed
        "import gymnasium as gym; env = gym.make('lagrseq.envs:lagrseq/ObjectArrangement-v0')",
    ],
)
def test_the_documented_ways_to_make_an_env_work_in_a_fresh_interpreter(code: str) -> None:
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "-c", code + "; env.reset(seed=0); print(env.spec.id)"],
        capture_output=True, text=True, env={"PYTHONPATH": str(root)}, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().startswith("lagrseq/")
