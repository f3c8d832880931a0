"""The number-sequence task: data and pure functions (``lagrseq.tasks.base.Task``).

A pattern is the tuple of numbers written so far (always a prefix of the target: the env refuses
a wrong number). The prompt shows the prefix; the answer is the whole sequence as a list of
numbers; its evaluation is the share of positions it gets right.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from lagrseq.tasks.base import Parsed, unreadable_answer

DESCRIPTOR = (
    "The numbers below are the beginning of a sequence of {length} numbers that follows a simple "
    "rule. Reply with the complete sequence as a comma-separated list in square brackets, nothing else."
)


@dataclass
class NumberSequence:
    start: int
    step: int
    length: int
    values: int
    name: str = "number-sequence"

    @property
    def target(self) -> tuple[int, ...]:
        return tuple(self.start + self.step * i for i in range(self.length))

    @property
    def n_actions(self) -> int:
        return self.values

    def prompt(self, pattern: tuple[int, ...]) -> str:
        shown = ", ".join(str(n) for n in pattern) if pattern else "(none yet)"
        return DESCRIPTOR.format(length=self.length) + f"\nSequence so far: [{shown}]"

    def parse(self, text: str) -> Parsed:
        problem = unreadable_answer(text)
        if problem is not None:
            return Parsed(None, problem)
        found = re.search(r"\[([^\[\]]*)\]", text)
        if found is None:
            return Parsed(None, "no [list] in the answer")
        items = [item.strip() for item in found.group(1).split(",") if item.strip()]
        if not items or not all(re.fullmatch(r"-?\d{1,6}", item) for item in items):
            return Parsed(None, "the list holds something other than whole numbers")
        if len(items) > self.length:
            return Parsed(None, f"{len(items)} numbers listed, the sequence has {self.length}")
        return Parsed(tuple(int(item) for item in items))

    def evaluate(self, solution: tuple[int, ...]) -> float:
        return sum(a == b for a, b in zip(solution, self.target)) / self.length

    def guidance(self, pattern: tuple[int, ...], solution: tuple[int, ...], cursor: object = None) -> int | None:
        """pi_LLM: write the solution's next number (None past its end or outside the values)."""
        if len(pattern) >= len(solution):
            return None
        number = solution[len(pattern)]
        return number if 0 <= number < self.values else None

    def guided_cell(self, pattern: tuple[int, ...], solution: tuple[int, ...], cursor: object = None) -> None:
        return None

    def is_complete(self, pattern: tuple[int, ...]) -> bool:
        return tuple(pattern) == self.target

    def progress(self, pattern: tuple[int, ...]) -> int:
        return len(pattern)

    def render(self, pattern: tuple[int, ...]) -> str:
        return ", ".join(str(n) for n in pattern)


def extrapolate(prompt: str, temperature: float, rng: np.random.Generator) -> str:
    """The mock LLM: read the prefix from the prompt, continue its difference. Target-blind; with
    fewer than two numbers it guesses a step of 1 (temperature > 0: a step drawn from 1 to 4)."""
    length = int(re.search(r"sequence of (\d+) numbers", prompt).group(1))  # type: ignore[union-attr]
    shown = re.search(r"Sequence so far: \[([^\]]*)\]", prompt)
    known = [int(n) for n in re.findall(r"-?\d+", shown.group(1))] if shown else []
    if len(known) >= 2:
        step = known[1] - known[0]
    else:
        step = 1 if temperature <= 0 else int(rng.integers(1, 5))
    first = known[0] if known else 0
    return "[" + ", ".join(str(first + step * i) for i in range(length)) + "]"
