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
