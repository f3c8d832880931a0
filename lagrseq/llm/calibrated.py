"""The calibrated miss answer of a recorded store (``--on-miss calibrated``, a suite run's
``on_miss = "calibrated"``).

A query the store lacks is answered by one draw, fixed per distinct prompt: accepted (the task's
right answer, the extrapolation that evaluates as right) with the acceptance rate that the store's
own answers show for prompts of the same *kind*, else a wrong answer (one the loop does not
accept). The kind is the task's: for the grid tasks the number of cells the partial pattern shows,
in bins (:data:`lagrseq.tasks.grid_profiles.SHOWN_BINS`). The draw is a hash of the query's record
key and the run seed (the recorded provider's), so a prompt that recurs gets the same answer, in
this trial and in a rerun, as GPT-4 at temperature 0 would give (the authors' caches hold one
answer per prompt).

The rates are fitted to the store's answers (each sample counted once, by its id: the authors'
import stores each answer under both presets' keys), with their uncertainty: each draw table (one
per run seed, and the loop gives each trial its own run seed) draws every kind's rate from its
Beta posterior, ``Beta(accepted + 1, answers - accepted + 1)`` (a uniform prior), before drawing
the per-prompt answers, so the spread over trials holds the rates' own uncertainty (21 of 212 is
not exactly 9.9%) beside the draws'. A number made with this mode is
``fitted`` (:mod:`lagrseq.analysis.provenance`), and its answers carry the source
:data:`CALIBRATED_SOURCE`, which the miss count (:mod:`lagrseq.analysis.misses`) counts as a miss
a fallback answered (one that can be right).

This module knows no task: the task hands it a :class:`MissCalibration` (``TaskSpec.
miss_calibration``), as the mock provider is handed its extrapolator.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from lagrseq.llm.base import Answer, Query, Source
from lagrseq.llm.store import Entry, query_key

CALIBRATED_SOURCE: Source = "calibrated"
"""The ``source`` of a calibrated miss answer in a ``/query`` record."""


@dataclass(frozen=True)
class MissCalibration:
    """What a task hands the calibrated miss answer: the kind of a prompt, whether an answer is
    accepted, and a right and a wrong answer to a prompt (all as text, as a model sees them)."""

    task: str
    """The task's name (only the store's answers of this task are fitted)."""
    kinds: tuple[str, ...]
    """Every kind a prompt can have, in order (the bins' labels)."""
    kind: Callable[[str], str]
    """prompt -> its kind, one of ``kinds``; raises ValueError for a prompt that is not the task's."""
    accepted: Callable[[str], bool]
    """answer text -> whether the loop accepts it (parsed, evaluated at or above the threshold)."""
    right: Callable[[str], str]
    """prompt -> an answer the loop accepts."""
    wrong: Callable[[str], str]
    """prompt -> an answer the loop does not accept."""
    about: str = ""
    """What the kind measures, for tables and messages (e.g. "cells shown in the partial image")."""


@dataclass(frozen=True)
class KindRate:
    """The store's answers of one kind: how many, and how many the loop accepts."""

    kind: str
    answers: int
    accepted: int

    @property
    def rate(self) -> float:
        return self.accepted / self.answers if self.answers else 0.0


@dataclass(frozen=True)
class Fit:
    """Acceptance rates per kind, fitted to a store's answers of one task."""

    task: str
    rates: tuple[KindRate, ...]
    skipped: int = 0
    """Answers whose prompt is not the task's (its kind could not be read)."""
    by_kind: dict[str, KindRate] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        self.by_kind.update({r.kind: r for r in self.rates})

    @property
    def answers(self) -> int:
        return sum(r.answers for r in self.rates)

    def rate(self, kind: str) -> float:
        found = self.by_kind.get(kind)
        return 0.0 if found is None else found.rate

    def text(self) -> str:
        """``kind: accepted/answers (rate)`` per kind, for messages and notes."""
        return "; ".join(f"{r.kind}: {r.accepted}/{r.answers} ({100 * r.rate:.1f}%)" for r in self.rates)


def fit(entries: Iterable[Entry], calibration: MissCalibration) -> Fit:
    """The acceptance rate per kind of the answers in ``entries`` of the calibration's task, each
    sample counted once (by its id). A kind without answers has rate 0 (shown as 0/0)."""
    answers = dict.fromkeys(calibration.kinds, 0)
    accepted = dict.fromkeys(calibration.kinds, 0)
    seen: set[str] = set()
    skipped = 0
    for entry in entries:
        if entry.task != calibration.task:
            continue
        try:
            kind = calibration.kind(entry.prompt)
        except ValueError:
            skipped += len(entry.samples)
            continue
        for sample in entry.samples:
            if sample.id in seen:
                continue
            seen.add(sample.id)
            answers[kind] += 1
            accepted[kind] += bool(calibration.accepted(sample.text))
    return Fit(calibration.task, tuple(KindRate(k, answers[k], accepted[k]) for k in calibration.kinds), skipped)


def draw(key: str, run_seed: int) -> float:
    """A uniform number in [0, 1) fixed by a query's record key and the run seed."""
    digest = hashlib.blake2b(key.encode(), key=(run_seed % 2**64).to_bytes(8, "little"), digest_size=8)
    return int.from_bytes(digest.digest(), "little") / 2.0**64


def posterior_rates(fitted: Fit, run_seed: int) -> dict[str, float]:
    """One draw table's acceptance rate per kind: from each kind's Beta posterior under a uniform
    prior, ``Beta(accepted + 1, answers - accepted + 1)``, by a generator fixed by the run seed."""
    import numpy as np

    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(run_seed % 2**63, spawn_key=(0xCA11B,))))
    return {r.kind: float(rng.beta(r.accepted + 1, r.answers - r.accepted + 1)) for r in fitted.rates}


class CalibratedMissProvider:
    """The fallback of ``--on-miss calibrated`` (module docstring): answers a query the store
    lacks with the right answer when the prompt's draw falls below its kind's rate in this draw
    table (:func:`posterior_rates`)."""

    name = "calibrated"
    REASON = "calibrated"
    """The answers' ``finish_reason``."""

    def __init__(self, fitted: Fit, calibration: MissCalibration, endpoint: str, run_seed: int) -> None:
        self.fit = fitted
        self.calibration = calibration
        self.endpoint = endpoint
        self.run_seed = run_seed
        self.rates = posterior_rates(fitted, run_seed)
        """This draw table's rate per kind (a kind the fit never saw: 0)."""

    def accepts(self, query: Query) -> bool:
        """Whether this query's fixed draw is an accepted answer."""
        key, _ = query_key(query, self.endpoint)
        try:
            kind = self.calibration.kind(query.prompt)
        except ValueError:
            return False
        return draw(key, self.run_seed) < self.rates.get(kind, 0.0)

    def complete(self, query: Query) -> Answer:
        text = self.calibration.right(query.prompt) if self.accepts(query) else self.calibration.wrong(query.prompt)
        return Answer(
            text=text, source=CALIBRATED_SOURCE, model=query.model, usage=None, finish_reason=self.REASON,
            cost_usd=0.0,
        )

    def close(self) -> None:
        return None

    def __enter__(self) -> CalibratedMissProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
