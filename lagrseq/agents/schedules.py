"""Exploration schedules: epsilon as a function of the episode or of the environment step."""

from __future__ import annotations

from dataclasses import dataclass, field

SCHEDULES = ("divide-cumulative", "linear", "exponential", "inverse-episode", "constant")
UNITS = ("episode", "step")


@dataclass(frozen=True)
class EpsilonSchedule:
    """epsilon over a trial; ``schedule(i)`` is the epsilon of index i (0-based) in ``unit``.

    - ``divide-cumulative`` (released cube code): at the start of episode i,
      epsilon <- max(epsilon / (i + 1), minimum); gives 1, 0.5, 0.167, then the minimum.
    - ``linear``: from start to minimum over ``decay`` units (0: half of ``episodes``), then minimum.
    - ``exponential``: start * decay**i, floored at minimum (paper, grids: 0.998 per step).
    - ``inverse-episode`` (released grid code): max(1 / (i + 1), minimum).
    - ``constant``: start for ever.

    ``unit`` is what i counts: episodes (cube stacking) or environment steps (the grid tasks' DQN).
    ``episodes`` is the length of the run in that unit (used by ``linear``'s default length).
    During the first ``warmup`` steps of a trial epsilon stays at ``start`` and the index of a
    step-unit schedule counts from the end of the warm-up: the released grid code sets epsilon
    only inside its replay step, which does nothing until the buffer holds a batch.
    """

    kind: str
    start: float
    minimum: float
    decay: float
    episodes: int
    unit: str = "episode"
    warmup: int = 0
    _last: list[tuple[int, float]] = field(
        default_factory=lambda: [(-1, 0.0)], init=False, repr=False, compare=False, hash=False
    )
    """The last episode asked for by :meth:`at` and its epsilon: a per-episode schedule changes
    once per episode, and the loop asks at every step."""

    def __post_init__(self) -> None:
        if self.kind not in SCHEDULES:
            raise ValueError(f"unknown epsilon schedule {self.kind!r}; expected one of {SCHEDULES}")
        if self.unit not in UNITS:
            raise ValueError(f"unknown epsilon unit {self.unit!r}; expected one of {UNITS}")

    def at(self, episode: int, step: int) -> float:
        """epsilon at global step ``step`` (0-based), which belongs to episode ``episode``."""
        if step < self.warmup:
            return self.start
        if self.unit != "episode":
            return self(step - self.warmup)
        last_episode, epsilon = self._last[0]
        if last_episode != episode:
            epsilon = self(episode)
            self._last[0] = (episode, epsilon)  # one assignment: a reader never sees half of it
        return epsilon

    def steady_from(self, step: int) -> bool:
        """Whether :meth:`at` gives one epsilon for the rest of an episode that begins at global
        step ``step``: a per-episode schedule past its warm-up (the loop then asks once)."""
        return self.unit == "episode" and step >= self.warmup

    def __call__(self, index: int) -> float:
        kind, start, minimum = self.kind, self.start, self.minimum
        if kind == "constant":
            return start
        if kind == "inverse-episode":
            return max(1.0 / (index + 1), minimum)
        if kind == "exponential":
            return max(start * self.decay**index, minimum)
        if kind == "linear":
            length = self.decay if self.decay > 0 else max(self.episodes / 2, 1)
            return max(start + (minimum - start) * min(index / length, 1.0), minimum)
        epsilon = start
        for i in range(index + 1):
            epsilon = max(epsilon / (i + 1), minimum)
            if epsilon == minimum:  # it only ever shrinks: no need to run through every index
                break
        return epsilon
