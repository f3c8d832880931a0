"""The built-in tasks are registered as plugins are: their specs name functions of
``lagrseq.builtin_tasks``, and what running needs of a task (its state index, the length of a
pattern, its extras) comes through the spec or the task's own attributes."""

from __future__ import annotations

import numpy as np
import pytest

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from lagrseq.registry import TASKS
from lagrseq.running import wiring
from lagrseq.tasks.cube import CubeStacking, format_stack

BUILT_IN = ("cube-stacking", "image-completion", "object-arrangement", "arm-arrangement")


@pytest.mark.parametrize("name", BUILT_IN)
def test_a_built_in_spec_names_its_own_module_for_every_task_function(name: str) -> None:
    spec = TASKS.get(name)
    hooks = [spec.make_task, spec.make_env, spec.extrapolator, spec.profiles, spec.guide, spec.views, spec.view_topics, spec.miss_calibration]
    named = [hook.__qualname__ for hook in hooks if hook is not None and callable(hook)]
    named += [hook.__qualname__ for hook in spec.state_keys.values()]
    assert named and all(target.startswith("lagrseq.builtin_tasks.") for target in named), named


@pytest.mark.parametrize("name", BUILT_IN)
def test_a_built_in_task_is_built_through_its_spec(name: str) -> None:
    config = cfg.load(name, "lagr-seq", "upstream", None, [])
    task = wiring.make_task(config)
    assert task.name
    assert wiring.extrapolator(config)(task.prompt(task_start(task)), 0.0, np.random.default_rng(0))


def task_start(task: object) -> object:
    """The first pattern of ``task``: an empty stack, or an empty grid."""
    return () if isinstance(task, CubeStacking) else np.zeros_like(task.target)  # type: ignore[attr-defined]


def test_the_aliased_state_index_comes_from_the_cube_spec() -> None:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", None, [])
    task = wiring.make_task(config)
    assert isinstance(task, CubeStacking)
    assert wiring.state_key(config, task, "exact") is None
    key = wiring.state_key(config, task, "upstream-aliased")
    assert key is not None
    target = task.target
    shared = {key(target[:n]) for n in range(4)}  # [], [e], [e,f], [e,f,g]: one row
    assert len(shared) == 1
    assert key(target[:4]) == target[:4]


def test_a_state_index_the_task_lacks_is_one_line_naming_who_has_it() -> None:
    config = cfg.load("image-completion", "lagr-seq", "upstream", None, [])
    with pytest.raises(ConfigError, match=r"'upstream-aliased' is a state index of cube-stacking, not of image-completion; use exact"):
        wiring.state_key(config, wiring.make_task(config), "upstream-aliased")


def test_the_neural_seq_agent_reads_the_pattern_length_from_the_task() -> None:
    image = cfg.load("image-completion", "lagr-seq", "upstream", None, [])
    assert wiring.pattern_cells(image, wiring.make_task(image)) == 100
    cube = cfg.load("cube-stacking", "lagr-seq", "upstream", None, [])
    with pytest.raises(ConfigError, match="task cube-stacking has no cells: use a tabular"):
        wiring.pattern_cells(cube, wiring.make_task(cube))


def test_the_cube_tells_the_census_a_partial_answer_and_what_a_prompt_shows() -> None:
    task = CubeStacking(8)
    assert task.is_partial(task.target[:3]) and not task.is_partial(task.target)
    assert task.shown(task.prompt(task.target[:3])) == 3
    with pytest.raises(ValueError):
        task.shown(f"not a cube prompt {format_stack(task.target)}")
