"""lagr.py: each trigger kind, acceptance at the threshold, the query sent, and pi_LLM."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from lagrseq.config import LagrConfig, LLMConfig
from lagrseq.llm.base import Answer, Query, Usage
from lagrseq.loop.lagr import QueryTrigger, consult, follows, query_for
from lagrseq.tasks.cube import LETTERS, CubeStacking

TASK = CubeStacking(8)
LLM = LLMConfig(model="m", temperature=0.5, max_tokens=64)


class Fixed:
    """A provider that answers one text and remembers what it was asked."""

    name = "fixed"

    def __init__(self, text: str) -> None:
        self.text = text
        self.asked: list[Query] = []

    def complete(self, query: Query) -> Answer:
        self.asked.append(query)
        return Answer(self.text, "stop", "m", Usage(10, 5), 0.0, "mock")

    def close(self) -> None:
        return None


def letters(ids: tuple[int, ...]) -> str:
    return ",".join(LETTERS[i] for i in ids)


def test_positive_reward_trigger_fires_only_after_a_positive_reward() -> None:
    trigger = QueryTrigger("positive-reward")
    assert not trigger.armed(3, 0.0) and not trigger.armed(3, -1.0)
    assert trigger.armed(0, 1e-9) and trigger.armed(5, 8.0)


def test_new_max_prefix_trigger_waits_for_progress_past_the_last_query() -> None:
    trigger = QueryTrigger("new-max-prefix")
    assert not trigger.armed(0, 5.0), "an empty stack has made no progress"
    assert trigger.armed(1, 0.0)
    trigger.queried(3)
    assert not trigger.armed(3, 1.0) and not trigger.armed(2, 1.0)
    assert trigger.armed(4, 0.0)
    trigger.reset_episode()
    assert trigger.armed(1, 0.0), "a new episode starts from nothing"


def test_every_step_trigger_always_fires() -> None:
    trigger = QueryTrigger("every-step")
    trigger.queried(8)
    assert trigger.armed(0, -1.0) and trigger.armed(8, 0.0)


def test_query_is_the_tasks_prompt_with_the_llm_settings() -> None:
    query = query_for(TASK, LLM, (4, 5))
    assert query.prompt == TASK.prompt((4, 5))
    assert (query.model, query.temperature, query.max_tokens, query.task) == ("m", 0.5, 64, TASK.name)


def test_the_right_answer_is_accepted_at_the_threshold() -> None:
    provider = Fixed(letters(TASK.target))
    result = consult(TASK, provider, LLM, 1.0, (4,))
    assert result.evaluation == 1.0 and result.accepted
    assert result.parsed.solution == TASK.target
    assert result.prompt_sha256 == hashlib.sha256(TASK.prompt((4,)).encode()).hexdigest()
    assert provider.asked[0].prompt == TASK.prompt((4,))


@pytest.mark.parametrize("threshold", [0.5, 0.9, 1.0])
def test_acceptance_is_evaluation_at_least_threshold(threshold: float) -> None:
    # the target with its last two cubes swapped: C = 6 of 8, E = 8 * 6 / 64 = 0.75
    wrong = TASK.target[:6] + (TASK.target[7], TASK.target[6])
    result = consult(TASK, Fixed(letters(wrong)), LLM, threshold, (4,))
    assert result.evaluation == pytest.approx(0.75)
    assert result.accepted == (threshold <= 0.75)
    exactly = consult(TASK, Fixed(letters(wrong)), LLM, 0.75, (4,))
    assert exactly.accepted, "E == threshold is accepted (>=)"


def test_an_unparseable_answer_is_a_wrong_answer_with_its_reason() -> None:
    result = consult(TASK, Fixed("I think the answer is blue."), LLM, 0.0, (4,))
    assert result.evaluation == 0.0 and not result.accepted and not result.parsed.ok
    assert result.parsed.error


def test_pi_llm_adds_the_next_cube_of_the_solution() -> None:
    target = TASK.target
    assert TASK.guidance(target[:3], target) == target[3] + 1
    assert TASK.guidance(target[:3], target[:2] + (target[5],)) == 0, "off the solution: remove"
    rng = np.random.default_rng(0)
    assert follows(LagrConfig(follow_probability=1.0), rng)  # P = 1: pi_LLM acts at every step
    assert TASK.guidance(target[:1], target, None) == target[1] + 1


def test_follow_probability_one_draws_nothing_and_p_is_honoured() -> None:
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    assert follows(LagrConfig(follow_probability=1.0), rng)
    assert rng.bit_generator.state == state, "P = 1 draws nothing from the guidance stream"
    draws = [follows(LagrConfig(follow_probability=0.3), np.random.default_rng(s)) for s in range(2000)]
    assert 0.25 < np.mean(draws) < 0.35
    assert not any(follows(LagrConfig(follow_probability=0.0), np.random.default_rng(s)) for s in range(50))
