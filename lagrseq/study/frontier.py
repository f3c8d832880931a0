"""``lagrseq frontier``: run asking policies on one task and provider, then draw the frontier.

Each policy variant is an ordinary run (``lagrseq run``'s directories and resume): ``never`` is
``--method baseline``, ``always`` is ``--method lagr``, every other policy is ``--method lagr-seq``
with ``secondary.policy`` and its knobs set. The report (``lagrseq.analysis.frontier``) is rebuilt
from the MCAP logs alone, by the same command with ``--replay``.

A policy item is ``NAME`` or ``NAME:FIELD=VALUE[:FIELD=VALUE...]`` with FIELD a ``[secondary]``
field (``thompson:query_cost=0.5``, ``random:ask_probability=0.1``, ``seq:budget=20``); a sweep
``NAME:FIELD=V1,V2,...`` adds one variant per value (drawn as a curve).

The protocol (docs/frontier.md; the verdicts are :mod:`lagrseq.analysis.frontier`'s):

- regimes: every variant runs under each ``lagr.solution_scope`` asked for (``episode``: an
  accepted answer guides one episode, so a policy must ask again; ``trial``: it guides the rest of
  the trial);
- random at a matched rate: after the variants, every learning policy's run is read back and
  ``random`` runs at its mean query rate (queries / decisions, :func:`lagrseq.frontier_protocol.matched_probability`);
- ``--tune``: each named policy's knob (:data:`TUNE_GRID`) is chosen on tuning seeds (another
  run seed, so no trial shares a seed with the evaluation) by :data:`TUNE_RULE`, the choice is
  written into the evaluation logs' metadata (:data:`lagrseq.frontier_protocol.TUNING_NOTE`), then evaluated. The variants
  as given stay: they are the task-agnostic settings, the same on every task.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq import outputs
from lagrseq.errors import UsageError
from lagrseq.frontier_protocol import TUNING_NOTE, matched_probability, wants_match
from lagrseq.progress import Reporter
from lagrseq.registry import POLICIES, TASKS, knob_names, tuned_knob


def tune_grid() -> dict[str, tuple[str, tuple[str, ...]]]:
    """Policy -> the knob ``--tune`` chooses and its candidate values (each registered policy's
    first knob with candidates, ``registry.tuned_knob``); read as ``TUNE_GRID``."""
    grid: dict[str, tuple[str, tuple[str, ...]]] = {}
    for spec in POLICIES.specs():
        knob = tuned_knob(spec)
        if knob is not None:
            grid[spec.name] = (knob.name, knob.candidates)
    return grid


TUNE_RULE = (
    "fewest mean queries among the settings non-inferior to always on steps to the first solve "
    "(margin 10% of always's mean, one-sided paired t test on the tuning trials, Welch where a trial is missing, "
    "alpha 0.05); if none is, the best mean steps"
)
TUNE_OFFSET = 1_000_003
"""Default tuning seed: the evaluation seed plus this (a different run seed: disjoint trials)."""
SCOPES = ("episode", "trial")

def policy_names() -> tuple[str, ...]:
    """Every registered asking policy, in frontier order."""
    return tuple(spec.name for spec in sorted(POLICIES.specs(), key=lambda spec: spec.order))


def policy_knobs() -> tuple[str, ...]:
    """The knobs a policy item may set: every registered policy's (shared fields and own knobs)."""
    out: list[str] = []
    for spec in POLICIES.specs():
        out += [knob for knob in knob_names(spec) if knob not in out]
    return tuple(out)


def __getattr__(name: str) -> Any:
    if name == "NAMES":  # read lazily: plugins add policies
        return policy_names()
    if name == "KNOBS":
        return policy_knobs()
    if name == "TUNE_GRID":
        return tune_grid()
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
    allowed = knob_names(POLICIES.get(name))  # a knob belongs to its policy: another's would be ignored
    for part in parts:
        field, sep, value = part.partition("=")
        if sep and value and field not in allowed and field in policy_knobs():
            owners = ", ".join(spec.name for spec in POLICIES.specs() if field in knob_names(spec))
            raise UsageError(
                f"{text!r}: {field} is a knob of {owners}, not of {name}, which would ignore it; "
                f"{name}'s knobs: {', '.join(allowed) or 'none'}"
            )
        if not sep or field not in allowed or not value:
            raise UsageError(f"{text!r}: expected NAME:FIELD=VALUE with FIELD one of {', '.join(allowed) or 'none (' + name + ' has no knobs)'}")
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


@dataclass(frozen=True)
class Tuning:
    """``--tune``: the tuning run seed and trials per candidate."""

    seed: int
    trials: int


@dataclass(frozen=True)
class Frontier:
    """What :func:`run_protocol` ran (every run directory) and what ``--tune`` chose."""

    directories: list[Path]
    variants: list[Variant]
    chosen: dict[str, dict[str, Any]]
    """Per scope and policy (``"episode/thompson"``): the tuning note written into the logs."""


def run_protocol(
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
    reporter: Reporter | None = None,
    scopes: Sequence[str | None] = (None,),
    matched_random: bool = False,
    tune: Tuning | None = None,
) -> Frontier:
    """Per solution scope (None: the preset's): ``--tune``'s tuning runs and choice, the variants
    and the chosen settings on the evaluation seed, then random at each learning policy's matched
    rate. Every configuration of a phase is checked before any of its trials starts."""
    if tune is not None and tune.seed == seed:
        raise UsageError(f"--tune-seed {tune.seed} is the evaluation seed; tuning must use other seeds")
    reporter = reporter or Reporter()
    directories: list[Path] = []
    ran: list[Variant] = []
    chosen: dict[str, dict[str, Any]] = {}
    for scope in scopes:
        extra = [*overrides, f'lagr.solution_scope="{scope}"'] if scope else list(overrides)
        where = f" ({scope} scope)" if scope else ""

        def phase(
            todo: Sequence[tuple[Variant, dict[str, str] | None]], run_seed: int, count: int, what: str,
            extra: list[str] = extra, where: str = where,
        ) -> list[Path]:
            return _run_phase(
                task, todo, provider, options, out, count, run_seed, preset, config_file, extra, jobs,
                progress, reporter, what + where,
            )

        notes: dict[Variant, dict[str, str]] = {}
        extra_variants: list[Variant] = []
        if tune is not None:
            for policy, note in _tune(task, variants, phase, tune, seed).items():
                chosen[f"{scope or 'preset'}/{policy}"] = note
                best = Variant(policy, ((tune_grid()[policy][0], str(note["chosen"])),))
                twin = next((v for v in variants if _same(v, best)), None)
                target = twin or best
                notes[target] = {TUNING_NOTE: json.dumps(note, sort_keys=True)}
                if twin is None and best not in extra_variants:
                    extra_variants.append(best)
        evaluated = [*variants, *extra_variants]
        done = phase([(v, notes.get(v)) for v in evaluated], seed, trials, "evaluation")
        directories += done
        ran += evaluated
        if matched_random:
            wanted: list[Variant] = []
            for variant, directory in zip(evaluated, done, strict=True):
                if not wants_match(variant.policy, variant.knobs):
                    continue
                queries, decisions = _rate(directory, trials)
                if decisions == 0 or queries == 0:
                    reporter.say(f"{variant}{where}: asked nothing, no random run at its rate")
                    continue
                p = matched_probability(queries, decisions)
                if p >= 1.0:  # random at rate 1 asks at every trigger: always is that run
                    continue
                match = Variant("random", (("ask_probability", f"{p:g}"),))
                if match not in wanted and not any(_same(match, v) for v in evaluated):
                    wanted.append(match)
            if wanted:
                directories += phase([(v, None) for v in wanted], seed, trials, "random at the matched rates")
                ran += wanted
    return Frontier(directories, ran, chosen)


def _same(a: Variant, b: Variant) -> bool:
    """Two variants that make the same configuration (a knob at its default is no knob)."""
    defaults = {"query_cost": 0.0, "budget": 0.0, "min_progress": 0.0, "ask_probability": 0.5}

    def knobs(v: Variant) -> dict[str, str]:
        out = {}
        for field, value in v.knobs:
            try:
                if float(value) == defaults.get(field):
                    continue
                out[field] = f"{float(value):g}"
            except ValueError:
                out[field] = value
        return out

    return a.method == b.method and a.policy == b.policy and knobs(a) == knobs(b)


def _run_phase(
    task: str,
    todo: Sequence[tuple[Variant, dict[str, str] | None]],
    provider: str,
    options: Any,
    out: Path,
    trials: int,
    seed: int,
    preset: str,
    config_file: Path | None,
    overrides: Sequence[str],
    jobs: int,
    progress: Callable[[str, int, str], Any] | None,
    reporter: Reporter,
    what: str,
) -> list[Path]:
    """Run ``todo``'s variants (with their run-metadata notes) as one pool: all trials at once, so
    with ``jobs`` workers no worker idles at the end of one policy's trials."""
    from lagrseq.running import runner

    prepared = []
    for variant, notes in todo:  # every configuration is checked before any trial starts
        config, directory = runner.prepare(
            task, variant.method, preset, config_file, [*overrides, *variant.overrides()], provider, options, out, seed
        )
        prepared.append((variant, config, directory, notes))
    unit, per_trial = runner.progress_unit(prepared[0][1])  # one task and run length: one unit
    with contextlib.ExitStack() as stack:
        bar = None
        if progress is not None:
            label = f"{task} {what}: {len(prepared)} polic{'ies' if len(prepared) != 1 else 'y'} x {trials} trials"
            bar = stack.enter_context(progress(label, len(prepared) * trials * per_trial, unit))
        sweep = [
            runner.SweepRun(config, trials, seed, provider, directory, options, progress=bar, notes=notes)
            for _, config, directory, notes in prepared
        ]
        outcome = runner.run_sweep(sweep, jobs, reporter=reporter)
    for (variant, _, directory, _), results in zip(prepared, outcome, strict=True):
        reporter.say(f"{variant} [{what}]: " + runner.summary(results, directory, provider).replace("\n", "; "))
    return [d for _, _, d, _ in prepared]


def _logs(directory: Path, trials: int) -> list[Path]:
    from lagrseq.running.runner import trial_path

    return [trial_path(directory, t) for t in range(trials) if trial_path(directory, t).is_file()]


def matched_random_config(config: Any, probability: float) -> Any:
    """``config`` (an :class:`lagrseq.config.ExperimentConfig` of ``lagr-seq``) with ``random``
    asking at ``probability`` in place of its asking policy, every other asking-policy field at
    its default: the run ``lagrseq frontier`` and ``lagrseq reproduce`` compare a learning policy
    with at its matched query rate (the same run directory either way)."""
    import dataclasses

    from lagrseq.config import POLICY_DEFAULTS

    fields = {f.name for f in dataclasses.fields(config.secondary)}
    reset = {name: value for name, value in POLICY_DEFAULTS.items() if name in fields}
    if "knobs" in fields:  # a plugin policy's own knobs belong to it, not to random
        reset["knobs"] = ()
    secondary = dataclasses.replace(config.secondary, **{**reset, "policy": "random", "ask_probability": probability})
    return dataclasses.replace(config, method="lagr-seq", secondary=secondary)


def rate_counts(directory: Path, trials: int) -> tuple[int, int]:
    """(queries, decisions) over the run's first ``trials`` trial logs (the query rate's terms)."""
    return _rate(directory, trials)


def _rate(directory: Path, trials: int) -> tuple[int, int]:
    """(queries, decisions) over the run's first ``trials`` trial logs."""
    from lagrseq.logs.reader import read_topic

    queries = decisions = 0
    for path in _logs(directory, trials):
        rows = read_topic(path, "/query")
        decisions += len(rows)
        queries += sum(bool(r.get("queried")) for r in rows)
    return queries, decisions


def trial_outcomes(directory: Path, trials: int) -> tuple[list[float], list[float]]:
    """Per trial log: steps to the end of the first solved episode (the trial's length when none
    was solved) and queries."""
    from lagrseq.logs.reader import read_topic

    steps, queries = [], []
    for path in _logs(directory, trials):
        episodes = sorted(read_topic(path, "/episode"), key=lambda e: int(e["episode"]))
        solved = [e for e in episodes if e.get("solved")]
        steps.append(float(solved[0]["global_step"]) if solved else float(sum(int(e["length"]) for e in episodes)))
        queries.append(float(sum(int(e["queries"]) for e in episodes)))
    return steps, queries


def _tune(
    task: str,
    variants: Sequence[Variant],
    phase: Callable[[Sequence[tuple[Variant, dict[str, str] | None]], int, int, str], list[Path]],
    tune: Tuning,
    evaluation_seed: int,
) -> dict[str, dict[str, Any]]:
    """Run always and every candidate of each named policy in :data:`TUNE_GRID` on the tuning
    seed and choose by :data:`TUNE_RULE`; returns the note per policy."""
    from lagrseq.analysis.inference import NON_INFERIOR, noninferiority, paired_noninferiority

    policies = [p for p in dict.fromkeys(v.policy for v in variants) if p in tune_grid()]
    if not policies:
        return {}
    role = {TUNING_NOTE: json.dumps({"role": "tuning", "evaluation_seed": evaluation_seed}, sort_keys=True)}
    control = Variant("always")
    candidates = [(p, value, Variant(p, ((tune_grid()[p][0], value),))) for p in policies for value in tune_grid()[p][1]]
    done = phase([(control, role), *[(v, role) for _, _, v in candidates]], tune.seed, tune.trials, "tuning")
    always_steps, _ = trial_outcomes(done[0], tune.trials)
    margin = 0.10 * (sum(always_steps) / len(always_steps)) if always_steps else 0.0
    scores: dict[str, list[tuple[str, float, float, str]]] = {}
    for (policy, value, _), directory in zip(candidates, done[1:], strict=True):
        steps, queries = trial_outcomes(directory, tune.trials)
        # the candidates and always ran the same tuning (seed, trial) pairs: paired when all are there
        test = paired_noninferiority if len(steps) == len(always_steps) == tune.trials else noninferiority
        verdict = test(steps, always_steps, margin, higher_is_better=False, min_n=min(tune.trials, 10))
        mean_q = sum(queries) / len(queries) if queries else float("inf")
        mean_s = sum(steps) / len(steps) if steps else float("inf")
        scores.setdefault(policy, []).append((value, mean_q, mean_s, verdict.verdict))
    notes = {}
    for policy, rows in scores.items():
        fine = [r for r in rows if r[3] == NON_INFERIOR]
        best = min(fine, key=lambda r: (r[1], r[2])) if fine else min(rows, key=lambda r: (r[2], r[1]))
        notes[policy] = {
            "role": "tuned", "policy": policy, "knob": tune_grid()[policy][0], "chosen": best[0],
            "tuning_seed": tune.seed, "tuning_trials": tune.trials, "evaluation_seed": evaluation_seed,
            "rule": TUNE_RULE, "fallback_rule_used": not fine,
            "candidates": [
                {"value": v, "queries_mean": q, "steps_to_solve_mean": s, "vs_always": verdict} for v, q, s, verdict in rows
            ],
        }
    return notes


def protocol_defaults(task: str | None, provider: str, preset: str | None, on_miss: str | None) -> tuple[str, str | None]:
    """The protocol's defaults where the command line left them open: the task's frontier preset
    (cube stacking: the paper's) and, on a store, refused misses (no policy gains from answers
    nobody recorded); ``on_miss`` stays None for a provider that answers every query itself."""
    from lagrseq.registry import kind_of

    if preset is None:
        preset = TASKS.get(task).frontier_preset if task is not None else "upstream"
    if on_miss is None:
        kind = kind_of(provider)
        on_miss = "refuse" if kind is not None and kind.replays else None
    return preset, on_miss


def tuning(tune: bool, seed: int, tune_seed: int | None, trials: int) -> Tuning | None:
    """``--tune``: the tuning seeds (default: the evaluation seed plus :data:`TUNE_OFFSET`)."""
    if not tune:
        return None
    return Tuning(seed + TUNE_OFFSET if tune_seed is None else tune_seed, trials)


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
    scopes: str = "auto",
    matched_random: bool = True,
    tune: Tuning | None = None,
    reporter: Reporter | None = None,
    stop_at_first_solve: bool = False,
    full_horizon_trials: int = 0,
) -> tuple[Path, list[Path]]:
    """``lagrseq frontier``'s runs: with ``replay``, the logs under it (no trial runs); else every
    variant run on ``task`` under ``out`` by the protocol (:func:`run_protocol`) and indexed.
    ``stop_at_first_solve``: the protocol's trials (tuning, evaluation, matched random) stop at
    their first solved episode (``run.stop_at = "first_solve"``: steps to the first solve are
    known then, and queries are counted to it); ``full_horizon_trials`` K > 0: then the variants
    also run K trials at full length on the same seed (trials 0 to K-1), a second group whose
    panel measures the full-horizon query count. Returns the report's folder and the run
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
    if full_horizon_trials and not stop_at_first_solve:
        raise UsageError(
            f"--full-horizon-trials {full_horizon_trials} measures full-length trials beside trials stopped at the "
            "first solve; give --stop-at-first-solve with it (without it every trial runs its full length)"
        )
    chosen_scopes = parse_scopes(scopes, task)
    stopped = [*overrides, f'run.stop_at="{FIRST_SOLVE}"'] if stop_at_first_solve else list(overrides)
    matched = [Variant("random")] if matched_random and any(wants_match(v.policy, v.knobs) for v in variants) else []
    check_variants(task, [*variants, *matched], provider, options, preset, config_file, stopped, chosen_scopes)
    if full_horizon_trials:
        check_variants(task, variants, provider, options, preset, config_file, overrides, chosen_scopes)
    reporter = reporter or Reporter()
    made = run_protocol(  # out is made once every configuration is checked
        task, list(variants), provider, options, out, trials, seed, preset, config_file, stopped, jobs,
        progress=progress, reporter=reporter, scopes=chosen_scopes, matched_random=matched_random, tune=tune,
    )
    ran, directories = list(made.variants), list(made.directories)
    if full_horizon_trials:  # the second group: the variants at full length, on fewer pairs
        reporter.say(f"full-horizon query counts: {len(variants)} variants x {full_horizon_trials} trials at full length")
        full = run_protocol(
            task, list(variants), provider, options, out, full_horizon_trials, seed, preset, config_file, list(overrides),
            jobs, progress=progress, reporter=reporter, scopes=chosen_scopes, matched_random=False, tune=None,
        )
        ran += full.variants
        directories += full.directories
    write_index(out, ran, directories, made.chosen)
    return out / "frontier", directories


FIRST_SOLVE = "first_solve"
"""``run.stop_at``'s value for trials that stop at their first solved episode."""


def check_variants(
    task: str,
    variants: Sequence[Variant],
    provider: str,
    options: Any,
    preset: str,
    config_file: Path | None,
    overrides: Sequence[str],
    scopes: Sequence[str | None],
) -> None:
    """Every variant's configuration in every scope checked (with the extras and the provider)
    before anything is made: a variant refused late in ``--policies`` leaves no ``--out``
    folder behind."""
    from lagrseq.running import runner

    for scope in scopes:
        extra = [*overrides, f'lagr.solution_scope="{scope}"'] if scope else list(overrides)
        for variant in variants:
            runner.check(task, variant.method, preset, config_file, [*extra, *variant.overrides()], provider, options)


def write_index(
    out: Path, variants: Sequence[Variant], directories: Sequence[Path], chosen: dict[str, dict[str, Any]] | None = None
) -> Path:
    """``frontier.json``: which run directory holds which policy, and ``--tune``'s choices (the
    report itself needs only the logs, whose metadata holds the same choices)."""
    path = out / "frontier.json"
    entries: list[dict[str, Any]] = [
        {"policy": str(v), "method": v.method, "directory": str(d)} for v, d in zip(variants, directories, strict=True)
    ]
    if chosen:
        entries.append({"tuned": chosen})
    outputs.write_text(path, json.dumps(entries, indent=1) + "\n", "--out")
    return path




def parse_scopes(text: str, task: str) -> list[str | None]:
    """``--scopes``: ``episode,trial``; ``auto``: both on the grid tasks (whose presets keep an
    answer for the trial), the preset's own (None) on cube stacking."""
    if text.strip() == "auto":
        regimes = TASKS.get(task).solution_scopes
        return [scope for scope in SCOPES if scope in regimes] or [None]
    scopes: list[str | None] = []
    for item in text.split(","):
        item = item.strip()
        if item not in SCOPES:
            raise UsageError(f"--scopes {text!r}: expected auto or a comma-separated list of {', '.join(SCOPES)}")
        if item not in scopes:
            scopes.append(item)
    if not scopes:
        raise UsageError("--scopes is empty; expected auto, episode, trial or episode,trial")
    return scopes
