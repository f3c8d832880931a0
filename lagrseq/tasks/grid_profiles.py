"""Calibrated mock profiles of the grid tasks (``--provider mock:authors-gpt4``).

A profile simulates a model whose chance of answering with an acceptable completion depends on
what the partial pattern shows, measured on the authors' GPT-4 answers (``../shared/data/
authors_caches/image_completion_gpt4.pkl``: 780 answers; ``object_arrangement_gpt4.pkl``: 142):

- ``fraction``: the share of the target's on-cells already on, in four bins (<1/4, <1/2, <3/4, more);
- ``wrong``: whether the partial pattern has any on-cell outside the target.

An answer counts as right when it would be accepted (E >= 0.96 for the image, the exact diamond
for the arrangement: the acceptance thresholds of both presets). The profile then answers the
target itself. Otherwise it answers like GPT-4's wrong answers did: a shape of the extrapolator's
library (lines, diagonals, outlines) that holds what the prompt shows but is not acceptable, and,
when no such shape exists, a diagonal line, the commonest wrong answer measured (image: 157 of
707 wrong answers are one of the two diagonals, E about 0.8; arrangement: 33 of 101). A wrong
answer is never accepted, so only P(right) moves a run's numbers; the wrong answers' kinds are
kept for the logs to look real. Unlike the rule-based extrapolator, a profile knows the target.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where used: the profiles' names and help alone need neither
    from lagrseq.tasks import grid, shapes

BIN_EDGES = (0.25, 0.5, 0.75)
"""Upper edges of the fraction-of-target-shown bins (the last bin runs to 1)."""
ACCEPT = {"image-completion": 0.96, "object-arrangement": 1.0}
"""E an answer needs to be accepted (``lagr.threshold`` of both presets), per task name."""


def fraction_bin(fraction: float) -> int:
    return int(np.searchsorted(BIN_EDGES, fraction, side="right"))


@dataclass(frozen=True)
class GridProfile:
    """P(right) per fraction bin, without and with wrong on-cells in the partial pattern."""

    name: str
    description: str
    calibration: str
    tables: tuple[tuple[str, tuple[float, ...], tuple[float, ...]], ...]
    """(task name, P(right) per bin with no wrong cell, P(right) per bin with a wrong cell)."""

    def probability(self, task: str, fraction: float, wrong: bool) -> float:
        tables = {name: (clean, dirty) for name, clean, dirty in self.tables}
        if task not in tables:
            raise ValueError(f"mock profile {self.name!r} has no table for {task}; it covers {', '.join(tables)}")
        clean, dirty = tables[task]
        return (dirty if wrong else clean)[fraction_bin(fraction)]


def features(partial: np.ndarray, target: np.ndarray) -> tuple[float, bool]:
    """(share of the target's on-cells on in ``partial``, whether an on-cell lies outside it)."""
    on = np.asarray(partial, dtype=bool)
    goal = np.asarray(target, dtype=bool)
    return float((on & goal).sum() / max(goal.sum(), 1)), bool((on & ~goal).any())


def calibrate(
    pairs: Sequence[tuple[object, object]], task: grid.GridTask, accept: float
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[int, ...], tuple[int, ...]]:
    """From an authors' grid cache read as (key, answer) pairs: P(right) per bin without and with
    wrong cells, and the answer counts behind them. Pairs of another shape than the task's are
    skipped; a bin without answers takes the nearest lower bin's value (the first: 0), and a
    column without any answer repeats the clean one."""
    n = len(BIN_EDGES) + 1
    right = np.zeros((2, n))
    total = np.zeros((2, n), dtype=int)
    for key, answer in pairs:
        if not isinstance(key, np.ndarray) or not isinstance(answer, np.ndarray):
            continue
        if key.shape != task.target.shape or answer.shape != task.target.shape:
            continue
        fraction, wrong = features(key, task.target)
        b = fraction_bin(fraction)
        total[int(wrong), b] += 1
        right[int(wrong), b] += task.evaluate(answer.astype(np.int8)) >= accept
    rates = []
    for w in range(2):
        row: list[float] = []
        for b in range(n):
            row.append(round(float(right[w, b] / total[w, b]), 2) if total[w, b] else (row[-1] if row else 0.0))
        rates.append(tuple(row))
    if not total[1].any():  # no partial pattern with a wrong cell: that column repeats the clean one
        rates[1] = rates[0]
    return rates[0], rates[1], tuple(int(x) for x in total[0]), tuple(int(x) for x in total[1])


AUTHORS_GPT4 = GridProfile(
    name="authors-gpt4",
    description="GPT-4 at temperature 0 as in the authors' grid caches: image completion right about 1 "
    "time in 10 whatever the partial image shows; object arrangement right more often the more of the "
    "diamond is placed, and rarely once a wrong object is on the table",
    calibration="grid_profiles.calibrate over image_completion_gpt4.pkl (780 answers, all without wrong "
    "cells: 178/405/193/4 per bin) and object_arrangement_gpt4.pkl (142 5x5 answers: 130 without wrong "
    "cells, 9/62/55/4 per bin; 12 with, 8/4/0/0); bins are the share of the target's cells on: <1/4, <1/2, "
    "<3/4, more. The image cache has no partial image with a wrong pixel (the released code reverts them), "
    "so that column repeats the clean one",
    tables=(
        ("image-completion", (0.07, 0.09, 0.11, 0.25), (0.07, 0.09, 0.11, 0.25)),
        ("object-arrangement", (0.0, 0.11, 0.53, 1.0), (0.0, 0.25, 0.25, 0.25)),
    ),
)
PROFILES: dict[str, GridProfile] = {"authors-gpt4": AUTHORS_GPT4}


def _diagonal(partial: np.ndarray) -> np.ndarray:
    """The diagonal line (main or anti) holding more of the partial pattern's on-cells."""
    rows, cols = partial.shape
    main = np.eye(rows, cols, dtype=np.int8)
    anti = np.fliplr(main)
    return anti if int((partial * anti).sum()) >= int((partial * main).sum()) else main


def profile_extrapolator(
    task: grid.GridTask, profile: str, accept: float | None = None
) -> Callable[[str, float, np.random.Generator], str]:
    """The mock handler of ``--provider mock:PROFILE`` for a grid task."""
    if profile not in PROFILES:
        raise ValueError(f"unknown grid mock profile {profile!r}; expected one of {', '.join(PROFILES)}")
    chosen = PROFILES[profile]
    threshold = ACCEPT.get(task.name, 1.0) if accept is None else accept
    chosen.probability(task.name, 0.0, False)  # a task the profile lacks fails now
    from lagrseq.tasks import grid, shapes

    library = shapes.library(task.rows, task.cols)
    salt: list[int] = []

    def draw(partial: np.ndarray, temperature: float, rng: np.random.Generator) -> float:
        """A uniform draw; at temperature 0 a fixed one per partial pattern (within a trial), as
        GPT-4 at tau = 0 gives the same answer to the same prompt (the caches hold one answer per
        pattern, and a run that asks again about a pattern gets it again)."""
        if temperature > 0:
            return float(rng.random())
        if not salt:
            salt.append(int(rng.integers(2**63)))
        digest = hashlib.blake2b(partial.astype(np.int8).tobytes(), key=salt[0].to_bytes(8, "little"), digest_size=8)
        return int.from_bytes(digest.digest(), "little") / 2.0**64

    def answer(prompt: str, temperature: float, rng: np.random.Generator) -> str:
        partial = grid.partial_grid(prompt)
        if partial.shape != task.target.shape:
            return grid.format_comma(partial)
        fraction, wrong = features(partial, task.target)
        p = chosen.probability(task.name, fraction, wrong)
        if p >= 1.0 or (p > 0.0 and draw(partial, temperature, rng) < p):
            return grid.format_comma(task.target)
        return grid.format_comma(wrong_answer(task, partial, threshold, library))

    return answer


def wrong_answer(task: grid.GridTask, partial: np.ndarray, threshold: float, library: shapes.Library | None = None) -> np.ndarray:
    """A completion of ``partial`` that is not accepted, as GPT-4's wrong answers were (module
    docstring): the first shape of the extrapolator's library that holds the partial pattern and
    evaluates below ``threshold``, else a diagonal line (below it unless the target is one)."""
    from lagrseq.tasks import grid, shapes

    library = library or shapes.library(task.rows, task.cols)
    for index in grid.hypotheses(partial):
        shape = library.grid(int(index))
        if task.evaluate(shape) < threshold:
            return shape
    diagonal = _diagonal(partial)
    if task.evaluate(diagonal) < threshold:
        return diagonal
    return np.zeros_like(task.target)  # an empty grid: nothing of the target drawn


SHOWN_BINS: dict[str, tuple[int, ...]] = {
    "image-completion": (2, 5, 8, 11),
    "object-arrangement": (1, 2, 3, 4),
    "arm-arrangement": (1, 2, 3, 4),  # the arrangement's 5 x 5 table, placed by the arm
}
"""Upper edges of the bins of cells shown in a partial pattern, per task: the kinds of the
calibrated miss answer (``--on-miss calibrated``, ``lagrseq.llm.calibrated``). Chosen on the
authors' GPT-4 caches (accepted / answers by pixels shown, image: 0/48 at 0-2 pixels, 21/212 at
3-5, 19/235 at 6-8, 20/218 at 9-11, 13/67 at 12 or more; arrangement: 0/11 at 0-1 cells, 1/28 at
2, 7/40 at 3, 16/36 at 4, 17/27 at 5 or more): the image's first bin is where GPT-4 was never
right, the rest are about as large as each other. The arm's table takes the arrangement's bins."""


def shown_labels(edges: Sequence[int]) -> tuple[str, ...]:
    """The bins' labels: ``0-2 shown``, ``3-5 shown``, ..., ``12+ shown``."""
    labels, low = [], 0
    for edge in edges:
        labels.append(f"{low}-{edge} shown" if edge > low else f"{edge} shown")
        low = edge + 1
    return (*labels, f"{low}+ shown")


def shown_bin(partial: np.ndarray, edges: Sequence[int]) -> int:
    """The bin of a partial pattern by its cells shown (on)."""
    return int(np.searchsorted(np.asarray(edges), int(np.count_nonzero(partial)), side="left"))
