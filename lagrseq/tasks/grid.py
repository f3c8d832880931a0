"""Grid pattern-completion tasks (image completion, object arrangement; SPEC sections 2, 3, 6).

A pattern is a rows x cols int8 grid of 0/1 (1 = a white pixel, an object on the table). This
module holds what the two grid tasks share: the evaluation E (fraction of matching cells), the
prompt (a task descriptor followed by the partial grid), the answer parser, pi_LLM and the
rule-based extrapolator that stands in for an LLM. :mod:`lagrseq.tasks.image` and
:mod:`lagrseq.tasks.arrangement` supply the descriptors and the targets.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from lagrseq.tasks import shapes
from lagrseq.tasks.base import Parsed, clip_token, unreadable_answer

MatrixFormat = Literal["numpy", "comma"]
GuidanceMode = Literal["cell-by-cell", "next-missing"]
CellAction = Literal["flip", "drop"]


# ------------------------------------------------------------------------------------------
# Writing grids
# ------------------------------------------------------------------------------------------
def format_numpy(grid: np.ndarray) -> str:
    """``str()`` of an integer numpy grid, as the released code writes the partial pattern into
    its prompt: ``[[0 0 1]\\n [0 1 0]]``."""
    rows = ("[" + " ".join(str(int(v)) for v in row) + "]" for row in np.asarray(grid))
    return "[" + "\n ".join(rows) + "]"


def format_comma(grid: np.ndarray) -> str:
    """A grid the way the descriptors' examples write it: ``[[0,0,1],\\n    [0,1,0]]``."""
    rows = ("[" + ",".join(str(int(v)) for v in row) + "]" for row in np.asarray(grid))
    return "[" + ",\n    ".join(rows) + "]"


FORMATS = {"numpy": format_numpy, "comma": format_comma}


def grid_of(rows: Sequence[str]) -> np.ndarray:
    """A grid from strings of 0/1 digits, one per row (for descriptors and tests)."""
    return np.array([[int(ch) for ch in row] for row in rows], dtype=np.int8)


# ------------------------------------------------------------------------------------------
# Reading grids out of text (answers and prompts)
# ------------------------------------------------------------------------------------------
# Every pattern below runs in time linear in the text: no prefix can be matched in two ways, so
# the backtracking engine retries each character a bounded number of times. A number is
# -?\d+(\.\d*)?, and a line may hold numbers written one after another without a separator
# (``010``, ``1.0-1``): such a run of numbers is one _RUN (inside it a point or a sign always lies
# between two numbers, never an empty string), and runs are separated by at least one separator.
_BINARY = re.compile(r"^[01](?:\.0*)?$")
_NUMBER = re.compile(r"^-?\d+(?:\.\d*)?$")
_SEPARATOR = r"[\s,;|]"
_RUN = r"-?\d+(?:\.-?\d+|-\d+)*\.?"
_MATRIX_LINE = re.compile(rf"^{_SEPARATOR}*{_RUN}(?:{_SEPARATOR}+{_RUN})*{_SEPARATOR}*$")
_COMPACT_ROW = re.compile(r"\d{2,}")
_TOKEN_SEPARATORS = re.compile(r"[\s,;|'\"]+")
_BRACKET = re.compile(r"[\[\]]")


@dataclass(frozen=True)
class _Candidate:
    """A matrix-like block of the text: rows of tokens, and where it ends (for ordering)."""

    rows: tuple[tuple[str, ...], ...]
    end: int


def _tokens(row: str) -> tuple[str, ...]:
    row = row.strip()
    if not row:
        return ()
    if _COMPACT_ROW.fullmatch(row):  # a compact row such as 00100
        return tuple(row)
    return tuple(t for t in _TOKEN_SEPARATORS.split(row) if t)


# A balanced ``[...]`` group: (start, end, depth, children) where ``text[start:end]`` is the
# group, depth counts the brackets open around it (unclosed ones too) and children are the spans
# of its direct children (groups one level in), in order.
_Group = tuple[int, int, int, list[tuple[int, int]]]


def _bracket_groups(text: str) -> list[_Group]:
    """Every balanced ``[...]`` group, ordered by start; one pass over the brackets.

    A ``]`` closes the latest open ``[`` (a ``]`` with none open is ignored), so every ``[``
    inside a closed group opens one of its descendants: a group is a leaf (no ``[`` inside)
    exactly when it has no children.
    """
    slots: list[_Group | None] = []  # one per ``[``, in order: its group once it is closed
    stack: list[tuple[int, int, list[tuple[int, int]]]] = []
    for match in _BRACKET.finditer(text):
        i = match.start()
        if text[i] == "[":
            stack.append((i, len(slots), []))
            slots.append(None)
        elif stack:
            start, slot, children = stack.pop()
            slots[slot] = (start, i + 1, len(stack), children)
            if stack:
                stack[-1][2].append((start, i + 1))
    return [group for group in slots if group is not None]


_SEPARATORS = re.compile(r"[\s,]*")


def _rows_if_separated(text: str, spans: list[tuple[int, int]], start: int, end: int) -> bool:
    """True when only whitespace and commas lie between ``start``, the spans and ``end``."""
    edges = [start, *(p for span in spans for p in span), end]
    return all(_SEPARATORS.fullmatch(text, edges[i], edges[i + 1]) for i in range(0, len(edges), 2))


def _candidates(text: str) -> list[_Candidate]:
    """Matrix-like blocks in ``text``, in the order in which they end.

    - a ``[...]`` group whose children are flat ``[...]`` rows separated by commas or whitespace
      (Python lists, numpy prints; the rows may hold commas or spaces);
    - a run of flat top-level ``[...]`` groups separated the same way (one row per group);
    - a run of lines made only of numbers and separators (``0 1 0``, ``0,1,0``, ``| 0 | 1 |``,
      ``010``), e.g. inside a code fence.

    Time linear in the length of ``text`` (each group is looked at as itself and as a child).
    """
    found: list[_Candidate] = []
    groups = _bracket_groups(text)
    leaves = {(start, end) for start, end, _, children in groups if not children}
    in_matrix: set[tuple[int, int]] = set()
    for start, end, _, children in groups:
        rows_only = children and all(child in leaves for child in children)
        if rows_only and _rows_if_separated(text, children, start + 1, end - 1):
            found.append(_Candidate(tuple(_tokens(text[s + 1 : e - 1]) for s, e in children), end))
            in_matrix.update(children)
    run: list[tuple[int, int]] = []
    tops = [(s, e) for s, e, depth, _ in groups if depth == 0 and (s, e) in leaves and (s, e) not in in_matrix]
    for span in tops:
        if run and not _SEPARATORS.fullmatch(text, run[-1][1], span[0]):
            found.append(_Candidate(tuple(_tokens(text[s + 1 : e - 1]) for s, e in run), run[-1][1]))
            run = []
        run.append(span)
    if run:
        found.append(_Candidate(tuple(_tokens(text[s + 1 : e - 1]) for s, e in run), run[-1][1]))
    position = 0
    lines: list[str] = []
    for line in text.splitlines(keepends=True):
        bare = line.strip()
        if bare and _MATRIX_LINE.match(bare):
            lines.append(bare)
        elif lines:
            found.append(_Candidate(tuple(_tokens(row) for row in lines), position))
            lines = []
        position += len(line)
    if lines:
        found.append(_Candidate(tuple(_tokens(row) for row in lines), position))
    return sorted(found, key=lambda c: c.end)


def _as_grid(candidate: _Candidate, rows: int, cols: int) -> tuple[np.ndarray | None, str]:
    """The candidate as a rows x cols 0/1 grid, or None and the reason it is not one."""
    cells = [t for row in candidate.rows for t in row]
    shape_ok = len(candidate.rows) == rows and all(len(row) == cols for row in candidate.rows)
    if not shape_ok and len(candidate.rows) == 1 and len(cells) == rows * cols:
        shape_ok = True  # one flat list of rows*cols values, read row by row
    if not shape_ok:
        widths = sorted({len(row) for row in candidate.rows})
        found = len(candidate.rows)
        size = (
            f"{found}x{widths[0]}"
            if len(widths) == 1
            else f"{found} rows of {widths[0]} to {widths[-1]} values"
        )
        return None, f"expected a {rows}x{cols} matrix of 0/1, found {size}"
    for index, token in enumerate(cells):
        if not _BINARY.match(token):
            what = "value" if _NUMBER.match(token) else "token"
            return None, (
                f"expected 0 or 1 in every cell, found {what} {clip_token(token)} at row "
                f"{index // cols + 1}, column {index % cols + 1}"
            )
    grid = np.array([int(float(t)) for t in cells], dtype=np.int8).reshape(rows, cols)
    return grid, ""


def read_grid(text: str, rows: int, cols: int) -> Parsed:
    """Read a rows x cols 0/1 grid from free text; never raises.

    Accepts Python-style lists (``[[0,1],[1,0]]``), numpy prints (``[[0 1]\\n [1 0]]``, also with
    ``0.``/``1.``), rows of digits or of spaced/comma-separated values, code fences and prose
    around any of them. When several matrices appear (a model repeating the initial grid before
    its answer), the last one of the right shape wins. Failure reasons: no matrix at all, the
    wrong shape, a value other than 0 or 1, an answer longer than ``MAX_ANSWER_CHARS`` (not
    read). Time linear in the answer's length.
    """
    problem = unreadable_answer(text)
    if problem is not None:
        return Parsed(None, problem)
    failures: list[tuple[int, str]] = []
    for candidate in reversed(_candidates(text)):
        grid, reason = _as_grid(candidate, rows, cols)
        if grid is not None:
            return Parsed(grid)
        failures.append((sum(len(row) for row in candidate.rows), reason))
    if failures:  # explain the biggest matrix-like block, the one most likely meant as the answer
        return Parsed(None, max(failures, key=lambda f: f[0])[1])
    return Parsed(None, f"no matrix found in {clip_token(' '.join(text.split()), 60)}")


def read_any_grid(text: str) -> np.ndarray | None:
    """The last matrix in ``text`` whatever its size (every row as long as the first), or None."""
    for candidate in reversed(_candidates(text)):
        rows = len(candidate.rows)
        cols = len(candidate.rows[0]) if rows else 0
        if rows and cols:
            grid, _ = _as_grid(candidate, rows, cols)
            if grid is not None:
                return grid
    return None


# ------------------------------------------------------------------------------------------
# The task
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Descriptor:
    """The task descriptor d: instructions (with examples) first, then, inside a triple-backtick
    block, the context sentence and the partial grid, as the released ``LLM.py`` builds it."""

    instructions: str
    context: str

    def prompt(self, partial: str) -> str:
        return f"{self.instructions}```{self.context}{partial}```\n    "


class GridTask:
    """A grid pattern-completion task: a target grid, its descriptor, E, parser and pi_LLM.

    ``cell_action`` says what action 1 does at a cell: ``flip`` its value (image completion) or
    ``drop`` an object on it (object arrangement; objects are never removed).
    """

    def __init__(
        self,
        name: str,
        target: np.ndarray,
        target_name: str,
        descriptor: Descriptor,
        cell_action: CellAction,
        goal_threshold: float = 1.0,
        matrix_format: MatrixFormat = "numpy",
        guidance_mode: GuidanceMode = "cell-by-cell",
    ) -> None:
        if matrix_format not in FORMATS:
            raise ValueError(f"matrix_format {matrix_format!r}; expected one of {sorted(FORMATS)}")
        if guidance_mode not in ("cell-by-cell", "next-missing"):
            raise ValueError(f"guidance_mode {guidance_mode!r}; expected cell-by-cell or next-missing")
        self.name = name
        self.target = np.array(target, dtype=np.int8)
        self.target.setflags(write=False)
        self.target_name = target_name
        self.rows, self.cols = self.target.shape
        self.cells = self.rows * self.cols
        self.descriptor = descriptor
        self.cell_action = cell_action
        self.goal_threshold = goal_threshold
        self.matrix_format = matrix_format
        self.guidance_mode = guidance_mode
        self._format = FORMATS[matrix_format]

    # ---------------------------------------------------------------- evaluation
    def matches(self, grid: np.ndarray) -> int:
        """Cells equal to the target's."""
        return int(np.count_nonzero(np.asarray(grid) == self.target))

    def evaluate(self, solution: np.ndarray) -> float:
        """E(I) = (1/N) sum_i 1[p_i = p_T,i], the fraction of matching cells (paper, image task)."""
        return self.matches(solution) / self.cells

    def is_complete(self, pattern: np.ndarray) -> bool:
        """The goal: E >= ``goal_threshold`` (1.0: the exact target)."""
        return self.evaluate(pattern) >= self.goal_threshold

    def progress(self, pattern: np.ndarray) -> int:
        """Cells that are on."""
        return int(np.count_nonzero(pattern))

    def render(self, pattern: np.ndarray) -> str:
        return "\n".join("".join("#" if v else "." for v in row) for row in np.asarray(pattern))

    def coerce_pattern(self, value: object) -> np.ndarray:
        """A partial grid from outside data (an authors' cache key, an MCAP ``state``): a
        rows x cols array or nested list of 0/1 (floats 0.0/1.0 too). Raises ``ValueError``
        saying what is wrong otherwise (e.g. the 10 x 10 seed pair of the arrangement cache)."""
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"expected a {self.rows}x{self.cols} grid of 0/1, found {type(value).__name__}") from None
        if array.shape != (self.rows, self.cols):
            raise ValueError(f"expected a {self.rows}x{self.cols} grid of 0/1, found shape {array.shape}")
        if not np.isin(array, (0.0, 1.0)).all():
            others = np.unique(array[~np.isin(array, (0.0, 1.0))])  # one nan, however many there are
            shown = ", ".join(f"{v:g}" for v in others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
            raise ValueError(f"expected only 0 and 1 in the grid, found {shown}")
        return array.astype(np.int8)

    # ---------------------------------------------------------------- prompt and parser
    def prompt(self, pattern: np.ndarray) -> str:
        """The descriptor with the partial grid written as configured (numpy ``str()`` as in the
        released code, or the examples' comma lists)."""
        return self.descriptor.prompt(self._format(np.asarray(pattern)))

    def parse(self, text: str) -> Parsed:
        """A rows x cols 0/1 grid from an answer (see :func:`read_grid`); never raises."""
        return read_grid(text, self.rows, self.cols)

    # ---------------------------------------------------------------- pi_LLM
    def guided_cell(
        self, pattern: np.ndarray, solution: np.ndarray, cursor: tuple[int, int] | None = None
    ) -> tuple[int, int] | None:
        """The cell pi_LLM chooses to act on, or None when it acts wherever the environment is.

        ``next-missing`` (released ``LLMgreedy``, SPEC 2.3): the first cell in row-major order that
        the solution has on and the pattern has off, wherever the scan or draw is; ``cursor``
        (a no-op there) when nothing is missing. ``cell-by-cell`` (paper, image task): None.
        """
        if self.guidance_mode != "next-missing":
            return None
        missing = (np.asarray(solution) == 1) & (np.asarray(pattern) == 0)
        first = int(missing.argmax())  # the first True in row-major order (0 when there is none)
        if not missing.flat[first]:
            return cursor
        return divmod(first, self.cols)

    def guidance(
        self, pattern: np.ndarray, solution: np.ndarray, cursor: tuple[int, int] | None = None
    ) -> int | None:
        """pi_LLM's action at ``cursor``: 1 when the solution asks for a change there, else 0.

        flip: the cell differs from the solution (paper: "change pixel intensity or retain it").
        drop: the solution has an object there and the table does not. With ``next-missing`` only
        missing cells are ever set, never cleared (the released code never turns pixels off).
        """
        if cursor is None:
            return None
        have, want = int(pattern[cursor]), int(solution[cursor])
        if self.cell_action == "drop" or self.guidance_mode == "next-missing":
            return int(want == 1 and have == 0)
        return int(have != want)


# ------------------------------------------------------------------------------------------
# Rule-based extrapolator (the mock LLM). It reads the prompt text only: the partial grid in the
# prompt's last triple-backtick block. It never sees the target.
# ------------------------------------------------------------------------------------------
def partial_grid(prompt: str) -> np.ndarray:
    """The partial grid of a grid-task prompt (the last matrix of its last ``` block)."""
    blocks = prompt.split("```")
    grid = read_any_grid(blocks[-2] if len(blocks) >= 3 else prompt)
    if grid is None:
        raise ValueError("prompt does not contain a partial grid")
    return grid


def hypotheses(partial: np.ndarray) -> np.ndarray:
    """Library shapes (indices into :func:`shapes.library`, simplest first) that contain every
    on-cell of ``partial``. If none does, the shapes that contain the most of them."""
    rows, cols = partial.shape
    lib = shapes.library(rows, cols)
    on = np.asarray(partial, dtype=bool).ravel()
    found = lib.containing(on)
    if found.size:
        return found
    covered = lib.masks[:, on].sum(axis=1)
    return np.flatnonzero(covered == covered.max())


def extrapolate(prompt: str, temperature: float, rng: np.random.Generator) -> str:
    """Answer a grid prompt like a model told to reply with the matrix only.

    Temperature 0: the simplest library shape containing every on-cell of the partial grid (family
    rank, then fewest cells, then top-left first). Temperature > 0: one of those shapes drawn with
    weight exp(-rank / temperature) from ``rng``. The answer is written like the descriptor's
    examples.
    """
    partial = partial_grid(prompt)
    found = hypotheses(partial)
    if temperature <= 0 or found.size == 1:
        choice = int(found[0])
    else:
        weights = np.exp(-np.arange(found.size) / float(temperature))
        choice = int(found[rng.choice(found.size, p=weights / weights.sum())])
    return format_comma(shapes.library(*partial.shape).grid(choice))
