"""lagrseq-numseq: an example lagrseq plugin.

It adds, through entry points (see this package's ``pyproject.toml``):

- the task ``number-sequence`` (group ``lagrseq.tasks``): write an arithmetic sequence one number
  at a time, with its Gymnasium env, prompt, parser, evaluation, guidance and a rule-based mock
  extrapolator, plus two presets and its own suite (``suite.toml``: what ``lagrseq replay``
  draws for its logs without ``--suite``); its env logs a field of its own, ``wrong_numbers`` per episode;
- the asking policy ``backoff`` (group ``lagrseq.policies``): ask with probability
  ``ask_probability``, multiplied by its own knob ``backoff_factor`` (default 0.5: halved) after
  every rejected answer of the episode.

This module stays light: it imports the task and the policy, not gymnasium (the env is built
only when a run needs it), so listing plugins or replaying logs never loads the env.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from lagrseq.config import TabularConfig, TabularSecondaryConfig
from lagrseq.registry import Knob, PolicySpec, TaskSpec
from lagrseq_numseq.config import NumSeqEnvConfig, NumSeqTaskConfig

NAME = "number-sequence"


def _make_task(config: Any) -> Any:
    from lagrseq_numseq.task import NumberSequence

    return NumberSequence(config.task.start, config.task.step, config.task.length, config.task.values)


def _make_env(config: Any, render_dir: Path | None) -> Any:
    from lagrseq_numseq.env import NumberSequenceEnv

    return NumberSequenceEnv(_make_task(config), horizon=config.env.horizon, bonus=config.env.bonus)


def _extrapolator(config: Any, profile: str) -> Callable[..., str]:
    from lagrseq.errors import UsageError
    from lagrseq_numseq.task import extrapolate

    if profile != "ideal":
        raise UsageError(f"mock profile {profile!r}: {NAME} has the ideal mock only (--provider mock)")
    return extrapolate


EPISODE_FIELDS = {"wrong_numbers": "integer"}
"""The task's own ``/episode`` field: the numbers its env refused in the episode (the env's
``info["log_episode"]``); ``lagrseq replay`` shows its mean per episode in the runs table."""


def task_spec() -> TaskSpec:
    """The ``lagrseq.tasks`` entry point."""
    return TaskSpec(
        name=NAME,
        sections={"task": NumSeqTaskConfig, "env": NumSeqEnvConfig, "primary": TabularConfig, "secondary": TabularSecondaryConfig},
        presets=Path(__file__).parent / "presets",
        make_task=_make_task,
        make_env=_make_env,
        extrapolator=_extrapolator,
        episode_fields=EPISODE_FIELDS,
        description="write an arithmetic sequence one number at a time (example plugin)",
        suite="lagrseq_numseq:suite.toml",  # its own suite: `lagrseq replay` draws it without --suite
    )


def _make_backoff(section: Any, seq_agent: Callable[[], Any]) -> Any:
    from lagrseq_numseq.policy import Backoff

    return Backoff(section.ask_probability, section.knob("backoff_factor"))


BACKOFF_FACTOR = Knob(
    "backoff_factor", 0.5, ge=0.0, le=1.0, candidates=("0.25", "0.5", "0.75"),
    help="what the asking probability is multiplied by after a rejected answer (0.5: halved)",
)
"""``backoff``'s own knob: ``[secondary] backoff_factor``, ``--set secondary.backoff_factor=V``,
``lagrseq frontier --policies backoff:backoff_factor=V``."""


def policy_spec() -> PolicySpec:
    """The ``lagrseq.policies`` entry point."""
    return PolicySpec(
        name="backoff",
        make=_make_backoff,
        knobs=("ask_probability", "min_progress", "budget", "budget_scope", "query_cost", BACKOFF_FACTOR),
        order=20,
        description="ask with probability ask_probability, times backoff_factor after each rejected answer of the episode (example plugin)",
    )
