"""The arm task's parts that need no extra: configuration, transforms, and what runs without it."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from lagrseq.robot.frames import StaticTransform, Workspace


@pytest.mark.parametrize("preset", cfg.PRESETS)
def test_the_presets_load(preset: str) -> None:
    config = cfg.load("arm-arrangement", "lagr-seq", preset)
    assert config.env.robot == "sim" and config.run.max_steps == 200  # type: ignore[union-attr]
    remote = cfg.load("arm-arrangement", "lagr", preset, overrides=['env.robot="remote:10.0.0.7:50051"'])
    assert remote.env.robot == "remote:10.0.0.7:50051"  # type: ignore[union-attr]
    assert remote.digest() != config.digest()


@pytest.mark.parametrize("bad", ["simulator", "remote:", "remote:host", "remote:host:0", "remote:host:70000", "remote::50051", "remote:a b:1"])
def test_a_bad_robot_is_one_line_naming_the_field(bad: str) -> None:
    with pytest.raises(ConfigError, match=r'env.robot = .*; expected "sim", "remote:HOST:PORT" or "remote\+tls:HOST:PORT"') as error:
        cfg.load("arm-arrangement", "lagr-seq", "paper", overrides=[f"env.robot={bad!r}".replace("'", '"')])
    assert "\n" not in str(error.value)


def _without(monkeypatch: pytest.MonkeyPatch, *absent: str) -> None:
    real = importlib.util.find_spec

    def find_spec(name: str, *args, **kwargs):  # type: ignore[no-untyped-def]
        return None if name.split(".")[0] in absent else real(name, *args, **kwargs)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)


def test_without_the_arm_extra_runs_say_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    from lagrseq.running.wiring import missing_dependency

    config = cfg.load("arm-arrangement", "lagr-seq", "paper")
    _without(monkeypatch, "pybullet")
    assert "needs the arm extra" in missing_dependency(config) and "lagrseq[arm]" in missing_dependency(config)
    remote = cfg.load("arm-arrangement", "lagr-seq", "paper", overrides=['env.robot="remote:127.0.0.1:5"'])
    assert "pybullet" not in missing_dependency(remote)  # the client needs grpc only
    _without(monkeypatch, "pybullet", "grpc")
    assert "grpc" in missing_dependency(remote)


def test_reproduce_sets_the_arm_items_aside_without_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from lagrseq.study import reproduce
    from lagrseq.suite import load_suite

    _without(monkeypatch, "pybullet", "airo_models")
    suite = load_suite().select(["fig5c-arm", "fig6c-arm"])
    plan = reproduce.plan(suite, quick=True, provider=None, runs_dir=tmp_path, seed=0)
    assert plan.runs == []
    for item in ("fig5c-arm", "fig6c-arm"):
        assert "needs the arm extra" in plan.not_run[item]


def test_every_cell_goes_through_the_static_transforms_and_back() -> None:
    ws = Workspace()
    for row in range(5):
        for col in range(5):
            centre = ws.cell_in_base(row, col)
            # ARM_NOTES: cell (i, j) centre at (0.40 + 0.05 i, -0.10 + 0.05 j) in the base frame
            np.testing.assert_allclose(centre[:2], (0.40 + 0.05 * row, -0.10 + 0.05 * col), atol=1e-12)
            world = ws.cell_in_world(row, col)
            assert world[2] == pytest.approx(0.625)
            assert ws.cell_of_world(world) == (row, col)
            assert ws.cell_of_world(world + (0.024, -0.024, 0)) == (row, col)
            np.testing.assert_allclose(ws.offset_in_cell(world + (0.003, 0.001, 0), row, col), (0.003, 0.001), atol=1e-12)
    assert ws.cell_of_world((0.0, 0.0, 0.625)) is None and ws.cell_of_world((0.9, 0.0, 0.625)) is None


@given(
    st.tuples(*[st.floats(-2, 2)] * 3),
    st.tuples(*[st.floats(-2, 2)] * 3),
    st.floats(-math.pi, math.pi),
)
def test_a_static_transform_inverts(point, translation, yaw) -> None:  # type: ignore[no-untyped-def]
    transform = StaticTransform("a", "b", translation, yaw)
    np.testing.assert_allclose(transform.invert(transform.apply(point)), point, atol=1e-9)
    # distances are kept: a rigid motion
    origin = transform.apply((0.0, 0.0, 0.0))
    assert np.linalg.norm(transform.apply(point) - origin) == pytest.approx(np.linalg.norm(point), abs=1e-9)


def test_making_the_env_without_pybullet_is_one_usage_error(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    from lagrseq.errors import UsageError
    from lagrseq.running.wiring import make_env

    monkeypatch.setitem(sys.modules, "pybullet", None)  # import pybullet -> ImportError
    with pytest.raises(UsageError, match=r"arm-arrangement: .*pip install 'lagrseq\[arm\]'") as error:
        make_env(cfg.load("arm-arrangement", "lagr-seq", "paper"))
    assert "\n" not in str(error.value)
