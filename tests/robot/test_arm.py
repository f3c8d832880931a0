"""The simulated UR5e (pybullet DIRECT), its env, its gRPC service and its pictures (the arm extra).

One robot is built per module (about 3 s: the scene and every cell's IK) and shared; each test
starts from ``clear()``, which the determinism test shows to be as good as a fresh robot.
"""

from __future__ import annotations

import dataclasses
import io
import math
import socket

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("airo_models")

from lagrseq.robot import OUTCOMES, RobotError  # noqa: E402
from lagrseq.robot.sim import SimRobot  # noqa: E402

pytestmark = pytest.mark.arm

DIAMOND = [(0, 2), (1, 1), (1, 3), (2, 0), (2, 4), (3, 1), (3, 3), (4, 2)]


@pytest.fixture(scope="module")
def robot():
    sim = SimRobot()
    yield sim
    sim.close()


@pytest.fixture
def fresh(robot):
    robot.clear()
    settings = robot.settings
    yield robot
    robot.settings = settings
    robot.on_frame = None


def test_ik_reaches_every_cell_within_a_millimetre(fresh) -> None:
    errors = fresh.reach_errors()
    assert len(errors) == 25
    assert max(errors.values()) < 1e-3  # every waypoint of every descent, hover to release
    # and the tool really is there: forward kinematics of the release pose of each cell
    for (row, col), (path, _) in fresh._plans.items():
        fresh._set_joints(path[-1])
        tool = fresh._tool_pose()
        centre = fresh.workspace.cell_in_world(row, col)
        release, _ = fresh._heights()
        assert np.linalg.norm(tool[:2] - centre[:2]) < 1e-3
        assert abs(tool[2] - (centre[2] + release)) < 1e-3
    fresh.clear()


def test_a_placement_lands_inside_its_cell(fresh) -> None:
    result = fresh.place(2, 3)
    assert result.ok and result.outcome == "placed"
    assert (result.landed_row, result.landed_col) == (2, 3)
    assert result.offset_mm < 1.0 and result.tilt_deg < 1.0
    assert result.height_mm == pytest.approx(fresh.settings.cube_size * 500, abs=1.0)
    assert 60 <= result.sim_steps <= 200  # the descent and release are simulated, nothing more
    expected = np.zeros((5, 5), dtype=np.int8)
    expected[2, 3] = 1
    np.testing.assert_array_equal(fresh.observe(), expected)


def test_the_whole_diamond_with_neighbours_present(fresh) -> None:
    results = [fresh.place(*cell) for cell in DIAMOND]
    assert all(r.ok for r in results), [r for r in results if not r.ok]
    grid = fresh.observe()
    assert sorted(zip(*np.nonzero(grid))) == sorted(DIAMOND)


def test_occupancy_is_read_from_physics(fresh) -> None:
    fresh.place(1, 1)
    assert fresh.observe()[1, 1] == 1
    (cube,) = fresh.cubes
    p = fresh.p
    # slide the cube by hand to the centre of cell (3, 4)
    target = fresh.workspace.cell_in_world(3, 4)
    height = fresh.settings.cube_size / 2
    p.resetBasePositionAndOrientation(cube, (target[0], target[1], target[2] + height), (0, 0, 0, 1), physicsClientId=fresh.client)
    grid = fresh.observe()
    assert grid[1, 1] == 0 and grid[3, 4] == 1 and grid.sum() == 1
    # off the grid: nothing
    p.resetBasePositionAndOrientation(cube, (0.3, 0.4, target[2] + height), (0, 0, 0, 1), physicsClientId=fresh.client)
    assert fresh.observe().sum() == 0
    # tilted on an edge over a cell: not resting flat, not counted
    tilted = p.getQuaternionFromEuler((math.radians(40), 0, 0))
    p.resetBasePositionAndOrientation(cube, (target[0], target[1], target[2] + 0.021), tilted, physicsClientId=fresh.client)
    assert fresh.observe().sum() == 0


def test_failed_placements_are_reported(fresh) -> None:
    assert fresh.place(2, 2).ok
    on_top = fresh.place(2, 2)  # the cell is taken: the cube ends up on the other one
    assert not on_top.ok and on_top.outcome == "not-resting" and on_top.height_mm > 20
    fresh.clear()
    fresh.settings = dataclasses.replace(fresh.settings, max_offset=0.0)  # no tolerance at all
    strict = fresh.place(0, 0)
    assert strict.outcome == "outside-cell" and not strict.ok and strict.offset_mm > 0
    assert set(OUTCOMES) >= {on_top.outcome, strict.outcome}


def test_an_unreachable_cell_is_reported_not_raised() -> None:
    from lagrseq.robot.frames import StaticTransform, Workspace

    far = Workspace(table_in_base=StaticTransform("base_link", "table", (1.5, -0.125, 0.0)))
    sim = SimRobot(workspace=far)
    try:
        result = sim.place(0, 0)
        assert result.outcome == "unreachable" and not result.ok and sim.cubes == []
        assert sim.observe().sum() == 0
        with pytest.raises(RobotError, match="outside the 5x5 grid"):
            sim.place(5, 0)
    finally:
        sim.close()


def test_clear_is_as_good_as_a_fresh_robot(fresh) -> None:
    for cell in [(4, 4), (2, 2), (2, 2), (0, 1)]:
        fresh.place(*cell)
    fresh.clear()
    assert fresh.cubes == [] and fresh.observe().sum() == 0
    again = [fresh.place(*cell) for cell in DIAMOND[:4]]
    other = SimRobot()
    try:
        assert [other.place(*cell) for cell in DIAMOND[:4]] == again
    finally:
        other.close()


def test_a_rendered_frame_is_a_picture(fresh) -> None:
    fresh.place(0, 2)
    rgb = fresh.render(80, 60)
    assert rgb.shape == (60, 80, 3) and rgb.dtype == np.uint8
    assert rgb.std() > 10 and len(np.unique(rgb.reshape(-1, 3), axis=0)) > 20  # not a blank frame


# ------------------------------------------------------------------------------------------
# The env
# ------------------------------------------------------------------------------------------
class _Shared:
    """The module's robot, not closed by an env that borrows it."""

    def __init__(self, robot: SimRobot) -> None:
        self.robot = robot
        self.rows, self.cols = robot.rows, robot.cols

    def __getattr__(self, name: str):
        return getattr(self.robot, name)

    def close(self) -> None:
        return None


def test_check_env(fresh) -> None:
    from gymnasium.utils.env_checker import check_env

    from lagrseq.envs.arm_arrangement import ArmArrangementEnv

    env = ArmArrangementEnv(robot=_Shared(fresh), render_mode="rgb_array", render_size=(64, 48))
    check_env(env, skip_render_check=False)
    env.close()


def test_the_env_reports_a_failed_placement(fresh) -> None:
    from lagrseq.envs.arm_arrangement import ArmArrangementEnv

    env = ArmArrangementEnv(robot=_Shared(fresh))
    env.reset(seed=0)
    assert env.unwrapped.robot.cubes == []
    _, reward, _, _, info = env.step(env.cell_action((0, 2), 1))
    assert info["placement"]["ok"] and info["placement"]["outcome"] == "placed" and reward == pytest.approx(0.04)
    assert info["pattern"][0, 2] == 1
    fresh.settings = dataclasses.replace(fresh.settings, max_offset=0.0)
    _, _, _, _, info = env.step(env.cell_action((1, 1), 1))
    assert info["placement"] == {**info["placement"], "row": 1, "col": 1, "ok": False, "outcome": "outside-cell"}
    _, reward, _, _, info = env.step(env.cell_action((4, 4), 1))  # not in the target: nothing is placed
    assert info["placement"] is None and reward == 0.0
    env.reset()
    assert env.unwrapped.robot.cubes == [] and info["pattern"].sum() >= 1


# ------------------------------------------------------------------------------------------
# The robot service (gRPC on 127.0.0.1)
# ------------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_service_round_trips_every_call(fresh) -> None:
    pytest.importorskip("grpc")
    from lagrseq.robot.remote import RemoteRobot, start_server

    server, port = start_server(fresh, "127.0.0.1", 0, "test robot")
    remote = RemoteRobot("127.0.0.1", port, timeout_s=30)
    try:
        assert (remote.rows, remote.cols) == (5, 5) and remote.description == "test robot"
        assert remote.joint_names == fresh.joint_state().names and len(remote.joint_names) == 6
        placed = remote.place(3, 1)
        assert placed.ok and (placed.landed_row, placed.landed_col) == (3, 1)
        np.testing.assert_array_equal(remote.observe(), fresh.observe())
        assert remote.joint_state() == fresh.joint_state()
        picture = remote.render(64, 48)
        assert picture is not None and picture.shape == (48, 64, 3) and picture.std() > 10
        remote.clear()
        assert fresh.cubes == [] and remote.observe().sum() == 0
        with pytest.raises(RobotError, match="INVALID_ARGUMENT"):
            remote.place(7, 0)
        with pytest.raises(RobotError, match="INVALID_ARGUMENT"):
            remote.render(4, 4)
        server.stop(grace=None).wait()
        with pytest.raises(RobotError, match="unavailable") as stopped:
            remote.place(0, 0)
        assert "\n" not in str(stopped.value)
    finally:
        remote.close()
        server.stop(grace=None)


def test_a_dead_server_is_one_clear_error() -> None:
    pytest.importorskip("grpc")
    from lagrseq.robot.remote import RemoteRobot

    port = _free_port()
    with pytest.raises(RobotError, match=f"no robot service answers at 127.0.0.1:{port}") as error:
        RemoteRobot("127.0.0.1", port, timeout_s=1.0)
    assert "\n" not in str(error.value) and "lagrseq robot serve --sim" in str(error.value)


def test_the_command_line_says_so_and_exits_2(tmp_path, capsys) -> None:
    pytest.importorskip("grpc")
    pytest.importorskip("torch")
    from lagrseq.cli import main

    port = _free_port()
    status = main(["run", "arm-arrangement", "--trials", "1", "--out", str(tmp_path), "--quiet",
                   "--set", f'env.robot="remote:127.0.0.1:{port}"', "--set", "env.robot_timeout_s=1"])
    err = capsys.readouterr().err.strip()
    assert status == 2 and err.count("\n") == 0 and "no robot service answers" in err
    assert not list(tmp_path.rglob("*.mcap"))


def test_png_from_a_server_is_checked() -> None:
    from lagrseq.robot.remote import _decode_png

    with pytest.raises(RobotError, match="expected a PNG of that size"):
        _decode_png(b"not a png", 64, 48, "x:1")
    from PIL import Image

    buffer = io.BytesIO()
    Image.new("RGB", (10, 10)).save(buffer, format="PNG")
    with pytest.raises(RobotError, match="expected a PNG of that size"):
        _decode_png(buffer.getvalue(), 64, 48, "x:1")


# ------------------------------------------------------------------------------------------
# Whole runs: the MCAP log, --render, and the same events in process and behind the service
# ------------------------------------------------------------------------------------------
def _run(tmp_path, *extra: str) -> list:
    from lagrseq.cli import main
    from lagrseq.logs.reader import find_logs

    args = ["run", "arm-arrangement", "--method", "lagr-seq", "--preset", "paper", "--trials", "1",
            "--seed", "0", "--quiet", "--set", "run.max_steps=24", "--set", "env.view_every=8",
            "--set", "env.view_width=64", *extra]
    assert main(args) == 0
    return find_logs([tmp_path])


def test_a_run_logs_placements_camera_frames_and_joints(tmp_path) -> None:
    pytest.importorskip("torch")
    from PIL import Image

    from lagrseq.logs.reader import read_info, read_topic

    out, frames = tmp_path / "runs", tmp_path / "frames"
    (log,) = _run(out, "--out", str(out), "--render", str(frames))
    placed = [t["placement"] for t in read_topic(log, "/transition") if "placement" in t]
    assert placed and all(p["outcome"] in OUTCOMES for p in placed)
    episodes = read_topic(log, "/episode")
    assert sum(e["placements"] for e in episodes) == len(placed)
    assert sum(e["failed_placements"] for e in episodes) == sum(not p["ok"] for p in placed)
    cameras = read_topic(log, "/view/arm")
    assert [c["timestamp"]["nsec"] for c in cameras] == [0, 8, 16]
    import base64

    with Image.open(io.BytesIO(base64.b64decode(cameras[0]["data"]))) as picture:
        assert picture.format == "PNG" and picture.size == (64, 48)
    joints = read_topic(log, "/view/arm/joints")
    assert len(joints) == 24 and len(joints[0]["name"]) == 6
    assert read_info(log).config["env"]["robot"] == "sim"
    # --render: PNG frames of every placement's key poses and a GIF per episode
    pngs, gifs = sorted(frames.rglob("*.png")), sorted(frames.rglob("*.gif"))
    assert len(pngs) >= 4 * len(placed) and gifs
    with Image.open(gifs[0]) as gif:
        assert gif.format == "GIF" and gif.n_frames > 1
    # replay's GIF, from the log alone (frames every 8 steps: the trial's last frames)
    from lagrseq.analysis.arm_gif import episode_gif

    shown = episode_gif(log, tmp_path / "replay.gif")
    assert shown is not None and "3 frames" in shown
    with Image.open(tmp_path / "replay.gif") as gif:
        assert gif.n_frames == 3 and gif.size == (64, 48)


def test_the_same_run_behind_the_service_logs_the_same_events(tmp_path) -> None:
    pytest.importorskip("torch")
    pytest.importorskip("grpc")
    from lagrseq.logs.reader import read_topic
    from lagrseq.robot.remote import start_server

    (local,) = _run(tmp_path / "local", "--out", str(tmp_path / "local"))
    served = SimRobot()
    server, port = start_server(served, "127.0.0.1", 0)
    try:
        (remote,) = _run(tmp_path / "remote", "--out", str(tmp_path / "remote"), "--set", f'env.robot="remote:127.0.0.1:{port}"')
    finally:
        server.stop(grace=None)
        served.close()
    for topic in ("/transition", "/query", "/episode"):
        assert read_topic(local, topic) == read_topic(remote, topic), topic
    assert any("placement" in t for t in read_topic(remote, "/transition"))
