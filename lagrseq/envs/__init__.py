"""Gymnasium environments of the LaGR-SEQ tasks, registered under versioned ids.

========================================  =========================================
id                                        task
========================================  =========================================
``lagrseq/CubeStacking-v0``               8 cubes (``stack_size`` kwarg: 5, 8, 11)
``lagrseq/CubeStacking5-v0``              5 cubes
``lagrseq/CubeStacking11-v0``             11 cubes
========================================  =========================================
"""

from __future__ import annotations

import gymnasium as gym

from lagrseq.envs.cube_stacking import CubeStackingEnv

CUBE_ENTRY = "lagrseq.envs.cube_stacking:CubeStackingEnv"

REGISTERED: dict[str, dict[str, object]] = {
    "lagrseq/CubeStacking-v0": {"entry_point": CUBE_ENTRY, "kwargs": {"stack_size": 8}},
    "lagrseq/CubeStacking5-v0": {"entry_point": CUBE_ENTRY, "kwargs": {"stack_size": 5}},
    "lagrseq/CubeStacking11-v0": {"entry_point": CUBE_ENTRY, "kwargs": {"stack_size": 11}},
}


def register_all() -> None:
    """Register every lagrseq environment with gymnasium (idempotent)."""
    for env_id, spec in REGISTERED.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, **spec)  # type: ignore[arg-type]


register_all()

__all__ = ["CubeStackingEnv", "REGISTERED", "register_all"]
