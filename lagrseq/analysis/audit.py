"""The audit of paper vs code: what each deviation does, from the logs alone (``lagrseq audit``).

For every field where the ``upstream`` and ``paper`` presets differ (plus ``lagr.solution_scope``,
which the presets may set alike), ``lagrseq audit`` runs the upstream preset with only that field
switched to the paper's value, and the paper preset with only that field switched back, for the
baseline, LaGR and LaGR-SEQ. Here those runs are recognised from their logged configuration (a
run whose configuration differs from its preset in exactly one audited field, run length aside)
and each field's effect on the headline numbers is the switched run's mean minus the preset's,
with Welch's 95% t-interval and two-sided p-value (:mod:`lagrseq.analysis.inference`).

Marks: the effects of one task's audit are one family (every preset x field x quantity with a
p-value; its size is stated on the page) and Holm's step-down correction keeps the family-wise
error at 5%. An effect is marked (``*``) only where its Holm-adjusted p is below 0.05 *and* both
arms have at least :data:`MIN_N_MARK` trials; fewer trials make the cell ``indicative`` and it is
never marked, whatever its p.

Interactions: for the fields of :data:`INTERACTIONS` (the cube: the primary's epsilon schedule,
learning on guided steps and the secondary's epsilon schedule) the audit also runs every
combination of two or three of them switched together on the upstream preset (the full 2x2x2
with the one-field runs and the preset itself). Each pair's interaction contrast is
``(Y_ab - Y_a) - (Y_b - Y_0)`` (how much switching both differs from the sum of switching each,
with the third field at the preset's value) and the three-way contrast is the alternating sum
over the eight corners; each has a Welch-Satterthwaite t-interval and p, Holm-corrected as a
second family. :func:`gap_explained_by` uses these numbers to name what accounts for a gap
between a measured value and the paper's.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from lagrseq import config as cfg
from lagrseq.analysis import inference, stats
from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table, outward
from lagrseq.errors import ConfigError

PRESETS = ("upstream", "paper")
METHODS = ("baseline", "lagr", "lagr-seq")
EXTRA_FIELDS: dict[str, tuple[Any, ...]] = {"lagr.solution_scope": ("episode", "trial")}
"""Fields audited even where both presets agree, with the values they may take."""
MIN_N_MARK = 10
"""No effect is marked with fewer trials than this in either arm (the cell says ``indicative``)."""
INTERACTIONS: dict[str, tuple[str, ...]] = {
    "cube-stacking": ("primary.epsilon_schedule", "lagr.update_primary_while_guided", "secondary.epsilon_schedule"),
}
"""Per task, the fields whose combinations the audit also runs together (on the upstream preset):
those with the largest effects in the one-field audit, and the ones that together move Table 2."""
INTERACTION_PRESET = "upstream"
# Which sections a method's trials read: a field of another section cannot change its runs.
USES = {
    "baseline": ("task", "env", "primary", "run"),
    "lagr": ("task", "env", "primary", "lagr", "llm", "run"),
    "lagr-seq": ("task", "env", "primary", "lagr", "llm", "secondary", "run"),
}


def _flat(config: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for section, values in config.items():
        if isinstance(values, dict) and section != "run":
            for name, value in values.items():
                out[f"{section}.{name}"] = value
    return out


def preset_dict(task: str, method: str, preset: str) -> dict[str, Any]:
    return json.loads(_preset_json(task, method, preset))


@functools.lru_cache(maxsize=256)
def _preset_json(task: str, method: str, preset: str) -> str:
    """A preset's configuration as JSON, resolved once per process (a replay asks for each one
    about ten times; resolving takes about a millisecond)."""
    return cfg.load(task, method, preset).to_json()


def audited_fields(task: str) -> list[tuple[str, Any, Any]]:
    """(field, upstream value, paper value) for every audited field of ``task``: those where the
    presets differ for any method, then the extra fields; the value a preset switches to is the
    other preset's, or for an extra field on which they agree, the other allowed value."""
    seen: dict[str, tuple[Any, Any]] = {}
    for method in METHODS:
        up = _flat(preset_dict(task, method, "upstream"))
        pa = _flat(preset_dict(task, method, "paper"))
        for name in up:
            if name in pa and up[name] != pa[name] and name not in seen:
                seen[name] = (up[name], pa[name])
    for name in EXTRA_FIELDS:
        if name in seen:
            continue
        up_value = _flat(preset_dict(task, "lagr", "upstream")).get(name)
        pa_value = _flat(preset_dict(task, "lagr", "paper")).get(name)
        if up_value is None or pa_value is None:
            continue
        seen[name] = (up_value, pa_value)  # where they agree, both presets switch to the value neither uses
    return [(name, up, pa) for name, (up, pa) in seen.items()]


def switched_value(field: str, preset: str, fields: Sequence[tuple[str, Any, Any]]) -> Any:
    """The value ``preset`` takes when ``field`` is switched: the other preset's (or, where both
    agree, the other allowed value)."""
    for name, up, pa in fields:
        if name == field:
            if up == pa:
                return next(v for v in EXTRA_FIELDS[field] if v != up)
            return pa if preset == "upstream" else up
    raise KeyError(field)


def override(field: str, value: Any) -> str:
    """``section.field=value`` in the ``--set`` syntax (TOML values)."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value)
    elif isinstance(value, (list, tuple)):
        text = json.dumps(list(value))
    else:
        text = repr(value)
    return f"{field}={text}"


def relevant(field: str, method: str) -> bool:
    return field.split(".", 1)[0] in USES[method]


def classify_variant(run: Run, fields: Sequence[tuple[str, Any, Any]]) -> tuple[str, frozenset[str]] | None:
    """(preset, the audited fields switched) of a logged run, read back from its configuration:
    the empty set for the preset itself, one field for a one-field run, two or three of the
    task's :data:`INTERACTIONS` fields (upstream preset only) for an interaction run; None when
    it is no audit run (another field differs, or a field holds neither preset's value)."""
    if run.key.kind != "trial" or run.key.preset not in PRESETS or run.key.method not in METHODS:
        return None
    try:
        wanted = _flat(preset_dict(run.key.task, run.key.method, run.key.preset))
    except ConfigError:
        return None
    logged = _flat(run.config)
    differs = [name for name, value in wanted.items() if name in logged and logged[name] != value]
    names = {name for name, _, _ in fields}
    for field in differs:
        if field not in names or logged[field] != switched_value(field, run.key.preset, fields):
            return None
    switched = frozenset(differs)
    if len(switched) > 1 and not (run.key.preset == INTERACTION_PRESET and switched <= set(INTERACTIONS.get(run.key.task, ()))):
        return None
    return run.key.preset, switched


def classify(run: Run, fields: Sequence[tuple[str, Any, Any]]) -> tuple[str, str | None] | None:
    """(preset, switched field or None for the preset itself) of a logged run, read back from its
    configuration; None when it is no one-field audit run (another field differs, or several)."""
    kind = classify_variant(run, fields)
    if kind is None or len(kind[1]) > 1:
        return None
    return kind[0], next(iter(kind[1]), None)


def interaction_sets(task: str, fields: Sequence[tuple[str, Any, Any]] | None = None) -> list[frozenset[str]]:
    """The combinations of two or more of ``task``'s :data:`INTERACTIONS` fields that the audit
    runs together (only fields the task audits; none where fewer than two are)."""
    names = {name for name, _, _ in (fields if fields is not None else audited_fields(task))}
    chosen = [f for f in INTERACTIONS.get(task, ()) if f in names]
    return [frozenset(c) for size in range(2, len(chosen) + 1) for c in itertools.combinations(chosen, size)]


def relevant_part(switched: frozenset[str], method: str) -> frozenset[str]:
    """The switched fields a method's trials can read: its run of a variant is the run of this part
    (e.g. the baseline of any ``lagr.*`` switch is the preset's baseline)."""
    return frozenset(f for f in switched if relevant(f, method))


def first_solved(run: Run) -> dict[int, float]:
    """Per trial, the environment step at which the first solved episode ended (a trial that
    never solves counts its whole length, so the value is a lower bound)."""
    out = {}
    for trial, group in run.episodes.groupby("trial", sort=True):
        ordered = group.sort_values("episode")
        solved = ordered[ordered["solved"].fillna(False).astype(bool)]
        steps = ordered["global_step"].to_numpy(dtype=float)
        out[int(trial)] = float(solved["global_step"].iloc[0]) if len(solved) else float(steps.max() if len(steps) else 0)
    return out


@dataclass(frozen=True)
class Quantity:
    name: str
    per_trial: Callable[[dict[str, Run]], np.ndarray | None]
    """Per-trial values of one variant's runs (by method), None when a run is missing."""


def _total(method: str, column: str) -> Callable[[dict[str, Run]], np.ndarray | None]:
    def values(runs: dict[str, Run]) -> np.ndarray | None:
        run = runs.get(method)
        return None if run is None else np.array(list(run.total_per_trial(column).values()), dtype=float)

    return values


def _ratio(runs: dict[str, Run]) -> np.ndarray | None:
    top, bottom = runs.get("lagr-seq"), runs.get("baseline")
    if top is None or bottom is None:
        return None
    return stats.paired_ratios(top.total_per_trial("return"), bottom.total_per_trial("return"))


def _solved(runs: dict[str, Run]) -> np.ndarray | None:
    run = runs.get("lagr-seq")
    return None if run is None else np.array(list(first_solved(run).values()), dtype=float)


def reads(quantity: str, field: str) -> bool:
    """Whether ``quantity`` can change when ``field`` is switched: the method it is measured on
    (LaGR for "queries without SEQ", else LaGR-SEQ) reads the field. A quantity that cannot is no
    comparison (its effect is 0 by construction) and is left out of the tables and the family."""
    return relevant(field, "lagr" if quantity == "queries without SEQ" else "lagr-seq")


QUANTITIES = (
    Quantity("queries with SEQ", _total("lagr-seq", "queries")),
    Quantity("queries without SEQ", _total("lagr", "queries")),
    Quantity("total return (LaGR-SEQ)", _total("lagr-seq", "return")),
    Quantity("performance ratio (LaGR-SEQ / baseline)", _ratio),
    Quantity("steps to first solved episode (LaGR-SEQ)", _solved),
)


POSITIVE = ("queries with SEQ", "queries without SEQ", "performance ratio (LaGR-SEQ / baseline)", "steps to first solved episode (LaGR-SEQ)")
"""Quantities that are never negative: their means get intervals on the log scale."""
MIN_N_INTERVAL = 3
"""No interval of a mean or an effect on fewer trials than this (t(0.975, 1) = 12.7: no information)."""


def mean_interval(values: np.ndarray, quantity: str, level: float = 0.95) -> inference.Interval:
    """The 95% interval of the mean of a quantity's per-trial values: on the log scale
    (:meth:`lagrseq.analysis.inference.Estimate.log_interval`) for a positive one, so it never
    reaches below 0; Student's t otherwise; NaN bounds below :data:`MIN_N_INTERVAL` trials."""
    estimate = inference.mean_estimate(values)
    if estimate.n < MIN_N_INTERVAL:
        return inference.Interval(estimate.n, estimate.value, math.nan, math.nan, level)
    if quantity in POSITIVE and bool(np.all(_finite(values) >= 0)):
        return estimate.log_interval(level)
    return estimate.interval(level)


def _mean(values: np.ndarray) -> float:
    """The mean of the finite values, NaN (and no warning) where there are none."""
    x = _finite(values)
    return float(x.mean()) if x.size else math.nan


def _finite(values: np.ndarray) -> np.ndarray:
    x = np.asarray(values, dtype=float).ravel()
    return x[np.isfinite(x)]


def contrast(groups: Sequence[tuple[float, np.ndarray]], level: float = 0.95) -> tuple[inference.Interval, float]:
    """``sum w_i mean(x_i)`` over independent groups with its Welch-Satterthwaite t-interval and
    two-sided p-value (of the contrast being 0); NaN bounds (and p) where a group has fewer than
    :data:`MIN_N_INTERVAL` values.
    With weights (+1, -1) it is Welch's difference of two means."""
    clean = [(float(w), _finite(x)) for w, x in groups]
    n = int(min((x.size for _, x in clean), default=0))
    if n == 0:
        return inference.Interval(n, math.nan, math.nan, math.nan, level), math.nan
    value = float(sum(w * x.mean() for w, x in clean))
    if n < MIN_N_INTERVAL:
        return inference.Interval(n, value, math.nan, math.nan, level), math.nan
    parts = [w * w * float(x.var(ddof=1)) / x.size for w, x in clean]
    var = sum(parts)
    if var == 0.0:
        return inference.Interval(n, value, value, value, level), (1.0 if value == 0.0 else 0.0)
    se = math.sqrt(var)
    df = inference.satterthwaite(parts, [x.size - 1 for _, x in clean])
    half = inference.t_ppf(0.5 + level / 2.0, df) * se
    p = 2.0 * (1.0 - inference.t_cdf(abs(value) / se, df))
    return inference.Interval(n, value, value - half, value + half, level), p


def mark(frame: pd.DataFrame) -> pd.DataFrame:
    """Holm-adjust the ``p`` column over the whole frame (one family: every row with a p-value)
    and mark the rows whose adjusted p is below 0.05 with at least :data:`MIN_N_MARK` trials;
    rows with fewer trials are ``indicative`` and never marked."""
    out = frame.copy()
    p = out["p"].to_numpy(dtype=float)
    out["p_holm"] = inference.holm(p)
    out["family_size"] = int(np.isfinite(p).sum())
    out["indicative"] = out["trials"].to_numpy() < MIN_N_MARK
    out["marked"] = (~out["indicative"]) & (np.nan_to_num(out["p_holm"].to_numpy(dtype=float), nan=1.0) < inference.ALPHA)
    return out


@dataclass
class Audit:
    task: str
    table: Table
    data: pd.DataFrame
    """One row per (direction, field, quantity)."""
    provider: str = "mock"
    """The provider of the audit's LaGR and LaGR-SEQ runs."""
    temperature: float | None = None
    """The LLM temperature the audit's runs used."""
    preset_configs: dict[str, dict[str, Any]] | None = None
    """Per preset, the flat configuration (``section.field``) of its LaGR-SEQ (else LaGR) run: a
    scoreboard row whose run differs from it (another stack size, temperature) was not audited."""
    corners: pd.DataFrame | None = None
    """Interaction runs: one row per (corner: the fields switched together, quantity), with the mean."""
    interactions: pd.DataFrame | None = None
    """One row per (contrast, quantity): the interaction contrasts, Holm-corrected as their own family."""
    interaction_table: Table | None = None
    length: str = ""
    """The runs' length, and whether it is reduced from the preset's (e.g. a quick audit)."""


def _variant_runs(variants: dict[tuple[str, frozenset[str]], dict[str, Run]], preset: str, switched: frozenset[str]) -> dict[str, Run]:
    """Each method's run of a variant: the run of the part of it that the method can read."""
    merged: dict[str, Run] = {}
    for m in METHODS:
        run = variants.get((preset, relevant_part(switched, m)), {}).get(m)
        if run is not None:
            merged[m] = run
    return merged


def _label(switched: frozenset[str] | Sequence[str]) -> str:
    return " + ".join(sorted(switched)) if switched else "none (the preset)"


def build(runs: Sequence[Run]) -> list[Audit]:
    """One audit per task whose logs hold both the preset runs and some switched runs."""
    audits = []
    for task in sorted({run.key.task for run in runs if run.key.kind == "trial"}):
        try:
            fields = audited_fields(task)
        except ConfigError:
            continue
        variants: dict[tuple[str, frozenset[str]], dict[str, Run]] = {}
        for run in sorted((r for r in runs if r.key.task == task), key=lambda r: (-r.size, r.key.name)):
            kind = classify_variant(run, fields)
            if kind is None:
                continue
            methods = variants.setdefault(kind, {})
            if run.key.method not in methods:
                methods[run.key.method] = run
        if not any(switched for _, switched in variants):
            continue
        rows = []
        for preset in PRESETS:
            base = _variant_runs(variants, preset, frozenset())
            if not base:
                continue
            for name, _, _ in fields:
                if (preset, frozenset({name})) not in variants:
                    continue
                merged = _variant_runs(variants, preset, frozenset({name}))
                value = switched_value(name, preset, fields)
                for q in QUANTITIES:
                    a, b = q.per_trial(merged), q.per_trial(base)
                    if a is None or b is None or not reads(q.name, name):
                        continue
                    interval, p = contrast([(1.0, a), (-1.0, b)])
                    rows.append(
                        {
                            "preset": preset,
                            "field": name,
                            "switched_to": json.dumps(value),
                            "quantity": q.name,
                            "preset_mean": _mean(b),
                            "switched_mean": _mean(a),
                            "effect": interval.mean,
                            "ci_low": interval.low,
                            "ci_high": interval.high,
                            "p": p,
                            "excludes_zero": bool(np.isfinite(interval.low) and (interval.low > 0 or interval.high < 0)),
                            "trials": interval.n,
                            "trials_switched": int(np.isfinite(a).sum()),
                            "trials_preset": int(np.isfinite(b).sum()),
                        }
                    )
        if not rows:
            continue
        data = mark(pd.DataFrame(rows))
        provider, temperature = _provider_of(variants)
        length = _length_note(task, next(iter(_variant_runs(variants, PRESETS[0], frozenset()).values()), None))
        configs = {}
        for preset in PRESETS:
            own = _variant_runs(variants, preset, frozenset())
            chosen = own.get("lagr-seq") or own.get("lagr")
            if chosen is not None:
                configs[preset] = _flat(chosen.config)
        made = Audit(task, _table(task, data, length), data, provider, temperature, preset_configs=configs, length=length)
        _add_interactions(made, variants, fields)
        audits.append(made)
    return audits


def _length_note(task: str, run: Run | None) -> str:
    """``N trials of S steps`` (or episodes) per run, saying where it is shorter than the preset's."""
    if run is None:
        return ""
    logged = run.config.get("run", {})
    preset = json.loads(cfg.load(task, run.key.method, run.key.preset).to_json()).get("run", {})
    parts = [f"{len(run.trials)} trials per run"]
    for key, unit in (("episodes", "episodes"), ("max_steps", "steps")):
        value, default = logged.get(key), preset.get(key)
        if isinstance(value, int) and value > 0:
            reduced = isinstance(default, int) and (default <= 0 or value < default)
            parts.append(f"{value} {unit} per trial" + (f" (reduced: the preset runs {default if default > 0 else 'no limit'})" if reduced else ""))
    return ", ".join(parts)


def _provider_of(variants: dict[tuple[str, frozenset[str]], dict[str, Run]]) -> tuple[str, float | None]:
    """The provider and temperature of the audit's LaGR-SEQ (else LaGR) preset runs."""
    for preset in PRESETS:
        for method in ("lagr-seq", "lagr"):
            run = variants.get((preset, frozenset()), {}).get(method)
            if run is not None:
                temperature = run.config.get("llm", {}).get("temperature")
                return run.key.provider, (float(temperature) if isinstance(temperature, (int, float)) else None)
    return "mock", None


def _add_interactions(made: Audit, variants: dict[tuple[str, frozenset[str]], dict[str, Run]], fields: Sequence[tuple[str, Any, Any]]) -> None:
    """The corners of the interaction design and the pairwise and three-way contrasts, where the
    logs hold every corner they need."""
    chosen = [f for f in INTERACTIONS.get(made.task, ()) if f in {name for name, _, _ in fields}]
    if len(chosen) < 2 or not any((INTERACTION_PRESET, s) in variants for s in interaction_sets(made.task, fields)):
        return
    subsets = [frozenset(c) for size in range(len(chosen) + 1) for c in itertools.combinations(chosen, size)]
    values: dict[tuple[frozenset[str], str], np.ndarray] = {}
    corner_rows = []
    for s in subsets:
        runs = _variant_runs(variants, INTERACTION_PRESET, s)
        for q in QUANTITIES:
            v = q.per_trial(runs)
            if v is None:
                continue
            values[(s, q.name)] = v
            ci = mean_interval(v, q.name)
            corner_rows.append({"corner": _label(s), "switched": len(s), "quantity": q.name, "mean": ci.mean, "ci_low": ci.low, "ci_high": ci.high, "trials": ci.n})
    designs: list[tuple[str, list[tuple[float, frozenset[str]]]]] = []
    for a, b in itertools.combinations(chosen, 2):
        designs.append((f"{a} x {b}", [(1.0, frozenset({a, b})), (-1.0, frozenset({a})), (-1.0, frozenset({b})), (1.0, frozenset())]))
    if len(chosen) == 3:
        designs.append((" x ".join(chosen), [(float((-1) ** (3 - len(s))), s) for s in subsets]))
    rows = []
    for name, design in designs:
        for q in QUANTITIES:
            if not all(reads(q.name, f) for _, s in design for f in s):
                continue  # a method that cannot read one of the fields: 0 by construction, no comparison
            groups = [(w, values.get((s, q.name))) for w, s in design]
            if any(v is None for _, v in groups):
                continue
            interval, p = contrast([(w, v) for w, v in groups if v is not None])
            rows.append({"contrast": name, "quantity": q.name, "value": interval.mean, "ci_low": interval.low, "ci_high": interval.high, "p": p, "trials": interval.n})
    if not corner_rows:
        return
    made.corners = pd.DataFrame(corner_rows)
    made.interactions = mark(pd.DataFrame(rows)) if rows else None
    made.interaction_table = _interaction_table(made)


def _n(row: pd.Series) -> str:
    a, b = int(row.get("trials_switched", row["trials"])), int(row.get("trials_preset", row["trials"]))
    return f"n={a}" if a == b else f"n={a}/{b}"


def _cell(row: pd.Series) -> str:
    if not np.isfinite(row["effect"]):  # an arm without a value (a ratio over a baseline that earned 0)
        return f"no value ({_n(row)}: an arm has no trial with a value; a ratio has none where its baseline earned no return)"
    if not np.isfinite(row["ci_low"]):
        text = f"{row['effect']:+.3g} (no interval)"
    else:
        low, high = outward(row["ci_low"], row["ci_high"], significant=3)
        text = f"{row['effect']:+.3g} [{low}, {high}]"
    if row["indicative"]:
        return f"{text} {_n(row)}, indicative"
    return f"{text} {_n(row)}" + (" *" if row["marked"] else "")


def _family_note(data: pd.DataFrame) -> str:
    m = int(data["family_size"].iloc[0]) if len(data) else 0
    return (
        f"Welch 95% t-interval, n trials per arm; * Holm-adjusted p < 0.05 over the m = {m} comparisons of this table; "
        f"no mark below {MIN_N_MARK} trials per arm (indicative)"
    )


def _table(task: str, data: pd.DataFrame, length: str = "") -> Table:
    quantities = [q.name for q in QUANTITIES if q.name in set(data["quantity"])]
    display = []
    for (preset, name), group in data.groupby(["preset", "field"], sort=False):
        cells = {r["quantity"]: _cell(r) for _, r in group.iterrows()}
        switched = group["switched_to"].iloc[0]
        display.append((f"{preset} + {name} = {switched}", *(cells.get(q, "—") for q in quantities)))
    bases = []
    for preset in PRESETS:
        rows = data[data["preset"] == preset].drop_duplicates("quantity")
        if len(rows):
            means = {r["quantity"]: f"{r['preset_mean']:.4g} (n={int(r['trials_preset'])})" for _, r in rows.iterrows()}
            bases.append((f"{preset} preset itself (mean)", *(means.get(q, "—") for q in quantities)))
    return Table(
        f"Audit of {task}: effect of switching one field (switched minus preset; {_family_note(data)}"
        + (f"; {length})" if length else ")"),
        ("run", *quantities),
        (*bases, *display),
        data,
    )


def _corner_cell(r: pd.Series) -> str:
    """A corner's mean with its 95% interval (on the log scale for a positive quantity), rounded
    outward; no interval below :data:`MIN_N_INTERVAL` trials."""
    if not np.isfinite(r["ci_low"]):
        return f"{r['mean']:.4g} n={int(r['trials'])} (no interval)"
    low, high = outward(r["ci_low"], r["ci_high"], significant=4)
    return f"{r['mean']:.4g} [{low}, {high}] n={int(r['trials'])}"


def _interaction_table(audit: Audit) -> Table | None:
    corners = audit.corners
    if corners is None:
        return None
    quantities = [q.name for q in QUANTITIES if q.name in set(corners["quantity"])]
    rows: list[tuple[str, ...]] = []
    for (corner, _), group in corners.groupby(["corner", "switched"], sort=False):
        cells = {r["quantity"]: _corner_cell(r) for _, r in group.iterrows()}
        rows.append((f"mean, {INTERACTION_PRESET} + {corner}", *(cells.get(q, "—") for q in quantities)))
    note = "no contrast (a corner is missing)"
    if audit.interactions is not None:
        shown = audit.interactions.rename(columns={"value": "effect"})
        for name, group in shown.groupby("contrast", sort=False):
            cells = {r["quantity"]: _cell(r) for _, r in group.iterrows()}
            rows.append((f"interaction {name}", *(cells.get(q, "—") for q in quantities)))
        note = _family_note(audit.interactions)
    frame = corners if audit.interactions is None else pd.concat([corners.assign(kind="corner"), audit.interactions.assign(kind="contrast")], ignore_index=True)
    return Table(
        f"Interactions in the audit of {audit.task} ({INTERACTION_PRESET} preset, fields switched together; "
        f"corner means with t-intervals; contrasts (Y_ab - Y_a) - (Y_b - Y_0): {note}"
        + (f"; {audit.length})" if audit.length else ")"),
        ("run", *quantities),
        tuple(rows),
        frame,
    )


def figure(audit: Audit, quantity: str | None = None) -> Figure:
    """One bar per field (upstream preset switched to the paper's value, and the paper preset
    switched back), sorted by effect, with its 95% Welch interval: red where marked (Holm),
    hatched where indicative (fewer than :data:`MIN_N_MARK` trials)."""
    data = audit.data
    quantity = quantity or headline(audit)
    panels = [p for p in PRESETS if ((data["preset"] == p) & (data["quantity"] == quantity)).any()]
    fig = Figure(figsize=(9, 1.2 + 0.32 * max(1, len(data["field"].unique())) * len(panels)))
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    for ax, preset in zip(axes, panels, strict=True):
        rows = data[(data["preset"] == preset) & (data["quantity"] == quantity)].sort_values("effect")
        y = np.arange(len(rows))
        effect = rows["effect"].to_numpy()
        err = np.nan_to_num(np.vstack([effect - rows["ci_low"].to_numpy(), rows["ci_high"].to_numpy() - effect]))
        colours = ["#c44e52" if m else "#8c8c8c" for m in rows["marked"]]
        bars = ax.barh(y, effect, xerr=np.abs(err), color=colours, capsize=2)
        for bar, indicative in zip(bars, rows["indicative"], strict=True):
            if indicative:
                bar.set_hatch("//")
                bar.set_alpha(0.6)
        ax.set_yticks(y, [f"{f} (n={int(n)})" for f, n in zip(rows["field"], rows["trials"], strict=True)], fontsize=8)
        ax.axvline(0, color="#333", linewidth=0.8)
        direction = "upstream preset, one field set to the paper's value" if preset == "upstream" else "paper preset, one field set back to upstream's"
        ax.set_title(f"{direction}", fontsize=9)
    m = int(data["family_size"].iloc[0]) if len(data) else 0
    axes[-1].set_xlabel(
        f"effect on {quantity} (switched − preset, Welch 95% CI)\nred: Holm-adjusted p < 0.05 over m = {m} comparisons; hatched: n < {MIN_N_MARK}, indicative",
        fontsize=8,
    )
    fig.suptitle(f"Audit of {audit.task}: what each deviation does", fontsize=11)
    fig.tight_layout()
    return fig


def interaction_figure(audit: Audit) -> Figure | None:
    """The corner means of the interaction runs for the query counts (LaGR and LaGR-SEQ), with
    t-intervals: what switching the fields together does, beside each alone."""
    corners = audit.corners
    if corners is None:
        return None
    shown = [q for q in ("queries without SEQ", "queries with SEQ", "total return (LaGR-SEQ)") if q in set(corners["quantity"])]
    if not shown:
        return None
    fig = Figure(figsize=(10, 1.5 + 4.2 * len(shown)))
    axes = fig.subplots(len(shown), 1, squeeze=False)[:, 0]
    for ax, q in zip(axes, shown, strict=True):
        rows = corners[corners["quantity"] == q]
        y = np.arange(len(rows))
        mean = rows["mean"].to_numpy()
        err = np.nan_to_num(np.vstack([mean - rows["ci_low"].to_numpy(), rows["ci_high"].to_numpy() - mean]))
        ax.barh(y, mean, xerr=np.abs(err), color="#4c72b0", capsize=2)
        labels = [f"{c.replace(' + ', ' +' + chr(10))} (n={int(n)})" for c, n in zip(rows["corner"], rows["trials"], strict=True)]
        ax.set_yticks(y, labels, fontsize=7)
        ax.set_title(q, fontsize=9)
    axes[-1].set_xlabel(f"mean per trial, 95% t-interval\n({INTERACTION_PRESET} preset, fields switched together)", fontsize=8)
    fig.suptitle(f"Audit of {audit.task}: interaction runs", fontsize=11)
    fig.tight_layout()
    return fig


def outputs(audit: Audit) -> list[tuple[str, Table, Figure]]:
    """What an audit writes: (file stem, table, figure), the one-field audit and, where the logs
    hold them, its interaction runs."""
    out = [(f"audit-{audit.task}", audit.table, figure(audit))]
    fig = interaction_figure(audit)
    if audit.interaction_table is not None and fig is not None:
        out.append((f"audit-{audit.task}-interactions", audit.interaction_table, fig))
    return out


def headline(audit: Audit) -> str:
    """The quantity the figure shows: the performance ratio where the runs give it, else LaGR's queries."""
    have = set(audit.data["quantity"])
    for name in ("performance ratio (LaGR-SEQ / baseline)", "queries without SEQ", "queries with SEQ"):
        if name in have:
            return name
    return str(audit.data["quantity"].iloc[0])


QUERY_COLUMNS = {"LaGR-SEQ": "queries with SEQ", "LaGR (without SEQ)": "queries without SEQ"}
"""The audit quantity behind a query table's column."""
RATIO_QUANTITY = "performance ratio (LaGR-SEQ / baseline)"
"""The audit quantity behind a ratio table whose numerator is LaGR-SEQ and denominator the baseline."""
_PAPER = re.compile(r"([-+]?\d+(?:\.\d+)?)\s*(?:±|\+-|\+/-)?\s*(\d+(?:\.\d+)?)?")


def _signed(x: float) -> str:
    return f"{x:+.3g}"


def gap_explained_by(
    audits: Sequence[Audit],
    task: str,
    preset: str,
    quantity: str | None,
    measured: float,
    paper: str,
    config: dict[str, Any] | None = None,
    margin: float | None = None,
    interval: tuple[float, float] | None = None,
) -> str | None:
    """What accounts for the gap between a measured value and the paper's (a scoreboard row):
    the audit rows of ``task`` whose measured effects on ``quantity``, from ``preset``, add up to
    the gap ``paper - measured`` within the equivalence margin
    (``margin``: the scoreboard's, :mod:`lagrseq.analysis.margins`; without one,
    :func:`lagrseq.analysis.inference.margin_for`: 10% of the paper's value or its own +-), with
    their sum; or the interaction run that does so (fields switched together); or ``partly``, or
    ``unexplained``. ``interval``: the 95% interval of ``measured - paper`` the scoreboard's test
    reads; where it holds 0 there is no gap to explain ("no gap shown"), where it lies inside
    ``± margin`` none beyond the margin; without it the point gap is compared with the margin.
    Only effects marked by the audit (Holm, enough trials) count, or, where none
    is marked, intervals that exclude 0 on fewer trials (said to be indicative). A row the audit
    never measured (another quantity; a run whose ``config`` differs from the audited preset's,
    such as another temperature or stack size) says so. None where the logs hold no audit of
    ``task``."""
    made = next((a for a in audits if a.task == task), None)
    if made is None:
        return None
    anchor = f"audit-{task}"
    if quantity is None:
        return f"not audited: {anchor} does not measure this quantity"
    if config is not None:
        other = _other_run(made, anchor, preset, config)
        if other is not None:
            return other
    found = _PAPER.search(paper)
    if found is None or not math.isfinite(measured):
        return f"not audited: no paper number to compare ({anchor})"
    value = float(found.group(1))
    if margin is None or not math.isfinite(margin):
        margin = inference.margin_for(value, float(found.group(2)) if found.group(2) else None)
    gap = value - measured
    no_gap = _no_gap(gap, margin, interval)
    if no_gap is not None:
        return no_gap
    source = f"{anchor}, {made.provider}"
    candidates, qualifier = _candidates(made, preset, quantity, gap)
    joint = _joint_effect(made, preset, quantity, gap, margin, source)
    if joint is not None:
        return joint
    if candidates.empty:
        return f"unexplained (gap {_signed(gap)}; no audited field moves it that way beyond noise; {source})"
    return _added_effects(candidates, gap, margin, qualifier, source)


def _other_run(made: Audit, anchor: str, preset: str, config: dict[str, Any]) -> str | None:
    """The line saying the audit never measured a run of ``config``, or None where it did."""
    audited = (made.preset_configs or {}).get(preset, {})
    row = _flat(config)
    temperature = row.get("llm.temperature")
    if isinstance(temperature, (int, float)) and made.temperature is not None and abs(float(temperature) - made.temperature) > 1e-9:
        return f"not audited: τ = {float(temperature):g} was never audited ({anchor} ran at τ = {made.temperature:g})"
    differs = sorted(k for k in row if k in audited and row[k] != audited[k])
    if differs:
        shown = ", ".join(f"{k} = {json.dumps(row[k])}" for k in differs)
        return f"not audited: this run's {shown} differs from the audited {preset} preset ({anchor})"
    return None


def _no_gap(gap: float, margin: float, interval: tuple[float, float] | None) -> str | None:
    """The line saying there is no gap beyond the margin to explain, or None where there is one."""
    if interval is not None and math.isfinite(interval[0]) and math.isfinite(interval[1]):
        if interval[0] <= 0.0 <= interval[1]:
            return f"no gap shown (the test's 95% interval [{interval[0]:.3g}, {interval[1]:.3g}] holds 0)"
        if -margin <= interval[0] and interval[1] <= margin:
            return f"no gap beyond the margin (the test's 95% interval lies inside ±{margin:.3g})"
    elif abs(gap) <= margin:
        return f"no gap beyond the margin (point gap {_signed(gap)}, margin ±{margin:.3g}; no interval)"
    return None


def _candidates(made: Audit, preset: str, quantity: str, gap: float) -> tuple[pd.DataFrame, str]:
    """The audit rows that move ``quantity`` the gap's way (marked, else indicative), and their qualifier."""
    rows = made.data[(made.data["preset"] == preset) & (made.data["quantity"] == quantity)]
    same_way = rows[np.sign(rows["effect"]) == np.sign(gap)]
    candidates = same_way[same_way["marked"]]
    qualifier = ""
    if candidates.empty:
        candidates = same_way[same_way["indicative"] & same_way["excludes_zero"]]
        qualifier = f", indicative: n < {MIN_N_MARK}" if not candidates.empty else ""
    return candidates, qualifier


def _joint_effect(made: Audit, preset: str, quantity: str, gap: float, margin: float, source: str) -> str | None:
    """The interaction run (fields switched together) whose effect is the gap within the margin, or None."""
    if made.corners is None or preset != INTERACTION_PRESET:
        return None
    corners = made.corners[made.corners["quantity"] == quantity]
    base = corners[corners["switched"] == 0]
    if not len(base):
        return None
    joint = corners[corners["switched"] >= 2].assign(effect=lambda f: f["mean"] - float(base["mean"].iloc[0]))
    if not len(joint):
        return None
    best = joint.iloc[int(np.argmin(np.abs(joint["effect"].to_numpy() - gap)))]
    if abs(best["effect"] - gap) <= margin:
        return (
            f"{best['corner']} switched together ({_signed(best['effect'])}, n={int(best['trials'])}) "
            f"of gap {_signed(gap)} (interaction runs, {source})"
        )
    return None


def _added_effects(candidates: pd.DataFrame, gap: float, margin: float, qualifier: str, source: str) -> str:
    """The line naming the one-field effects, largest first, whose sum comes nearest the gap."""
    # an effect far larger than the gap does not account for part of it: it measures another regime
    fitting = candidates[candidates["effect"].abs() <= abs(gap) + margin]
    if fitting.empty:
        largest = candidates.iloc[int(np.argmax(candidates["effect"].abs().to_numpy()))]
        return (
            f"unexplained (gap {_signed(gap)}; the audited effects that way overshoot it, e.g. "
            f"{largest['field']} ({_signed(largest['effect'])}){qualifier}; {source})"
        )
    ordered = fitting.reindex(fitting["effect"].abs().sort_values(ascending=False).index)
    sums = np.cumsum(ordered["effect"].to_numpy())
    k = int(np.argmin(np.abs(sums - gap))) + 1
    named = " + ".join(f"{r['field']} ({_signed(r['effect'])})" for _, r in ordered.iloc[:k].iterrows())
    total = float(sums[k - 1])
    if abs(total - gap) <= margin:
        return f"{named} = {_signed(total)} of gap {_signed(gap)} (one-field effects added{qualifier}; {source})"
    return f"partly: {named} = {_signed(total)} of gap {_signed(gap)}, the rest unexplained (one-field effects added{qualifier}; {source})"
