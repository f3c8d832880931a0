"""Gymnasium environments of the LaGR-SEQ tasks, registered under versioned ids.

========================================  =========================================
id                                        task
========================================  =========================================
``lagrseq/CubeStacking-v0``               8 cubes (``stack_size`` kwarg: 5, 8, 11)
``lagrseq/CubeStacking5-v0``              5 cubes
``lagrseq/CubeStacking11-v0``             11 cubes
``lagrseq/ImageCompletion-v0``            10 x 10 image, X target (``target`` kwarg)
``lagrseq/ObjectArrangement-v0``          5 x 5 table, diamond target (``target`` kwarg)
``lagrseq/ArmArrangement-v0``             the same, placed by a UR5e (``robot`` kwarg;
                                          the ``arm`` extra: pybullet, airo-models)
========================================  =========================================
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym

from lagrseq.envs.cube_stacking import CubeStackingEnv

if TYPE_CHECKING:
    from lagrseq.envs.image_completion import ImageCompletionEnv
    from lagrseq.envs.object_arrangement import ObjectArrangementEnv

CUBE_ENTRY = "lagrseq.envs.cube_stacking:CubeStackingEnv"
IMAGE_ENTRY = "lagrseq.envs.image_completion:ImageCompletionEnv"
ARRANGEMENT_ENTRY = "lagrseq.envs.object_arrangement:ObjectArrangementEnv"
ARM_ENTRY = "lagrseq.envs.arm_arrangement:ArmArrangementEnv"

REGISTERED: dict[str, dict[str, object]] = {
    "lagrseq/CubeStacking-v0": {"entry_point": CUBE_ENTRY, "kwargs": {"stack_size": 8}},
    "lagrseq/CubeStacking5-v0": {"entry_point": CUBE_ENTRY, "kwargs": {"stack_size": 5}},
    "lagrseq/CubeStacking11-v0": {"entry_point": CUBE_ENTRY, "kwargs": {"stack_size": 11}},
    "lagrseq/ImageCompletion-v0": {"entry_point": IMAGE_ENTRY, "kwargs": {"target": "x"}},
    "lagrseq/ObjectArrangement-v0": {"entry_point": ARRANGEMENT_ENTRY, "kwargs": {"target": "diamond"}},
    "lagrseq/ArmArrangement-v0": {"entry_point": ARM_ENTRY, "kwargs": {"target": "diamond", "robot": "sim"}},
}


def register_all() -> None:
    """Register every lagrseq environment with gymnasium (idempotent)."""
    for env_id, spec in REGISTERED.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, **spec)  # type: ignore[arg-type]


register_all()

_LAZY = {"ImageCompletionEnv": "image_completion", "ObjectArrangementEnv": "object_arrangement"}
"""The grid envs, imported when first named (a cube run imports this package, never them)."""


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = [
    "CubeStackingEnv",
    "ImageCompletionEnv",
    "ObjectArrangementEnv",
    "REGISTERED",
    "register_all",
]
