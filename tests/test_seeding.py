"""seeding.py: a trial's streams depend only on (seed, trial, stream, part)."""

from __future__ import annotations

import numpy as np

from lagrseq import seeding
from lagrseq.seeding import Stream


def draws(seed: int, trial: int, stream: Stream, part: int | None = None) -> list[float]:
    return seeding.generator(seed, trial, stream, part).random(5).tolist()


def test_the_same_key_gives_the_same_stream() -> None:
    assert draws(7, 3, Stream.PRIMARY) == draws(7, 3, Stream.PRIMARY)
    assert seeding.integer_seed(7, 3, Stream.ENV) == seeding.integer_seed(7, 3, Stream.ENV)


def test_every_component_of_the_key_changes_the_stream() -> None:
    base = draws(7, 3, Stream.PRIMARY)
    assert draws(8, 3, Stream.PRIMARY) != base
    assert draws(7, 4, Stream.PRIMARY) != base
    assert draws(7, 3, Stream.SECONDARY) != base
    assert draws(7, 3, Stream.TORCH, 0) != draws(7, 3, Stream.TORCH, 1)
    streams = {tuple(draws(0, 0, s)) for s in Stream}
    assert len(streams) == len(Stream)


def test_a_trials_streams_do_not_depend_on_how_many_trials_run() -> None:
    # trial 3 is spawned from (seed, 3) directly, never from a counter of trials before it
    assert draws(0, 3, Stream.LLM) == seeding.generator(0, 3, Stream.LLM).random(5).tolist()
    sequence = seeding.generator(0, 3, Stream.LLM).bit_generator.seed_seq
    assert sequence.spawn_key == (3, int(Stream.LLM)) and sequence.entropy == 0


def test_integer_seeds_are_32_bit_and_spread() -> None:
    seeds = {seeding.integer_seed(0, t, Stream.ENV) for t in range(1000)}
    assert len(seeds) == 1000 and all(0 <= s < 2**32 for s in seeds)


def test_generators_are_pcg64_from_a_seed_sequence() -> None:
    rng = seeding.generator(1, 2, Stream.GUIDANCE)
    assert isinstance(rng.bit_generator, np.random.PCG64)
    expected = np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy=1, spawn_key=(2, int(Stream.GUIDANCE)))))
    assert rng.random(3).tolist() == expected.random(3).tolist()
