"""How many of a run's answers missed its recorded store, and what answered them.

A run on ``recorded:STORE`` logs each answer's ``source`` in its ``/query`` records: ``recorded``
for the store's own answers; for a query the store lacks, what its ``on_miss`` chose (DESIGN
section 12): ``miss`` for a refusal (``refuse``: counted as a wrong answer, never accepted),
``mock`` for the rule-based mock (``mock``: it can be right), ``live`` for a live answer recorded
now. Every number made from such a run shows its miss share beside it ("misses: k of n answers
(x%)", :meth:`Misses.text`); the frontier's points use the same count (:func:`missed`).
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from lagrseq.registry import REFUSED_SOURCE, kind_of, stored_sources


def missed(sources: pd.Series) -> pd.Series:
    """Per answer, whether it came from outside the store (a miss that a fallback or a refusal
    answered), from the answers' ``source`` column."""
    return ~sources.fillna("").astype(str).isin(stored_sources())


def on_store(provider: str) -> bool:
    """Whether a run logged with ``provider`` (``kind:argument``) reads a recorded store."""
    kind = kind_of(provider)
    return kind is not None and kind.replays and ":" in provider


@dataclass(frozen=True)
class Misses:
    """The answers of one run on a recorded store: how many, how many missed, and by whom the
    misses were answered (source -> count, sorted)."""

    answers: int
    by_source: tuple[tuple[str, int], ...] = ()

    @property
    def missed(self) -> int:
        return sum(count for _, count in self.by_source)

    @property
    def share(self) -> float:
        """Missed answers over all answers (0 without answers)."""
        return self.missed / self.answers if self.answers else 0.0

    @property
    def refused(self) -> int:
        return dict(self.by_source).get(REFUSED_SOURCE, 0)

    @property
    def answered_by_fallback(self) -> int:
        """Misses answered by something that could be right (the mock, a live model)."""
        return self.missed - self.refused

    @property
    def answered_by(self) -> str:
        """What answered the misses, for a data column: ``refused``, ``mock``, ``refused/mock``...,
        or empty without misses."""
        return "/".join("refused" if source == REFUSED_SOURCE else source for source, _ in self.by_source)

    def text(self) -> str:
        """ "misses: k of n answers (x%)", and what answered them: refused (counted as wrong
        answers), or a fallback that can be right (named)."""
        line = f"misses: {self.missed} of {self.answers} answers ({percent(self.missed, self.answers)})"

        def what(source: str) -> str:
            if source == REFUSED_SOURCE:
                return "refused (counted as wrong answers)"
            return f"answered by the {source} fallback, which can be right"

        if len(self.by_source) == 1:
            return f"{line}, {what(self.by_source[0][0])}"
        if self.by_source:
            line += ": " + ", ".join(f"{count} {what(source)}" for source, count in self.by_source)
        return line


def percent(part: int, whole: int) -> str:
    """A share as people read it: 0%, 100% exactly, else one decimal."""
    if whole == 0 or part == 0:
        return "0%"
    if part == whole:
        return "100%"
    return f"{100 * part / whole:.1f}%"


def count_misses(provider: str, queries: pd.DataFrame) -> Misses | None:
    """The misses of a run logged with ``provider`` whose ``/query`` records are ``queries``
    (None for a run on no store)."""
    if not on_store(provider):
        return None
    if queries.empty:
        return Misses(0)
    sent = queries[queries["queried"].fillna(False).astype(bool)]
    sources = sent["source"].fillna("").astype(str)
    outside = sources[missed(sources)]
    by_source = tuple(sorted((str(source), int(n)) for source, n in outside.value_counts().items()))
    return Misses(len(sent), by_source)


def decided_by_fallback(queries: pd.DataFrame, trials: int) -> int:
    """Of a run's ``trials``, those whose first accepted answer came from outside the store (a
    fallback that can be right: the mock, a calibrated draw, a live model), from its ``/query``
    records; a trial with no accepted answer, or whose first came from the store, counts as not
    decided by it."""
    if queries.empty:
        return 0
    asked = queries[queries["queried"].fillna(False).astype(bool) & queries["accepted"].fillna(False).astype(bool)]
    decided = 0
    for _, group in asked.groupby("trial", sort=True):
        first = group.sort_values(["global_step", "step"], kind="stable").iloc[0]
        decided += str(first["source"] or "") not in stored_sources()
    return min(decided, trials)
