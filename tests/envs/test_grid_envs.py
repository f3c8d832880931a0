"""Grid environments: gymnasium's checker, and rewards worked out by hand from SPEC 2.1 and 3.1."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import lagrseq.envs  # noqa: F401  (registers the environments)
from lagrseq.envs import ImageCompletionEnv, ObjectArrangementEnv
from lagrseq.tasks import shapes

X = shapes.target("x", 10)
DIAMOND = shapes.target("diamond", 5)


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("lagrseq/ImageCompletion-v0", {}),
        ("lagrseq/ImageCompletion-v0", {"goal_ends": "scan", "goal_threshold": 1.0, "target": "oval"}),
        ("lagrseq/ObjectArrangement-v0", {}),
        ("lagrseq/ObjectArrangement-v0", {"target": "square", "horizon": 10}),
    ],
)
def test_check_env(env_id: str, kwargs: dict) -> None:
    env = gym.make(env_id, render_mode="ansi", **kwargs)
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


# ------------------------------------------------------------------------------------------
# Image completion (SPEC 2.1)
# ------------------------------------------------------------------------------------------
def test_image_rewards_by_hand() -> None:
    env = ImageCompletionEnv(goal_threshold=1.0, goal_ends="scan")
    obs, info = env.reset(seed=0)
    assert obs.shape == (103,) and info["cursor"] == (0, 0) and info["evaluation"] == 0.8
    _, reward, terminated, truncated, info = env.step(1)  # (0, 0) is in the X: +1/100
    assert reward == pytest.approx(0.01) and not (terminated or truncated)
    assert info["pattern"][0, 0] == 1 and info["cursor"] == (0, 1)
    _, reward, *_, info = env.step(1)  # (0, 1) is black in the target: blocked, 0, undone
    assert reward == 0.0 and info["pattern"][0, 1] == 0
    env.reset()
    env.step(1)
    for _ in range(99):
        env.step(0)
    _, reward, *_, info = env.step(1)  # second scan: turning (0, 0) off again is allowed
    assert reward == pytest.approx(-0.01) and info["pattern"][0, 0] == 0


def test_free_flips_cost_a_hundredth() -> None:
    env = ImageCompletionEnv(block_wrong_flips=False)
    env.reset(seed=0)
    env.step(0)
    _, reward, *_, info = env.step(1)
    assert reward == pytest.approx(-0.01) and info["pattern"][0, 1] == 1


def test_released_scan_rule_pays_the_bonus_once_per_scan() -> None:
    """The perfect policy of the released code: 100 steps to the X (+0.20 and the bonus at the last
    pixel), then each of the 4 remaining scans starts on the complete image: +1 at once (5.2)."""
    env = ImageCompletionEnv(goal_threshold=1.0, goal_ends="scan", scans=5)
    _, info = env.reset(seed=0)
    rewards = []
    while True:
        row, col = info["cursor"]
        action = int(X[row, col] == 1 and info["pattern"][row, col] == 0)
        _, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        assert not terminated
        if truncated:
            break
    assert len(rewards) == 104
    assert sum(rewards) == pytest.approx(5.2)
    assert rewards[99] == pytest.approx(1.01) and rewards[100:] == [1.0] * 4


def test_paper_goal_ends_the_episode_at_96_matching_pixels() -> None:
    env = ImageCompletionEnv(goal_threshold=0.96, goal_ends="episode")
    _, info = env.reset(seed=0)
    on = 0
    while True:
        row, col = info["cursor"]
        _, reward, terminated, truncated, info = env.step(int(X[row, col] == 1))
        on += reward > 0
        if terminated or truncated:
            break
    assert terminated and on == 16 and info["evaluation"] == 0.96
    assert reward == pytest.approx(1.01)


def test_image_truncates_after_the_scans() -> None:
    env = ImageCompletionEnv(scans=2)
    env.reset(seed=0)
    for step in range(200):
        *_, terminated, truncated, _ = env.step(0)
        assert not terminated and truncated == (step == 199)


def test_cell_actions_use_the_guided_goal_threshold() -> None:
    """Released code: pi_LLM's steps earn the bonus at E > 0.95, the primary's only at E = 1."""
    image = ImageCompletionEnv(goal_threshold=1.0, goal_ends="scan", guided_goal_threshold=0.96)
    image.reset(seed=0)
    cells = list(zip(*np.nonzero(X), strict=True))
    rewards = [image.step(image.cell_action(cell, 1))[1] for cell in cells[:16]]
    assert rewards[:15] == pytest.approx([0.01] * 15) and rewards[15] == pytest.approx(1.01)
    _, reward, *_ = image.step(0)  # the primary's step on the same 96-pixel image: no bonus
    assert reward == 0.0
    _, reward, *_ = image.step(image.cell_action(image.unwrapped._cursor, 0))  # pi_LLM with nothing left to place: the bonus again
    assert reward == 1.0


def test_a_cell_action_acts_elsewhere_without_moving_the_scan() -> None:
    env = ImageCompletionEnv()
    obs, info = env.reset(seed=0)
    seen, seen_info = env.at_cell(obs, info, (9, 9))
    assert seen_info["cursor"] == (9, 9) and seen[0] == 9 and seen[1] == 9 and info["cursor"] == (0, 0)
    assert env.action_space.n == 202 and env.agent_action_space.n == 2
    _, reward, *_, info = env.step(env.cell_action((9, 9), 1))
    assert info["pattern"][9, 9] == 1 and reward == pytest.approx(0.01)
    assert info["cursor"] == (0, 1)  # the scan goes on from where it was
    with pytest.raises(ValueError, match="on cell"):
        env.cell_action((10, 0), 1)
    with pytest.raises(ValueError, match="outside Discrete"):
        env.step(202)


# ------------------------------------------------------------------------------------------
# Object arrangement (SPEC 3.1)
# ------------------------------------------------------------------------------------------
def place(env: ObjectArrangementEnv, cell: tuple[int, int], action: int = 1) -> tuple[float, bool, bool, dict]:
    _, reward, terminated, truncated, info = env.step(env.cell_action(cell, action))
    return reward, terminated, truncated, info


def test_arrangement_rewards_by_hand() -> None:
    env = ObjectArrangementEnv()
    _, info = env.reset(seed=1)
    assert info["evaluation"] == 17 / 25
    reward, *_, info = place(env, (0, 2))
    assert reward == pytest.approx(0.04) and info["pattern"][0, 2] == 1
    reward, *_, info = place(env, (0, 2))  # occupied: nothing happens
    assert reward == 0.0
    reward, *_, info = place(env, (0, 0))  # outside the diamond: not executed, 0
    assert reward == 0.0 and info["pattern"][0, 0] == 0
    reward, *_ = place(env, (1, 1), action=0)
    assert reward == 0.0
    cells = list(zip(*np.nonzero(DIAMOND), strict=True))
    rewards = [place(env, cell) for cell in cells if cell != (0, 2)]
    assert [r for r, *_ in rewards[:-1]] == pytest.approx([0.04] * 6)
    last_reward, terminated, truncated, info = rewards[-1]
    assert last_reward == pytest.approx(1.04) and terminated and not truncated
    assert np.array_equal(info["pattern"], DIAMOND)


def test_best_arrangement_episode_returns_1_32() -> None:
    env = ObjectArrangementEnv()
    env.reset(seed=0)
    total = sum(place(env, cell)[0] for cell in zip(*np.nonzero(DIAMOND), strict=True))
    assert total == pytest.approx(1.32)


def test_arrangement_draws_cells_from_its_seed_and_truncates() -> None:
    def cursors(seed: int) -> list[tuple[int, int]]:
        env = ObjectArrangementEnv(horizon=20)
        _, info = env.reset(seed=seed)
        seen = [info["cursor"]]
        for step in range(20):
            *_, terminated, truncated, info = env.step(0)
            assert not terminated and truncated == (step == 19)
            seen.append(info["cursor"])
        return seen

    assert cursors(3) == cursors(3)
    assert cursors(3) != cursors(4)
    assert len(set(cursors(3))) > 5
