"""What made a number: the provenance class of a run, read from its logged provider and configuration.

Every scoreboard row, table cell and figure line of the report names one of these classes, so that
a reader can tell a replay of real answers from a simulation, and a simulation from a fit:

* ``authors' answers``: replayed from the paper authors' recorded GPT answers (the store that
  ``lagrseq reproduce --authors-caches`` imports; misses are answered by a fallback and counted
  beside the number).
* ``open model``: the recorded (or live, or local) answers of a named model other than the
  authors' GPT runs, e.g. SmolLM2-135M-Instruct in ``recorded_llm/``.
* ``fitted``: a mock profile whose parameters were chosen to match the paper or calibrated on the
  answers it is compared with: every ``mock:authors-*`` profile, and at tau > 0 its temperature
  model; and a run on a store whose misses a calibrated draw answered (``--on-miss calibrated``). A fitted number is never called reproduced (:data:`lagrseq.analysis.inference.FITTED`).
* ``rule-based mock``: the target-blind extrapolator (``mock``, ``mock:ideal``) or a profile fixed
  by definition (``mock:oracle``, ``mock:refuse``), with nothing tuned to a paper number.
* ``no LLM``: a run that never asks (the Q-learning baseline), whatever provider its log names.

The class is derived here, from the run's logged ``provider`` and ``config`` only, never from the
labels a suite file types, so a relabelled suite cannot turn a fitted number into a replayed one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import PurePath
from typing import Any

from lagrseq.registry import CALIBRATED_MISS, kind_of
from lagrseq.suite import MISS_VARIANT

AUTHORS = "authors' answers"
OPEN_MODEL = "open model"
FITTED = "fitted"
RULE_BASED = "rule-based mock"
NO_LLM = "no LLM"
UNKNOWN = "unknown"
CLASSES = (AUTHORS, OPEN_MODEL, FITTED, RULE_BASED, NO_LLM)

AUTHORS_STORE_NAME = "authors-answers"
"""The store ``reproduce --authors-caches`` imports into (the same name as
:data:`lagrseq.suite.AUTHORS_STORE_NAME`, which tests keep equal)."""
FITTED_PROFILE_PREFIX = "authors-"
"""Mock profiles calibrated on the authors' answers (``mock:authors-t0``, ``mock:authors-gpt4``)."""
BASELINE = "baseline"


@dataclass(frozen=True)
class Provenance:
    """A provenance class and one sentence on why this run has it."""

    kind: str
    why: str

    def __str__(self) -> str:
        return self.kind


def provenance(provider: str, config: Mapping[str, Any], method: str | None = None, on_miss: str = "") -> Provenance:
    """The provenance class of a run logged with ``provider`` (its spec, ``kind[:argument]``) and
    ``config`` (its resolved configuration as the log stores it); ``method`` defaults to the
    config's own; ``on_miss``: what answered its store's misses (its logged provider options):
    ``calibrated`` makes a run on a store ``fitted``. Anything the log does not say is treated as
    what it says least about (``unknown``)."""
    method = str(config.get("method", "")) if method is None else method
    llm = config.get("llm", {})
    llm = llm if isinstance(llm, Mapping) else {}
    model = str(llm.get("model", "") or "")
    try:
        temperature = float(llm.get("temperature", 0.0) or 0.0)
    except (TypeError, ValueError):
        temperature = 0.0
    if method == BASELINE:
        return Provenance(NO_LLM, "Q-learning never queries an LLM")
    kind, _, argument = str(provider).partition(":")
    spec = kind_of(str(provider))
    if spec is None:
        return Provenance(UNKNOWN, f"provider {provider!r} is not one lagrseq knows")
    if spec.synthetic:
        if argument.startswith(FITTED_PROFILE_PREFIX):
            if temperature > 0:
                return Provenance(
                    FITTED,
                    f"mock:{argument} at tau = {temperature:g}: its temperature model was chosen to follow the paper's trend "
                    "(no tau > 0 answers were published)",
                )
            return Provenance(FITTED, f"mock:{argument} was calibrated on the authors' answers")
        name = argument or "the rule-based extrapolator"
        return Provenance(RULE_BASED, f"mock {name}: nothing in it was tuned to a paper number")
    if spec.replays:
        if on_miss == CALIBRATED_MISS:
            return Provenance(
                FITTED,
                "the store's misses were answered by a draw at acceptance rates fitted to the store's own answers "
                "(--on-miss calibrated)",
            )
        if PurePath(argument.rstrip("/")).name == AUTHORS_STORE_NAME:
            return Provenance(AUTHORS, "the paper authors' recorded GPT answers (misses answered by a fallback, counted)")
        where = PurePath(argument.rstrip("/")).name or argument
        return Provenance(OPEN_MODEL, f"recorded answers of {model or 'a model'} ({where})")
    return Provenance(OPEN_MODEL, f"{kind} answers of {argument or model or 'a model'}")


def of_run(run: Any) -> Provenance:
    """:func:`provenance` of a loaded run (:class:`lagrseq.analysis.loading.Run`)."""
    variant = str(getattr(run.key, "variant", "") or "")
    on_miss = variant[len(MISS_VARIANT):] if variant.startswith(MISS_VARIANT) else ""
    return provenance(run.key.provider, run.config, run.key.method, on_miss)


def combined(parts: list[Provenance]) -> Provenance:
    """The provenance of a number made from several runs (a ratio, a reduction): the weakest
    part decides (fitted over anything; then the mock; a baseline adds nothing)."""
    order = (UNKNOWN, FITTED, RULE_BASED, OPEN_MODEL, AUTHORS, NO_LLM)
    chosen = [p for p in parts if p.kind != NO_LLM] or parts
    if not chosen:
        return Provenance(UNKNOWN, "no run")
    return min(chosen, key=lambda p: order.index(p.kind) if p.kind in order else 0)


def replays(run: Any) -> bool:
    """Whether a loaded run's provider replays stored answers (a recorded store)."""
    spec = kind_of(str(run.key.provider))
    return spec is not None and spec.replays


def decided_by_fallback(run: Any) -> list[bool]:
    """Per trial of a loaded run (in ``run.trials`` order): whether its first accepted answer came
    from a fallback rather than the stored answers it replays (any ``source`` other than a stored
    one: the rule-based mock answering a miss, a ``miss`` record, a live call). In such a trial
    the fallback, not the named source, decided when the agent first got a usable suggestion, so
    no verdict may rest on it (the scoreboard, :mod:`lagrseq.analysis.frontier`, the tables'
    cells). A trial without an accepted answer, and every trial of a run whose provider replays
    nothing, is not decided by a fallback."""
    from lagrseq.registry import stored_sources

    trials = list(run.trials)
    q = run.queries
    if not replays(run) or q.empty:
        return [False] * len(trials)
    taken = q[q["queried"].fillna(False).astype(bool) & q["accepted"].fillna(False).astype(bool)]
    stored = stored_sources()
    first: dict[int, bool] = {}
    for trial, group in taken.groupby("trial", sort=True):
        row = group.sort_values(["global_step", "step"], kind="stable").iloc[0]
        first[int(trial)] = str(row["source"] or "") not in stored
    return [first.get(int(t), False) for t in trials]
