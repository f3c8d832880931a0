"""The audit of paper vs code: what each deviation does, from the logs alone (``lagrseq audit``).

For every field where the ``upstream`` and ``paper`` presets differ (plus ``lagr.solution_scope``,
which the presets may set alike), ``lagrseq audit`` runs the upstream preset with only that field
switched to the paper's value, and the paper preset with only that field switched back, for the
baseline, LaGR and LaGR-SEQ. Here those runs are recognised from their logged configuration (a
run whose configuration differs from its preset in exactly one audited field, run length aside)
and each field's effect on the headline numbers is the switched run's mean minus the preset's,
with a 95% percentile-bootstrap interval (trials resampled within each run, seeded by the
statistic's name) and whether it excludes zero.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from lagrseq import config as cfg
from lagrseq.analysis import stats
from lagrseq.analysis.loading import Run
from lagrseq.analysis.tables import Table
from lagrseq.errors import ConfigError

PRESETS = ("upstream", "paper")
METHODS = ("baseline", "lagr", "lagr-seq")
EXTRA_FIELDS: dict[str, tuple[Any, ...]] = {"lagr.solution_scope": ("episode", "trial")}
"""Fields audited even where both presets agree, with the values they may take."""
RESAMPLES = 2000
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
    return json.loads(cfg.load(task, method, preset).to_json())


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


def classify(run: Run, fields: Sequence[tuple[str, Any, Any]]) -> tuple[str, str | None] | None:
    """(preset, switched field or None for the preset itself) of a logged run, read back from its
    configuration; None when it is no audit run (another field differs, or several)."""
    if run.key.kind != "trial" or run.key.preset not in PRESETS or run.key.method not in METHODS:
        return None
    try:
        wanted = _flat(preset_dict(run.key.task, run.key.method, run.key.preset))
    except ConfigError:
        return None
    logged = _flat(run.config)
    differs = [name for name, value in wanted.items() if name in logged and logged[name] != value]
    if not differs:
        return run.key.preset, None
    names = {name for name, _, _ in fields}
    if len(differs) == 1 and differs[0] in names:
        field = differs[0]
        if logged[field] == switched_value(field, run.key.preset, fields):
            return run.key.preset, field
    return None


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


QUANTITIES = (
    Quantity("queries with SEQ", _total("lagr-seq", "queries")),
    Quantity("queries without SEQ", _total("lagr", "queries")),
    Quantity("total return (LaGR-SEQ)", _total("lagr-seq", "return")),
    Quantity("performance ratio (LaGR-SEQ / baseline)", _ratio),
    Quantity("steps to first solved episode (LaGR-SEQ)", _solved),
)


def difference_ci(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> tuple[float, float, float]:
    """mean(a) - mean(b) and its 95% percentile-bootstrap interval (each resampled on its own)."""
    a = a[np.isfinite(a)]
    b = b[np.isfinite(b)]
    if not len(a) or not len(b):
        return float("nan"), float("nan"), float("nan")
    ia = rng.integers(0, len(a), size=(RESAMPLES, len(a)))
    ib = rng.integers(0, len(b), size=(RESAMPLES, len(b)))
    diffs = a[ia].mean(axis=1) - b[ib].mean(axis=1)
    low, high = np.percentile(diffs, [2.5, 97.5])
    return float(a.mean() - b.mean()), float(low), float(high)


@dataclass
class Audit:
    task: str
    table: Table
    data: pd.DataFrame
    """One row per (direction, field, quantity)."""


def build(runs: Sequence[Run]) -> list[Audit]:
    """One audit per task whose logs hold both the preset runs and some switched runs."""
    audits = []
    for task in sorted({run.key.task for run in runs if run.key.kind == "trial"}):
        try:
            fields = audited_fields(task)
        except ConfigError:
            continue
        variants: dict[tuple[str, str | None], dict[str, Run]] = {}
        provider: dict[tuple[str, str | None], str] = {}
        for run in sorted((r for r in runs if r.key.task == task), key=lambda r: (-r.size, r.key.name)):
            kind = classify(run, fields)
            if kind is None:
                continue
            methods = variants.setdefault(kind, {})
            if run.key.method not in methods:
                methods[run.key.method] = run
                provider.setdefault(kind, run.key.provider)
        if not any(field is not None for _, field in variants):
            continue
        rows = []
        for preset in PRESETS:
            base = variants.get((preset, None))
            if base is None:
                continue
            for name, _, _ in fields:
                switched = variants.get((preset, name))
                if switched is None:
                    continue
                # a method whose runs cannot read the field keeps the preset's run
                merged: dict[str, Run] = {}
                for m in METHODS:
                    chosen = switched.get(m) or (base.get(m) if not relevant(name, m) else None)
                    if chosen is not None:
                        merged[m] = chosen
                value = switched_value(name, preset, fields)
                for q in QUANTITIES:
                    a, b = q.per_trial(merged), q.per_trial(base)
                    if a is None or b is None:
                        continue
                    effect, low, high = difference_ci(a, b, stats.generator(f"audit/{task}/{preset}/{name}/{q.name}"))
                    rows.append(
                        {
                            "preset": preset,
                            "field": name,
                            "switched_to": json.dumps(value),
                            "quantity": q.name,
                            "preset_mean": float(np.nanmean(b)),
                            "switched_mean": float(np.nanmean(a)),
                            "effect": effect,
                            "ci_low": low,
                            "ci_high": high,
                            "excludes_zero": bool(np.isfinite(low) and (low > 0 or high < 0)),
                            "trials": int(min(len(a), len(b))),
                        }
                    )
        if not rows:
            continue
        data = pd.DataFrame(rows)
        audits.append(Audit(task, _table(task, data), data))
    return audits


def _cell(row: pd.Series) -> str:
    mark = " *" if row["excludes_zero"] else ""
    return f"{row['effect']:+.3g} [{row['ci_low']:+.3g}, {row['ci_high']:+.3g}]{mark}"


def _table(task: str, data: pd.DataFrame) -> Table:
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
            means = {r["quantity"]: f"{r['preset_mean']:.4g}" for _, r in rows.iterrows()}
            bases.append((f"{preset} preset itself (mean)", *(means.get(q, "—") for q in quantities)))
    return Table(
        f"Audit of {task}: effect of switching one field (switched minus preset, 95% bootstrap CI; * excludes 0)",
        ("run", *quantities),
        (*bases, *display),
        data,
    )


def figure(audit: Audit, quantity: str | None = None) -> Figure:
    """One bar per field (upstream preset switched to the paper's value, and the paper preset
    switched back), sorted by effect, with its 95% interval."""
    data = audit.data
    quantity = quantity or headline(audit)
    panels = [p for p in PRESETS if ((data["preset"] == p) & (data["quantity"] == quantity)).any()]
    fig = Figure(figsize=(9, 1.2 + 0.32 * max(1, len(data["field"].unique())) * len(panels)))
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    for ax, preset in zip(axes, panels, strict=True):
        rows = data[(data["preset"] == preset) & (data["quantity"] == quantity)].sort_values("effect")
        y = np.arange(len(rows))
        effect = rows["effect"].to_numpy()
        err = np.vstack([effect - rows["ci_low"].to_numpy(), rows["ci_high"].to_numpy() - effect])
        colours = ["#c44e52" if e else "#8c8c8c" for e in rows["excludes_zero"]]
        ax.barh(y, effect, xerr=np.abs(err), color=colours, capsize=2)
        ax.set_yticks(y, rows["field"].tolist(), fontsize=8)
        ax.axvline(0, color="#333", linewidth=0.8)
        direction = "upstream preset, one field set to the paper's value" if preset == "upstream" else "paper preset, one field set back to upstream's"
        ax.set_title(f"{direction}", fontsize=9)
    axes[-1].set_xlabel(f"effect on {quantity} (switched − preset; red: 95% CI excludes 0)")
    fig.suptitle(f"Audit of {audit.task}: what each deviation does", fontsize=11)
    fig.tight_layout()
    return fig


def headline(audit: Audit) -> str:
    """The quantity the figure shows: the performance ratio where the runs give it, else LaGR's queries."""
    have = set(audit.data["quantity"])
    for name in ("performance ratio (LaGR-SEQ / baseline)", "queries without SEQ", "queries with SEQ"):
        if name in have:
            return name
    return str(audit.data["quantity"].iloc[0])
