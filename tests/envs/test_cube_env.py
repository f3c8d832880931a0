"""Rewards and transitions of the cube env, worked by hand from SPEC section 1.1."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.envs.cube_stacking import CubeStackingEnv
from lagrseq.tasks.cube_dynamics import CubeStackingDynamics

E, F, G, A, B, C, D, H = 4, 5, 6, 0, 1, 2, 3, 7
TARGET = (E, F, G, A, B, C, D, H)


def upstream_env() -> CubeStackingEnv:
    return CubeStackingEnv(
        stack_size=8,
        horizon=50,
        bonus_on="either-state",
        revert_wrong_cube=True,
        wrong_cube_reward="pre-revert",
        terminate_on_complete=False,
    )


def paper_env() -> CubeStackingEnv:
    return CubeStackingEnv(stack_size=8, horizon=100, revert_wrong_cube=False)


def stack(env: CubeStackingEnv, cubes: tuple[int, ...]) -> list[float]:
    env.reset()
    return [env.step(c + 1)[1] for c in cubes]


def test_adding_the_right_cube_earns_2l_plus_1_and_the_last_one_16() -> None:
    rewards = stack(upstream_env(), TARGET)
    assert rewards == [1, 3, 5, 7, 9, 11, 13, 16]  # 15 + bonus for the complete stack


@pytest.mark.parametrize("length", range(0, 7))
def test_a_wrong_cube_earns_l_and_is_taken_off_again(length: int) -> None:
    env = upstream_env()
    stack(env, TARGET[:length])
    wrong = next(c for c in range(8) if c not in TARGET[: length + 1])
    _, reward, _, _, info = env.step(wrong + 1)
    assert reward == length
    assert info["pattern"] == TARGET[:length]
    assert info["pre_revert_pattern"] == TARGET[:length] + (wrong,)


def test_a_wrong_cube_stays_without_the_revert() -> None:
    env = paper_env()
    stack(env, TARGET[:3])
    _, reward, _, _, info = env.step(H + 1)
    assert reward == 3 and info["pattern"] == (E, F, G, H)
    _, reward, _, _, info = env.step(0)  # removing it: E goes from 12 to 9
    assert reward == -3 and info["pattern"] == (E, F, G)


@pytest.mark.parametrize("length", range(1, 8))
def test_removing_a_correct_cube_costs_2l_minus_1(length: int) -> None:
    env = upstream_env()
    stack(env, TARGET[:length])
    assert env.step(0)[1] == -(2 * length - 1)


def test_full_stack_edge_cases_of_the_released_code() -> None:
    env = upstream_env()
    stack(env, TARGET)
    _, reward, _, _, info = env.step(H + 1)  # "add" on the full stack: no-op, bonus for staying
    assert reward == 1 and info["pattern"] == TARGET
    assert env.step(0)[1] == -14  # -15 + the bonus for leaving the complete stack
    env.reset()
    assert env.step(0)[1] == 0  # remove on the empty stack


def test_paper_env_terminates_on_the_complete_stack_and_pays_the_bonus_once() -> None:
    env = paper_env()
    env.reset()
    for cube in TARGET[:-1]:
        assert not env.step(cube + 1)[2]
    _, reward, terminated, truncated, _ = env.step(H + 1)
    assert (reward, terminated, truncated) == (16, True, False)


def test_horizon_truncates() -> None:
    env = CubeStackingEnv(horizon=3)
    env.reset()
    flags = [env.step(0)[3] for _ in range(3)]
    assert flags == [False, False, True]


def test_action_mask_follows_the_released_validity_rule() -> None:
    env = upstream_env()
    _, info = env.reset()
    assert info["action_mask"].tolist() == [1] * 9  # remove is a valid no-op on the empty stack
    _, _, _, _, info = env.step(E + 1)
    assert info["action_mask"][E + 1] == 0 and info["action_mask"].sum() == 8
    stack(env, TARGET)
    assert env.action_mask().tolist() == [1] + [0] * 8


def test_observation_pads_with_n_and_render() -> None:
    env = CubeStackingEnv(render_mode="ansi")
    obs, _ = env.reset()
    assert obs.tolist() == [8] * 8
    obs, *_ = env.step(E + 1)
    assert obs.tolist() == [E] + [8] * 7
    assert env.render() == "stack (bottom to top): e\n"
    with pytest.raises(ValueError, match="outside"):
        env.step(9)


def test_paper_reading_of_the_wrong_cube_reward_is_zero() -> None:
    env = CubeStackingEnv(stack_size=8, horizon=100, revert_wrong_cube=True, wrong_cube_reward="zero")
    stack(env, TARGET[:6])
    _, reward, _, _, info = env.step(H + 1)
    assert reward == 0 and info["pattern"] == TARGET[:6]


@settings(max_examples=60, deadline=None)
@given(
    stack_size=st.sampled_from((5, 8, 11)),
    upstream=st.booleans(),
    terminate=st.booleans(),
    data=st.data(),
)
def test_a_run_s_gymnasium_free_dynamics_step_as_the_gymnasium_env(stack_size: int, upstream: bool, terminate: bool, data: st.DataObject) -> None:
    """A run steps ``CubeStackingDynamics`` (no gymnasium import); the registered env is that
    class with Gymnasium's interface, and both give the same observations, rewards, ends and
    infos on any action sequence, across episodes."""
    settings_ = dict(
        stack_size=stack_size, horizon=12, bonus_on="either-state" if upstream else "next-state",
        revert_wrong_cube=upstream, wrong_cube_reward="pre-revert" if upstream else "zero",
        terminate_on_complete=terminate,
    )
    env, dynamics = CubeStackingEnv(**settings_), CubeStackingDynamics(**settings_)  # type: ignore[arg-type]
    assert isinstance(env, CubeStackingDynamics) and not isinstance(dynamics, gym.Env)
    actions = data.draw(st.lists(st.integers(0, stack_size), min_size=1, max_size=60))
    ours, theirs = env.reset(seed=3), dynamics.reset(seed=3)
    for action in actions:
        assert (ours[0] == theirs[0]).all() and ours[0].dtype == theirs[0].dtype
        assert ours[1].keys() == theirs[1].keys()
        for key in ours[1]:
            assert np.array_equal(ours[1][key], theirs[1][key])
        assert (env.action_mask() == dynamics.action_mask()).all()
        ours, theirs = env.step(action), dynamics.step(action)  # type: ignore[assignment]
        assert ours[1:4] == theirs[1:4] and type(ours[1]) is type(theirs[1])
        ours, theirs = (ours[0], ours[4]), (theirs[0], theirs[4])
        if env._steps >= 12 or env._stack == env._target and terminate:
            ours, theirs = env.reset(), dynamics.reset()
    dynamics.close()
    env.close()


def test_a_cube_run_imports_no_gymnasium() -> None:
    """``lagrseq run cube-stacking`` (its env is the dynamics alone) never imports gymnasium."""
    code = (
        "import sys, tempfile\n"
        "from lagrseq.cli import main\n"
        "with tempfile.TemporaryDirectory() as out:\n"
        "    assert main(['run', 'cube-stacking', '--trials', '1', '--quiet', '--set', 'run.episodes=2', '--out', out]) == 0\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('gymnasium', 'tqdm', 'torch')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout
