"""The ``[task]`` and ``[env]`` sections of ``number-sequence`` (read by ``lagrseq.config``: every
field typed, unknown fields refused, the attribute docstrings shown by ``lagrseq config``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from lagrseq.errors import ConfigError


@dataclass(frozen=True)
class NumSeqTaskConfig:
    """[task] the arithmetic sequence to write: start, start + step, ..., ``length`` numbers."""

    name: Literal["number-sequence"] = "number-sequence"
    """The task's name (``lagrseq run number-sequence``)."""
    start: int = 2
    """First number of the target sequence."""
    step: int = 3
    """Difference between consecutive numbers."""
    length: int = 6
    """Numbers in the target sequence."""
    values: int = 20
    """The agent writes one of 0 .. values - 1 at each step (its actions)."""

    def __post_init__(self) -> None:
        if not 2 <= self.length <= 50:
            raise ConfigError(f"task.length = {self.length}; expected 2 to 50")
        if not 2 <= self.values <= 1000:
            raise ConfigError(f"task.values = {self.values}; expected 2 to 1000")
        last = self.start + self.step * (self.length - 1)
        if not (0 <= self.start < self.values and 0 <= last < self.values):
            raise ConfigError(f"the sequence {self.start}, {self.start + self.step}, ... {last} leaves 0 .. {self.values - 1}; change task.start, task.step or task.values")


@dataclass(frozen=True)
class NumSeqEnvConfig:
    """[env] the episode."""

    horizon: int = 40
    """Steps per episode."""
    bonus: float = 1.0
    """Reward for completing the sequence (the episode then ends)."""

    def __post_init__(self) -> None:
        if not 1 <= self.horizon <= 100_000:
            raise ConfigError(f"env.horizon = {self.horizon}; expected 1 to 100000")
