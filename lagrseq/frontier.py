"""``lagrseq frontier``: run asking policies on one task and provider, then draw the frontier.

Each policy variant is an ordinary run (``lagrseq run``'s directories and resume): ``never`` is
``--method baseline``, ``always`` is ``--method lagr``, every other policy is ``--method lagr-seq``
with ``secondary.policy`` and its knobs set. The report (``lagrseq.analysis.frontier``) is rebuilt
from the MCAP logs alone, by the same command with ``--replay``.

A policy item is ``NAME`` or ``NAME:FIELD=VALUE[:FIELD=VALUE...]`` with FIELD a ``[secondary]``
field (``thompson:query_cost=0.5``, ``random:ask_probability=0.1``, ``seq:budget=20``); a sweep
``NAME:FIELD=V1,V2,...`` adds one variant per value (drawn as a curve).
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq.errors import UsageError
from lagrseq.registry import POLICIES


def policy_names() -> tuple[str, ...]:
    """Every registered asking policy, in frontier order."""
    return tuple(spec.name for spec in sorted(POLICIES.specs(), key=lambda spec: spec.order))


def policy_knobs() -> tuple[str, ...]:
    """The ``[secondary]`` fields a policy item may set: every registered policy's knobs."""
    out: list[str] = []
    for spec in POLICIES.specs():
        out += [knob for knob in spec.knobs if knob not in out]
    return tuple(out)


def __getattr__(name: str) -> Any:
    if name == "NAMES":  # read lazily: plugins add policies
        return policy_names()
    if name == "KNOBS":
        return policy_knobs()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass(frozen=True)
class Variant:
    """One point of the frontier: a method and the ``--set`` overrides that make its policy."""

    policy: str
    knobs: tuple[tuple[str, str], ...] = ()

    @property
    def method(self) -> str:
        """The policy's own method without knobs (``never``: baseline, ``always``: lagr), else
        ``lagr-seq``."""
        return "lagr-seq" if self.knobs else POLICIES.get(self.policy).method

    def overrides(self) -> list[str]:
        sets = [] if self.method != "lagr-seq" else [f'secondary.policy="{self.policy}"']
        return sets + [f"secondary.{field}={value}" for field, value in self.knobs]

    def __str__(self) -> str:
        return ":".join([self.policy, *(f"{k}={v}" for k, v in self.knobs)])


def _item(text: str) -> tuple[str, list[tuple[str, str]]]:
    name, *parts = text.strip().split(":")
    if name not in policy_names():
        raise UsageError(f"policy {name!r} in {text!r}; expected one of {', '.join(policy_names())} (optionally NAME:FIELD=VALUE)")
    knobs: list[tuple[str, str]] = []
    allowed = policy_knobs()
    for part in parts:
        field, sep, value = part.partition("=")
        if not sep or field not in allowed or not value:
            raise UsageError(f"{text!r}: expected NAME:FIELD=VALUE with FIELD one of {', '.join(allowed)}")
        if any(field == seen for seen, _ in knobs):
            raise UsageError(f"{text!r} sets {field} twice; give each field once (for several values: --sweep {name}:{field}=V1,V2)")
        knobs.append((field, value))
    return name, knobs


def parse_policies(text: str) -> list[Variant]:
    """``never,always,seq,thompson:query_cost=0.5`` -> variants (duplicates dropped)."""
    variants: list[Variant] = []
    for item in text.split(","):
        if not item.strip():
            continue
        name, knobs = _item(item)
        variant = Variant(name, tuple(knobs))
        if variant not in variants:
            variants.append(variant)
    if not variants:
        raise UsageError("--policies is empty; expected e.g. never,always,seq,thompson")
    return variants


def parse_sweep(text: str) -> list[Variant]:
    """``thompson:query_cost=0.2,0.5,1`` -> one variant per value (other knobs first, as given)."""
    head, sep, tail = text.rpartition("=")
    if not sep or ":" not in head:
        raise UsageError(f"--sweep {text!r}: expected NAME:FIELD=V1,V2,... e.g. thompson:query_cost=0.2,0.5,1")
    prefix, _, field = head.rpartition(":")
    values = [v.strip() for v in tail.split(",") if v.strip()]
    if not values:
        raise UsageError(f"--sweep {text!r}: no values after '='")
    out = []
    for value in values:
        name, knobs = _item(f"{prefix}:{field}={value}")
        out.append(Variant(name, tuple(knobs)))
    return out


def run_frontier(
    task: str,
    variants: Sequence[Variant],
    provider: str,
    options: Any,
    out: Path,
    trials: int,
    seed: int,
    preset: str,
    config_file: Path | None,
    overrides: Sequence[str],
    jobs: int,
    progress: Callable[[str, int, str], Any] | None = None,
    say: Callable[[str], None] = print,
) -> list[Path]:
    """Run every variant (skipping finished trials) into ``out``; returns the run directories.
    All variants' trials go to one pool at once, so with ``jobs`` workers no worker idles at the
    end of one policy's trials. ``progress(label, total, unit)`` makes a progress bar (a context
    manager with ``update``)."""
    from lagrseq import runner

    prepared = []
    for variant in variants:  # every configuration is checked before any trial starts
        config, directory = runner.prepare(
            task, variant.method, preset, config_file, [*overrides, *variant.overrides()], provider, options, out, seed
        )
        prepared.append((variant, config, directory))
    unit, per_trial = runner.progress_unit(prepared[0][1])  # one task and run length: one unit
    with contextlib.ExitStack() as stack:
        bar = None
        if progress is not None:
            label = f"{task}: {len(prepared)} polic{'ies' if len(prepared) != 1 else 'y'} x {trials} trials"
            bar = stack.enter_context(progress(label, len(prepared) * trials * per_trial, unit))
        sweep = [runner.SweepRun(config, trials, seed, provider, directory, options, progress=bar) for _, config, directory in prepared]
        outcome = runner.run_sweep(sweep, jobs, say=say, warn=say)
    for (variant, _, directory), results in zip(prepared, outcome, strict=True):
        say(f"{variant}: " + runner.summary(results, directory, provider).replace("\n", "; "))
    return [d for _, _, d in prepared]


def variants_of(policies: str, sweeps: Sequence[str]) -> list[Variant]:
    """The variants of ``--policies`` and every ``--sweep``, duplicates dropped."""
    variants = parse_policies(policies)
    for sweep in sweeps:
        variants += [v for v in parse_sweep(sweep) if v not in variants]
    return variants


def runs_or_replay(
    task: str | None,
    replay: Path | None,
    variants: Sequence[Variant],
    provider: str,
    options: Any,
    out: Path,
    trials: int,
    seed: int,
    preset: str,
    config_file: Path | None,
    overrides: Sequence[str],
    jobs: int,
    progress: Callable[[str, float, str], Any],
) -> tuple[Path, list[Path]]:
    """``lagrseq frontier``'s runs: with ``replay``, the logs under it (no trial runs); else every
    variant run on ``task`` under ``out`` and indexed. Returns the report's folder and the run
    directories it reads."""
    from lagrseq.paths import writable_directory

    if replay is not None:
        if task is not None:
            raise UsageError(f"--replay rebuilds the report from the logs under {replay}; give no TASK with it")
        if not replay.is_dir():
            raise UsageError(f"--replay {replay}: not a directory of run logs")
        return writable_directory(out), [replay]
    if task is None:
        raise UsageError("frontier needs a TASK (or --replay DIR)")
    directories = run_frontier(  # out is made by run_frontier once every configuration is checked
        task, list(variants), provider, options, out, trials, seed, preset, config_file,
        list(overrides), jobs, progress=progress,
    )
    write_index(out, variants, directories)
    return out / "frontier", list(directories)


def write_index(out: Path, variants: Sequence[Variant], directories: Sequence[Path]) -> Path:
    """``frontier.json``: which run directory holds which policy (the report itself needs only
    the logs)."""
    path = out / "frontier.json"
    entries = [{"policy": str(v), "method": v.method, "directory": str(d)} for v, d in zip(variants, directories, strict=True)]
    path.write_text(json.dumps(entries, indent=1) + "\n", encoding="utf-8")
    return path
