"""Cube-stacking task: evaluation, prompt, parser (incl. every authors' answer), pi_LLM, mock."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from lagrseq.tasks.cube import (
    CubeStacking,
    consistent_orders,
    extrapolate,
    format_stack,
    upstream_state_key,
)

EIGHT = CubeStacking(8)
E, F, G, A, B, C, D, H = 4, 5, 6, 0, 1, 2, 3, 7


def test_targets_are_decreasing_edge_length() -> None:
    for size in (5, 8, 11):
        task = CubeStacking(size)
        edges = [task.cubes[i].edge_cm for i in task.target]
        assert edges == sorted(edges, reverse=True)
        assert sorted(task.target) == list(range(size))
    assert EIGHT.target == (E, F, G, A, B, C, D, H)
    assert CubeStacking(11).target == (5, 10, 4, 9, 3, 8, 2, 7, 1, 6, 0)  # f,k,e,j,d,i,c,h,b,g,a


@pytest.mark.parametrize(
    ("stack", "expected"),
    [
        ((), 0),
        ((E,), 1),  # 1 * 1
        ((E, F, G), 9),  # 3 * 3
        ((E, A), 2),  # 2 * 1: a is in the wrong place
        ((A, E), 0),  # nothing in place
        ((E, F, G, A, B, C, D, H), 64),
        ((E, F, G, A, B, C, H, D), 48),  # the paper's alternative order is not the code's target
    ],
)
def test_evaluation_is_length_times_correct_positions(stack: tuple[int, ...], expected: int) -> None:
    assert EIGHT.evaluation(stack) == expected


def test_normalised_evaluation_is_one_only_for_the_target() -> None:
    assert EIGHT.evaluate(EIGHT.target) == 1.0
    assert EIGHT.evaluate((E, F, G, H, A, B, C, D)) == pytest.approx(8 * 3 / 64)
    assert EIGHT.evaluate((E, F, G)) == pytest.approx(9 / 64)


def test_prompt_is_the_released_descriptor() -> None:
    prompt = EIGHT.prompt((E, F, G))
    assert prompt.startswith("You are an organizing robot. Stack the remaining cubes")
    assert "The final stack should have all 8 cubes. Lets think step by step." in prompt
    assert "     - Blue cube of edge length 10cm (represented by 'e')\n" in prompt
    assert "(from bottom to top): \n    ['e','f','g']```\n    " in prompt
    # The exact bytes (checked once against the released llm.py): recorded answers are keyed
    # by this text, so any change must be deliberate.
    digest = hashlib.sha256(prompt.encode()).hexdigest()
    assert digest.startswith("c4f721f4a1b2")
    assert format_stack(()) == "[]"
    assert "have all 11 cubes" in CubeStacking(11).prompt(())


def test_parser_reads_every_answer_in_the_authors_caches(cube_cache_8, cube_cache_11) -> None:
    for cache, task in ((cube_cache_8, EIGHT), (cube_cache_11, CubeStacking(11))):
        pairs = list(zip(cache[0::2], cache[1::2]))
        for key, answer in pairs:
            text = answer if isinstance(answer, str) else str(answer)  # the seed pair is a list
            parsed = task.parse(text)
            if len(key) == 1 and key == [4] and task is not EIGHT:
                continue  # the 8-cube seed pair copied into the 11-cube cache
            assert parsed.ok, (text, parsed.error)
            letters = "".join(ch for ch in text if ch.isalpha())
            assert parsed.solution == tuple("abcdefghijk".index(ch) for ch in letters)


def test_authors_cache_accuracy_matches_spec(cube_cache_8) -> None:
    """SPEC section 5: 40 of the 81 answers in the tau=0 cache equal the target."""
    pairs = list(zip(cube_cache_8[0::2], cube_cache_8[1::2]))
    correct = sum(EIGHT.parse(str(a)).solution == EIGHT.target for _, a in pairs)
    assert (len(pairs), correct) == (81, 40)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("['e','f','g','a','b','c','d','h']", (E, F, G, A, B, C, D, H)),
        ('["e", "f", "g"]', (E, F, G)),
        ("[e, f, g, a]", (E, F, G, A)),
        ("efgabcdh", (E, F, G, A, B, C, D, H)),
        ("e, f, g", (E, F, G)),
        ("Sure! The order (bottom to top) is:\n['e','f','g','a','b','c','d','h']", (E, F, G, A, B, C, D, H)),
        ("```python\n['e','f','g','a','b','c','d','h']\n```", (E, F, G, A, B, C, D, H)),
        ("From ['e','f'] the stack becomes ['e','f','g','a']", (E, F, G, A)),
        ("['E','F']", (E, F)),
    ],
)
def test_parser_accepts_common_answer_shapes(text: str, expected: tuple[int, ...]) -> None:
    parsed = EIGHT.parse(text)
    assert parsed.ok and parsed.solution == expected


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("", "empty answer"),
        ("   ", "empty answer"),
        ("I cannot determine the order.", "no list of cubes"),
        ("['e','f','1','a']", "'1' is not a cube"),  # the released parser repeated 'f' here
        ("['e','z']", "'z' is not a cube"),
        ("['e','e','f']", "appears twice"),
        ("[]", "empty list"),
        ("['e','f','g','a','b','c','d','h','e']", "appears twice"),
        ("['red cube', 'blue cube']", "is not a cube"),
    ],
)
def test_parser_refuses_malformed_answers_with_a_reason(text: str, reason: str) -> None:
    parsed = EIGHT.parse(text)
    assert not parsed.ok and parsed.solution is None
    assert reason in (parsed.error or "")


def test_guidance_follows_the_solution() -> None:
    solution = EIGHT.target
    assert EIGHT.guidance((), solution) == E + 1
    assert EIGHT.guidance((E, F, G), solution) == A + 1
    assert EIGHT.guidance(solution, solution) == H + 1  # a no-op re-add on the full stack
    assert EIGHT.guidance((E, A), solution) == 0  # off the solution: remove
    assert EIGHT.guidance((E, F), (E, F, E)) is None  # next cube already stacked: nothing to ask


def test_mock_is_wrong_on_short_prefixes_and_right_on_long_ones() -> None:
    rng = np.random.default_rng(0)
    outcomes = []
    for length in range(0, 9):
        answer = extrapolate(EIGHT.prompt(EIGHT.target[:length]), 0.0, rng)
        outcomes.append(EIGHT.parse(answer).solution == EIGHT.target)
    # [e]: colour grouping (primed by the descriptor's example) predicts e,f,g,h,a,b,c,d, as
    # GPT did in the authors' cache; from [e,f,g,a] only "largest first" fits.
    assert outcomes == [False, False, False, False, True, True, True, True, True]
    assert extrapolate(EIGHT.prompt((E,)), 0.0, rng) == "['e', 'f', 'g', 'h', 'a', 'b', 'c', 'd']"


def test_mock_reads_only_the_prompt() -> None:
    """The extrapolator answers from the descriptor in the text, whatever the target is."""
    prompt = EIGHT.prompt((A, D, B)).replace("edge length 3cm", "edge length 1cm")
    orders = consistent_orders(prompt)
    assert all(order[:3] == ["a", "d", "b"] for _, order in orders)
    with pytest.raises(ValueError, match="cube-stacking prompt"):
        consistent_orders("hello")


def test_mock_samples_consistent_orders_at_temperature_one() -> None:
    prompt = EIGHT.prompt((E,))
    allowed = {" ".join(order) for _, order in consistent_orders(prompt)}
    draws = [extrapolate(prompt, 1.0, np.random.default_rng(seed)) for seed in range(60)]
    letters = {" ".join(ch for ch in d if ch.isalpha()) for d in draws}
    assert letters <= allowed and len(letters) > 1
    again = [extrapolate(prompt, 1.0, np.random.default_rng(seed)) for seed in range(60)]
    assert draws == again


def test_upstream_state_key_merges_only_the_sorted_prefixes() -> None:
    target = EIGHT.target
    shared = {upstream_state_key(s, target) for s in [(), (E,), (E, F), (E, F, G)]}
    assert len(shared) == 1
    assert upstream_state_key((E, F, G, A), target) == (E, F, G, A)
    assert upstream_state_key((A,), target) == (A,)  # a wrong stack keeps its own row
