"""Answer parsers against hostile answers: linear time, a size cap, one-line reasons, never raising.

An LLM answer is untrusted input: the old grid parser's line pattern
backtracked exponentially (``'1' * 30 + 'x'`` took minutes) and its bracket matching was quadratic
(``'[]' * 32000`` took 25 s). Each bound below is generous on a loaded machine and orders of
magnitude below what the old code took on the same input. Times are CPU times of this process
(``time.process_time``), so other work on the machine does not make them flaky.
"""

from __future__ import annotations

import gc
import re
import time
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lagrseq.running.recording import classify
from lagrseq.tasks import cube, grid
from lagrseq.tasks.arrangement import arm_arrangement, object_arrangement
from lagrseq.tasks.base import MAX_ANSWER_CHARS, Parsed
from lagrseq.tasks.image import image_completion

PARSERS: dict[str, Callable[[str], Parsed]] = {
    "image 10x10": image_completion().parse,
    "arrangement 5x5": object_arrangement().parse,
    "grid 1x4": lambda text: grid.read_grid(text, 1, 4),
    "cube 5": cube.CubeStacking(5).parse,
    "cube 8": cube.CubeStacking(8).parse,
    "cube 11": cube.CubeStacking(11).parse,
    "arm 5x5": arm_arrangement().parse,
}
CLASSIFIERS: dict[str, Callable[[str], object]] = {  # ``lagrseq cache parse``: the parser and then the class
    "classify cube 8": lambda text: classify(cube.CubeStacking(8), text),
    "classify image": lambda text: classify(image_completion(), text),
}

PER_CALL_S = 1.0  # for answers up to MAX_ANSWER_CHARS; the new parsers take a few ms
EXPLICIT_S = 0.5


def timed(parse: Callable[[str], object], text: str) -> tuple[object, float]:
    """CPU seconds of one parse, without the garbage collector: in a long test session a full
    collection walks every object earlier tests left behind, which is not the parser's time."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        start = time.process_time()
        result = parse(text)
        return result, time.process_time() - start
    finally:
        if enabled:
            gc.enable()


def check_parsed(result: object) -> None:
    """A parser's answer: a solution or a short one-line reason, never both, never neither."""
    assert isinstance(result, Parsed)
    assert (result.solution is None) == (result.error is not None)
    if result.error is not None:
        assert "\n" not in result.error and "\r" not in result.error
        assert 0 < len(result.error) <= 200, result.error


# ------------------------------------------------------------------------------------------
# Adversarial answers built from the grammars' own alphabet
# ------------------------------------------------------------------------------------------
FRAGMENTS = [
    *"0123456789", "[", "]", ",", " ", "\n", "\t", "\r\n", ".", "-", ";", "|", "'", '"', "`",
    *"abcdefghijk", "x", "A", "١", "\x00", "\u2028",  # an Arabic-Indic digit, NUL, a line separator
    "0.", "1.0", "-1", "[]", "[[", "]]", "], [", "[0, 1]", "[[0 1]\n [1 0]]", "'a', ", "```",
    "0 1 0\n", "01010\n", "| 0 | 1 |\n",
    # unicode digits (\\d matches them, int() reads some), fences with a language, quoted letters
    "０", "１", "¹", "²", "٠", "७", "𝟏", "\u00a0", "\u3000", "```python\n", "```json\n[[", "'e','f',", "e f g ", "efgabcdh",
    "[['e'", "[1,[0,[1,[", "]]]]", "1.-1", "--1", "1e5", "[1 0 1\n", "\r",
]

hostile = st.lists(
    st.tuples(st.sampled_from(FRAGMENTS), st.integers(1, 4000)), min_size=1, max_size=6
).map(lambda parts: "".join(piece * count for piece, count in parts)[:MAX_ANSWER_CHARS])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=hostile)
def test_every_parser_reads_hostile_answers_in_bounded_time(text: str) -> None:
    for name, parse in PARSERS.items():
        result, took = timed(parse, text)
        assert took < PER_CALL_S, f"{name}: {took:.2f} s on {len(text)} characters starting {text[:40]!r}"
        check_parsed(result)
    for name, work in [*CLASSIFIERS.items(), ("read_any_grid", grid.read_any_grid)]:
        _, took = timed(work, text)
        assert took < PER_CALL_S, f"{name}: {took:.2f} s on {len(text)} characters starting {text[:40]!r}"


def long_line(piece: str) -> str:
    return (piece * (MAX_ANSWER_CHARS // len(piece) + 1))[:MAX_ANSWER_CHARS]


@pytest.mark.parametrize(
    "text",
    [
        long_line("١٢٣٤"), long_line("０ １ "), long_line("¹,²,"), long_line("𝟏 "), long_line("1,"), long_line("1."),
        long_line("1.-"), long_line("```\n"), long_line("```python\n0 1 0\n```\n"), long_line("[1,"), long_line("[['e',"),
        long_line("'e','f',"), long_line("a "), "a" * MAX_ANSWER_CHARS, long_line("[[0,1],[1,0]]"), long_line("0 1\u2028"),
        long_line("\u3000"), long_line("[" + "0 " * 300 + "]\n"), ("0 " * 3000 + "\n") * 2, long_line("[x ") + "]",
    ],
    ids=lambda text: repr(text[:12]),
)
def test_long_lines_of_one_fragment_parse_quickly(text: str) -> None:
    for name, work in [*PARSERS.items(), *CLASSIFIERS.items()]:
        result, took = timed(work, text)
        assert took < EXPLICIT_S, f"{name}: {took:.2f} s"
        if isinstance(result, Parsed):
            check_parsed(result)


@settings(max_examples=200, deadline=None)
@given(text=st.lists(st.sampled_from(FRAGMENTS), max_size=30).map("".join))
def test_every_parser_answers_short_junk_with_a_solution_or_a_reason(text: str) -> None:
    for parse in PARSERS.values():
        check_parsed(parse(text))


# The line pattern of the old parser, kept as the reference for what a matrix line is (it is
# exponential on long digit runs, so only short strings are given to it).
_OLD_MATRIX_LINE = re.compile(r"^[\s,;|]*(?:-?\d+(?:\.\d*)?[\s,;|]*)+$")


@settings(max_examples=300, deadline=None)
@given(line=st.text(alphabet=st.sampled_from([*"01٣-. ,;|\tx"]), max_size=12))
def test_the_linear_matrix_line_pattern_accepts_exactly_the_old_lines(line: str) -> None:
    assert bool(grid._MATRIX_LINE.match(line)) == bool(_OLD_MATRIX_LINE.match(line))


@settings(max_examples=50, deadline=None)
@given(
    cells=st.lists(st.integers(0, 1), min_size=25, max_size=25),
    prose=st.text(alphabet=st.sampled_from([*"abcdefghijk x.:\n"]), max_size=200),
    writing=st.sampled_from(["numpy", "comma"]),
)
def test_a_grid_after_prose_is_still_read(cells: list[int], prose: str, writing: str) -> None:
    target = np.array(cells, dtype=np.int8).reshape(5, 5)
    parsed = object_arrangement().parse(prose + "\n" + grid.FORMATS[writing](target) + "\n")
    assert parsed.ok and np.array_equal(parsed.solution, target)


# ------------------------------------------------------------------------------------------
# Answers shaped to make a backtracking parser take minutes
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "text",
    [
        "1" * 30 + "x",  # old: about 4 minutes (doubling with every digit from 1.5 s at 24)
        "1" * 48 + "!\n",  # the live run's 48-digit line, not quite a matrix line: for ever
        "[0 1 0]\n" + "0" * 48 + " x",
        "[]" * (MAX_ANSWER_CHARS // 2),  # old: 4 s
        "[" * (MAX_ANSWER_CHARS // 2) + "]" * (MAX_ANSWER_CHARS // 2),  # old: 7 s
        "[0]" * (MAX_ANSWER_CHARS // 3),
    ],
    ids=["30 digits", "48 digits", "after a row", "[] at the cap", "nested at the cap", "[0] rows"],
)
def test_issue_examples_parse_quickly(text: str) -> None:
    for name, parse in PARSERS.items():
        result, took = timed(parse, text)
        assert took < EXPLICIT_S, f"{name}: {took:.2f} s"
        check_parsed(result)


def test_bracket_matching_is_linear_beyond_the_cap() -> None:
    """The matrix finder itself (also used on prompts, which are not capped): old 25 s and more."""
    for text in ("[]" * 32000, "[" * 32000 + "]" * 32000, "[[0,1]," * 10000 + "]" * 10000):
        _, took = timed(grid.read_any_grid, text)
        assert took < 2 * EXPLICIT_S, f"{took:.2f} s on {text[:20]!r}"


def test_the_cube_prompt_reader_does_not_backtrack_on_whitespace() -> None:
    """The mock LLM's prompt reader: ``\\s*\\n?\\s*`` was quadratic (old: 13 s on this)."""
    start = time.process_time()
    with pytest.raises(ValueError, match="does not look like a cube-stacking prompt"):
        cube.partial_stack("(from bottom to top):" + " " * 32000 + "x")
    assert time.process_time() - start < EXPLICIT_S


# ------------------------------------------------------------------------------------------
# The size cap
# ------------------------------------------------------------------------------------------
def padded(answer: str, length: int) -> str:
    """``answer`` after prose, ``length`` characters in all."""
    prose = "Here is the completed pattern. " * (length // 31 + 1)
    return prose[: length - len(answer) - 1] + "\n" + answer


def test_answers_at_the_cap_are_read_and_longer_ones_refused_with_the_limit() -> None:
    diamond = grid.format_comma(object_arrangement().target)
    stack = "['e','f','g','a','b','c','d','h']"
    cases = [(object_arrangement().parse, diamond), (cube.CubeStacking(8).parse, stack)]
    for parse, answer in cases:
        at_cap = padded(answer, MAX_ANSWER_CHARS)
        assert len(at_cap) == MAX_ANSWER_CHARS
        assert parse(at_cap).ok
        over = padded(answer, MAX_ANSWER_CHARS + 1)
        refused, took = timed(parse, over)
        assert not refused.ok and took < EXPLICIT_S
        assert refused.error == (
            f"answer of {MAX_ANSWER_CHARS + 1} characters is longer than the "
            f"{MAX_ANSWER_CHARS}-character limit (MAX_ANSWER_CHARS in lagrseq/tasks/base.py); not read"
        )
    huge, took = timed(image_completion().parse, "1" * 10_000_000)
    assert not huge.ok and "16000-character limit" in (huge.error or "") and took < EXPLICIT_S


def test_the_cap_is_well_above_real_answers() -> None:
    """A 10 x 10 numpy print with a paragraph of reasoning is a small fraction of the cap."""
    answer = "Let me think step by step. " * 40 + grid.format_numpy(image_completion().target)
    assert len(answer) * 5 < MAX_ANSWER_CHARS and image_completion().parse(answer).ok


def test_long_tokens_are_clipped_in_reasons() -> None:
    rows = "[0,1,0,1,0]," * 4
    grid_reason = object_arrangement().parse("[" + rows + "[0,1,0,1," + "2" * 5000 + "]]")
    assert grid_reason.error == f"expected 0 or 1 in every cell, found value '{'2' * 37}...' at row 5, column 5"
    cube_reason = cube.CubeStacking(8).parse("['e','" + "z1" * 5000 + "']")
    assert cube_reason.error == f"'{'z1' * 18}z...' is not a cube of this table"


@pytest.mark.parametrize("text", ["\x00" * 44, "\x01\x02" * 500, "\U0010ffff" * 100, "a\x00" * 30 + " xyz"])
def test_reasons_stay_short_when_escapes_lengthen_the_repr(text: str) -> None:
    """Found by hypothesis on CI: 44 NUL characters made a 204-character reason."""
    for parse in PARSERS.values():
        check_parsed(parse(text))
