"""Exploration schedules: epsilon as a function of the episode index (0-based)."""

from __future__ import annotations

from dataclasses import dataclass

SCHEDULES = ("divide-cumulative", "linear", "exponential", "inverse-episode", "constant")


@dataclass(frozen=True)
class EpsilonSchedule:
    """epsilon per episode; ``values[i]`` is the epsilon of episode i.

    - ``divide-cumulative`` (released cube code): at the start of episode i,
      epsilon <- max(epsilon / (i + 1), minimum); gives 1, 0.5, 0.167, then the minimum.
    - ``linear``: from start to minimum over ``decay`` episodes (0: half the run), then minimum.
    - ``exponential``: start * decay**i, floored at minimum.
    - ``inverse-episode`` (released grid code): max(1 / (i + 1), minimum).
    - ``constant``: start for ever.
    """

    kind: str
    start: float
    minimum: float
    decay: float
    episodes: int

    def __post_init__(self) -> None:
        if self.kind not in SCHEDULES:
            raise ValueError(f"unknown epsilon schedule {self.kind!r}; expected one of {SCHEDULES}")

    def __call__(self, episode: int) -> float:
        kind, start, minimum = self.kind, self.start, self.minimum
        if kind == "constant":
            return start
        if kind == "inverse-episode":
            return max(1.0 / (episode + 1), minimum)
        if kind == "exponential":
            return max(start * self.decay**episode, minimum)
        if kind == "linear":
            length = self.decay if self.decay > 0 else max(self.episodes / 2, 1)
            return max(start + (minimum - start) * min(episode / length, 1.0), minimum)
        epsilon = start
        for i in range(episode + 1):
            epsilon = max(epsilon / (i + 1), minimum)
        return epsilon
