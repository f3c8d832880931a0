"""What every pattern-completion task provides (the task descriptor d of the paper and more).

A task is data plus pure functions; it knows nothing of agents, environments, LLM providers or
logs. ``Pattern`` is the task's own partial-pattern type (a tuple of cube ids, a 2-D grid).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

from lagrseq.errors import ConfigError

Pattern = Any
Solution = Any

STEP_LOG = "log_step"
"""An env's ``info`` key (optional): extra fields of the step's ``/transition`` record (the arm's
``placement``), set on the step that has them."""
EPISODE_LOG = "log_episode"
"""An env's ``info`` key (optional): extra fields of the episode's ``/episode`` record, counted by
the env since its last reset (the arm's ``placements`` and ``failed_placements``)."""

MAX_ANSWER_CHARS = 16_000
"""The longest answer text (in characters) a task's parser reads. Real answers are under 2 kB
(a 10 x 10 matrix with prose, or 256 tokens of a small model's prose); anything longer is refused
unread, as a wrong answer with :func:`oversized_answer`'s reason. The one place this limit lives:
other layers that cap answers (the store, a live provider) use the same value."""


def oversized_answer(text: str) -> str | None:
    """The parse-error reason for an answer longer than :data:`MAX_ANSWER_CHARS`, else None."""
    if len(text) <= MAX_ANSWER_CHARS:
        return None
    return (
        f"answer of {len(text)} characters is longer than the {MAX_ANSWER_CHARS}-character limit "
        "(MAX_ANSWER_CHARS in lagrseq/tasks/base.py); not read"
    )


_Section = TypeVar("_Section")


def expect(value: Any, cls: type[_Section], section: str) -> _Section:
    """``value`` (a configuration section, or a task) as the class a task's factory needs;
    ConfigError (one line) otherwise (configurations from ``config.load`` always are)."""
    if not isinstance(value, cls):
        raise ConfigError(
            f"[{section}] is a {type(value).__name__}, this task needs a {cls.__name__}; "
            "build configurations with lagrseq.config.load"
        )
    return value


def unreadable_answer(text: object) -> str | None:
    """Why an answer cannot be read at all (not text, empty, longer than the cap), else None:
    the check every parser makes first."""
    if not isinstance(text, str):
        return "empty answer"
    too_long = oversized_answer(text)
    if too_long is not None:
        return too_long
    return "empty answer" if not text.strip() else None


def clip_token(token: str, width: int = 40) -> str:
    """``repr`` of a token quoted in a parse-error reason: at most ``width`` + 2 characters, also
    when escapes (``\x00`` for a NUL) make the repr longer than the token."""
    shown = repr(token if len(token) <= width else token[: width - 3] + "...")
    return shown if len(shown) <= width + 2 else shown[: width - 1] + "..."


@dataclass(frozen=True)
class Parsed:
    """An LLM answer read as a solution: ``solution`` is None exactly when ``error`` says why."""

    solution: Solution | None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


class Task(Protocol):
    """A pattern-completion task. ``lagrseq record`` also uses three optional methods where a
    task has them (cube stacking does): ``prefixes()``, the patterns asked without
    ``--from-runs``; ``is_partial(solution)``, a parsed answer of the wrong size; and
    ``shown(prompt)``, how much of the pattern a prompt shows (ValueError: not its prompt)."""

    name: str

    def prompt(self, pattern: Pattern) -> str:
        """The full prompt (descriptor + partial pattern) a language model is shown."""
        ...

    def parse(self, text: str) -> Parsed:
        """Read an answer's text; never raises on bad text (the reason goes in ``Parsed.error``)."""
        ...

    def evaluate(self, solution: Solution) -> float:
        """Normalised evaluation E(s_LLM) / E(target), in [0, 1]; 1 means the exact target."""
        ...

    def guidance(self, pattern: Pattern, solution: Solution, cursor: Any = None) -> int | None:
        """pi_LLM: the action the solution asks for in ``pattern`` (None: it asks for nothing)."""
        ...

    def is_complete(self, pattern: Pattern) -> bool:
        """The pattern is the target."""
        ...

    def progress(self, pattern: Pattern) -> int:
        """How far the partial pattern has come (stack height, cells on), for query triggers."""
        ...

    def render(self, pattern: Pattern) -> str:
        """A short human-readable form of a pattern (logs, errors)."""
        ...

    def guided_cell(self, pattern: Pattern, solution: Solution, cursor: Any = None) -> Any:
        """The cell pi_LLM chooses to act on when the environment works cell by cell (grids;
        its action names that cell: the task's registered ``guide``), or None to act wherever the environment
        is (its ``info["cursor"]``, if any)."""
        ...


class Extrapolator(Protocol):
    """A rule-based stand-in for an LLM: prompt text in, answer text out. Target-blind."""

    def __call__(self, prompt: str, temperature: float, rng: np.random.Generator) -> str: ...
