"""Seeding: every random draw comes from a ``numpy.random.Generator`` derived from the run seed.

A trial's generators depend only on (run seed, trial index, component), never on how many trials
run or in which process, so trial 3 of a 10-trial run equals trial 3 of a 4-trial run.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class Stream(IntEnum):
    """The independent random streams of one trial."""

    ENV = 0
    PRIMARY = 1
    SECONDARY = 2
    GUIDANCE = 3
    LLM = 4
    TORCH = 5
    REPLAY = 6


def _key(trial: int, stream: Stream, part: int | None) -> tuple[int, ...]:
    return (trial, int(stream)) if part is None else (trial, int(stream), part)


def generator(seed: int, trial: int, stream: Stream, part: int | None = None) -> np.random.Generator:
    """The generator of one component (``stream``) of one trial; ``part`` tells apart several
    consumers of one stream (the primary and the secondary network)."""
    sequence = np.random.SeedSequence(entropy=seed, spawn_key=_key(trial, stream, part))
    return np.random.Generator(np.random.PCG64(sequence))


def integer_seed(seed: int, trial: int, stream: Stream, part: int | None = None) -> int:
    """A 32-bit integer seed for libraries that want one (gymnasium reset, torch)."""
    sequence = np.random.SeedSequence(entropy=seed, spawn_key=_key(trial, stream, part))
    return int(sequence.generate_state(1, dtype=np.uint32)[0])
