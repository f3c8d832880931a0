"""The query-efficiency frontier: return against queries and dollars per trial, one point per
asking policy, from the MCAP logs alone.

Each run found under the given directories is one point: its policy comes from the configuration
stored in its logs (``baseline`` is ``never``, ``lagr`` is ``always``, ``lagr-seq`` is
``secondary.policy`` with its knobs). Per trial: total return, steps to the end of the first
solved episode (the trial's length when none was solved), queries, dollars, and answers that a
fallback gave because the recorded store missed them. Points carry 95% bootstrap intervals on
both axes; the variants of one policy (a swept knob) are joined into a curve. Tables give means
with intervals, the interquartile mean of the return with a stratified bootstrap interval, and
the probability that a trial of the policy returns more than one of ``always``. The paper's SEQ
(``seq`` with no knob changed) and LaGR (``always``) rows are marked.

Dollars: a query's logged ``cost_usd`` when it has one; else its logged token usage priced by
``price``; else (answers imported from the authors' caches carry no usage) the median token
usage of the queries of the same task that have one (the mock estimates about 4 characters a
token), marked as estimated. No usage anywhere: NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from lagrseq.analysis import stats
from lagrseq.analysis.figures import COLORS, STYLE
from lagrseq.analysis.loading import Run, load
from lagrseq.analysis.tables import Table, interval, number, to_csv, to_markdown
from lagrseq.errors import LogError

Price = Callable[[str, int, int], float | None]
MISS_THRESHOLD = 0.1
"""Default: a point whose answers came from a fallback for more than this share is marked."""
PAPER_ROWS = {"seq": "SEQ (paper)", "always": "LaGR (paper)"}
DPI = 150
_DEFAULTS = {"query_cost": 0.0, "budget": 0, "ask_probability": 0.5, "thompson_prior": [1.0, 1.0], "min_progress": 0}


def policy_of(config: dict[str, Any]) -> tuple[str, str]:
    """(policy, knobs) of a run's configuration: ``("never", "")``, ``("thompson", "cost 0.5")``."""
    method = config.get("method")
    if method == "baseline":
        return "never", ""
    if method == "lagr":
        return "always", ""
    section = config.get("secondary", {})
    name = str(section.get("policy", "seq"))
    knobs = []
    if name == "random":
        knobs.append(f"p {section.get('ask_probability', 0.5):g}")
    if name == "thompson" and list(section.get("thompson_prior", [1.0, 1.0])) != [1.0, 1.0]:
        a, b = section["thompson_prior"]
        knobs.append(f"prior {a:g},{b:g}")
    if section.get("query_cost", 0.0):
        knobs.append(f"cost {section['query_cost']:g}")
    if section.get("budget", 0):
        knobs.append(f"budget {section['budget']}/{section.get('budget_scope', 'trial')}")
    if section.get("min_progress", 0):
        knobs.append(f"gate {section['min_progress']}")
    return name, " ".join(knobs)


def _knob_value(config: dict[str, Any]) -> float:
    """The value a policy's curve is ordered by (its swept knob, whichever differs)."""
    section = config.get("secondary", {})
    return (
        float(section.get("query_cost", 0.0)) + float(section.get("budget", 0)) * 1e-6
        + float(section.get("ask_probability", 0.5)) * 1e-9 + float(section.get("min_progress", 0)) * 1e-3
    )


@dataclass
class Point:
    """One policy variant's per-trial numbers and their summaries."""

    policy: str
    knobs: str
    run: Run
    returns: np.ndarray
    steps_to_solve: np.ndarray
    solved: np.ndarray
    queries: np.ndarray
    dollars: np.ndarray
    fallback: np.ndarray
    estimated_dollars: bool = False
    summary: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"{self.policy} ({self.knobs})" if self.knobs else self.policy

    @property
    def miss_share(self) -> float:
        total = float(self.queries.sum())
        return float(self.fallback.sum()) / total if total else 0.0


def _panel_key(run: Run) -> tuple[str, str, str, int]:
    return (run.key.task, run.key.preset, run.key.provider, run.key.seed)


def _dollars(run: Run, price: Price | None, fallback_tokens: tuple[float, float] | None) -> tuple[np.ndarray, bool]:
    """What each trial's queries would cost live: a live answer's logged cost; else its logged
    token usage (a mock's estimate) at ``price`` for the configured ``llm.model``; else
    ``fallback_tokens`` (estimated)."""
    trials = list(run.trials)
    q = run.queries
    if q.empty:
        return np.zeros(len(trials)), False
    sent = q[q["queried"].astype(bool)]
    per_trial = dict.fromkeys(trials, 0.0)
    estimated = False
    asked = str(run.config.get("llm", {}).get("model", ""))  # what a live run would pay for
    for trial, model, source, cost, prompt, completion in zip(
        sent["trial"], sent["model"], sent["source"], sent["cost_usd"], sent["prompt_tokens"],
        sent["completion_tokens"], strict=True,
    ):
        usd: float | None = None
        if source == "live" and not _nan(cost):
            usd = float(cost)
        else:
            tokens: tuple[float, float] | None = None
            if not _nan(prompt) and float(prompt) > 0:  # imported answers log no usage (0)
                tokens = (float(prompt), 0.0 if _nan(completion) else float(completion))
            elif fallback_tokens is not None:
                tokens, estimated = fallback_tokens, True
            if tokens is not None and price is not None:
                usd = price(asked or str(model), int(tokens[0]), int(tokens[1]))
        per_trial[int(trial)] += math.nan if usd is None else usd
    return np.array([per_trial[t] for t in trials]), estimated


def estimated_tokens(config: dict[str, Any]) -> tuple[float, float] | None:
    """Tokens of one query of ``config``'s task, estimated as the mock does (about 4 characters
    a token): the prompt of the empty pattern, and an answer the size of a full pattern (a list
    of letters for cubes, a bracketed 0/1 matrix for grids)."""
    from lagrseq.tasks import cube
    from lagrseq.tasks.arrangement import object_arrangement
    from lagrseq.tasks.image import image_completion

    task = config.get("task", {})
    name = task.get("name")
    try:
        if name == "cube-stacking":
            size = int(task.get("stack_size", 8))
            prompt = cube.CubeStacking(size).prompt(())
            answer = 4 * size + 2
        elif name in ("image-completion", "object-arrangement"):
            make = image_completion if name == "image-completion" else object_arrangement
            grid = make(task.get("target", "x"), float(task.get("goal_threshold", 1.0)), task.get("prompt_matrix", "numpy"))
            prompt = grid.prompt(np.zeros((grid.rows, grid.cols), dtype=np.int8))
            answer = 2 * grid.rows * grid.cols + 2 * grid.rows
        else:
            return None
    except (TypeError, ValueError, KeyError):
        return None
    return float(max(1, len(prompt) // 4)), float(max(1, answer // 4))


def _nan(value: Any) -> bool:
    try:
        return math.isnan(float(value))
    except (TypeError, ValueError):
        return True


def _median_tokens(runs: Sequence[Run]) -> tuple[float, float] | None:
    """The median logged token usage of the queries of ``runs`` (the mock's estimates, live
    usage); without any, the task's estimate (:func:`estimated_tokens`)."""
    frames = [r.queries for r in runs if not r.queries.empty]
    q = pd.concat(frames) if frames else pd.DataFrame(columns=["queried", "prompt_tokens"])
    q = q[q["queried"].astype(bool) & (q["prompt_tokens"].fillna(0).astype(float) > 0)]
    if q.empty:
        return estimated_tokens(runs[0].config) if runs else None
    return float(q["prompt_tokens"].astype(float).median()), float(q["completion_tokens"].fillna(0).astype(float).median())


def point_of(run: Run, price: Price | None, fallback_tokens: tuple[float, float] | None) -> Point:
    """Per-trial numbers of one run."""
    policy, knobs = policy_of(run.config)
    trials = list(run.trials)
    episodes = run.episodes
    returns, steps, solved = [], [], []
    for trial in trials:
        rows = episodes[episodes["trial"] == trial].sort_values("episode")
        returns.append(float(rows["return"].sum()))
        done = rows[rows["solved"].astype(bool)]
        solved.append(not done.empty)
        steps.append(float(done["global_step"].iloc[0]) if not done.empty else float(rows["length"].sum()))
    q = run.queries
    sent = q[q["queried"].astype(bool)] if not q.empty else q
    recorded = str(run.key.provider).startswith("recorded")
    queries = np.array([float((sent["trial"] == t).sum()) if len(sent) else 0.0 for t in trials])
    if recorded and len(sent):
        fallback = np.array([float(((sent["trial"] == t) & (sent["source"] != "recorded")).sum()) for t in trials])
    else:
        fallback = np.zeros(len(trials))
    dollars, estimated = _dollars(run, price, fallback_tokens)
    return Point(
        policy, knobs, run, np.array(returns), np.array(steps), np.array(solved), queries, dollars, fallback, estimated
    )


ORDER = {"never": 0, "always": 1, "seq": 2, "random": 3, "thompson": 4, "oracle": 5}


def points_of(runs: Sequence[Run], price: Price | None) -> list[Point]:
    """One summarised point per run, in the tables' order (policy, then the swept knob)."""
    tokens = _median_tokens(runs)
    points = [point_of(run, price, tokens) for run in runs]
    points.sort(key=lambda p: (ORDER.get(p.policy, 9), _knob_value(p.run.config), p.knobs))
    summarise(points)
    return points


def summarise(points: Sequence[Point]) -> None:
    """Means with 95% bootstrap intervals (seeded per quantity and label)."""
    for p in points:
        for name in ("returns", "steps_to_solve", "queries", "dollars"):
            values = getattr(p, name)
            key = f"frontier/{p.run.key.task}/{p.label}/{name}"
            mean = float(np.mean(values)) if len(values) else math.nan
            low, high = stats.bootstrap_ci(values, stats.generator(key)) if not np.isnan(values).any() else (math.nan, math.nan)
            if len(values) >= 2 and np.all(values == values[0]):
                low = high = float(values[0])
            p.summary[name] = (mean, low, high)


def table(points: Sequence[Point], miss_threshold: float = MISS_THRESHOLD, provider: str | None = None) -> Table:
    """The frontier table: one row per policy variant (paper rows marked). ``provider``: the one
    named in the title (default: the first point's)."""
    reference = next((p for p in points if p.policy == "always" and not p.knobs), None)
    columns = (
        "policy", "paper", "trials", "queries / trial [95% CI]", "USD / trial [95% CI]", "return / trial [95% CI]",
        "return IQM [95% CI]", "P(return > always) [95% CI]", "steps to first solve [95% CI]", "solved trials",
        "fallback answers", "queries vs always",
    )
    rows, data = [], []
    for p in points:
        iqm, iqm_low, iqm_high = stats.iqm_ci([p.returns], stats.generator(f"frontier/{p.label}/iqm"), 2000)
        if reference is not None:
            poi, poi_low, poi_high = stats.probability_of_improvement_ci(
                [p.returns], [reference.returns], stats.generator(f"frontier/{p.label}/poi"), 2000
            )
        else:
            poi = poi_low = poi_high = math.nan
        q, d, r, s = (p.summary[n] for n in ("queries", "dollars", "returns", "steps_to_solve"))
        ratio = q[0] / reference.summary["queries"][0] - 1.0 if reference and reference.summary["queries"][0] else math.nan
        flagged = p.miss_share > miss_threshold
        usd = f"{number(d[0], 4)} {interval(d[1], d[2], 4)}" + (" (est.)" if p.estimated_dollars else "")
        rows.append((
            p.label + (" *" if flagged else ""),
            PAPER_ROWS.get(p.policy, "") if not p.knobs else "",
            str(len(p.returns)),
            f"{number(q[0], 1)} {interval(q[1], q[2], 1)}",
            usd,
            f"{number(r[0], 1)} {interval(r[1], r[2], 1)}",
            f"{number(iqm, 1)} {interval(iqm_low, iqm_high, 1)}",
            f"{number(poi, 2)} {interval(poi_low, poi_high, 2)}",
            f"{number(s[0], 0)} {interval(s[1], s[2], 0)}",
            f"{int(p.solved.sum())}/{len(p.solved)}",
            f"{int(p.fallback.sum())} ({100 * p.miss_share:.0f}%)",
            "n/a" if math.isnan(ratio) else f"{100 * ratio:+.0f}%",
        ))
        data.append({
            "policy": p.policy, "knobs": p.knobs, "paper": PAPER_ROWS.get(p.policy, "") if not p.knobs else "",
            "trials": len(p.returns),
            "queries_mean": q[0], "queries_low": q[1], "queries_high": q[2],
            "usd_mean": d[0], "usd_low": d[1], "usd_high": d[2], "usd_estimated": p.estimated_dollars,
            "return_mean": r[0], "return_low": r[1], "return_high": r[2],
            "return_iqm": iqm, "return_iqm_low": iqm_low, "return_iqm_high": iqm_high,
            "p_improvement_vs_always": poi, "p_improvement_low": poi_low, "p_improvement_high": poi_high,
            "steps_to_solve_mean": s[0], "steps_to_solve_low": s[1], "steps_to_solve_high": s[2],
            "solved_trials": int(p.solved.sum()), "fallback_answers": int(p.fallback.sum()),
            "miss_share": p.miss_share, "miss_flagged": flagged, "queries_vs_always": ratio,
            "run": p.run.key.name,
        })
    first = points[0].run.key if points else None
    shown = provider if provider is not None else (first.provider if first else "")
    title = f"Query-efficiency frontier: {first.task} ({first.preset}, {shown}, seed {first.seed})" if first else "Frontier"
    return Table(title, columns, tuple(rows), pd.DataFrame(data))


def _curves(points: Sequence[Point]) -> list[tuple[str, list[Point]]]:
    """One curve per policy and swept knob (``thompson`` over cost, ``thompson`` over budget...);
    the policy's point without knobs starts every one of its curves (cost 0, no budget)."""
    plain = {p.policy: p for p in points if not p.knobs}
    curves: dict[tuple[str, str], list[Point]] = {}
    for p in points:
        names = " ".join(p.knobs.split()[0::2])
        curves.setdefault((p.policy, names), []).append(p)
    out = []
    for (policy, names), members in curves.items():
        if names and policy in plain:
            members = [plain[policy], *members]
        members.sort(key=lambda p: (p.summary["queries"][0], p.summary["returns"][0]))
        out.append((policy, members))
    return out


MARKERS = ("o", "s", "^", "D", "v", "P", "X", "h", "<", ">", "p", "d")
"""A policy's variants, told apart by marker (one colour per policy); the paper's rows are stars."""

PROFILE_STYLES = ("-", "--", "-.", ":")
"""Performance profiles: one line style per policy, so lines that coincide stay visible."""


def _markers(points: Sequence[Point]) -> dict[int, str]:
    """id(point) -> marker: ``*`` for the paper's SEQ and LaGR rows, else the next free marker of
    the point's policy."""
    used: dict[str, int] = {}
    out = {}
    for p in points:
        if p.policy in PAPER_ROWS and not p.knobs:
            out[id(p)] = "*"
            continue
        n = used.get(p.policy, 0)
        used[p.policy] = n + 1
        out[id(p)] = MARKERS[n % len(MARKERS)]
    return out


def draw(points: Sequence[Point], title: str, miss_threshold: float = MISS_THRESHOLD, figure: Any = None) -> Figure:
    """2 x 2: return and steps to the first solved episode against queries and dollars per
    trial; 95% bootstrap intervals on both axes; a policy's variants joined as a curve, one colour
    per policy and one marker per variant, named in a legend below the panels (labels beside
    the points overlapped where policies cluster); hollow markers: more than ``miss_threshold``
    of the answers came from a fallback. ``figure``: draw into this (sub)figure instead of a new
    one; returns the figure drawn into."""
    figure = figure if figure is not None else Figure(figsize=(11.5, 9.2), layout="constrained")
    axes = figure.subplots(2, 2)
    curves = _curves(points)
    colors = {name: COLORS[i % len(COLORS)] for i, name in enumerate(dict.fromkeys(p.policy for p in points))}
    markers = _markers(points)
    handles: dict[str, Any] = {}
    for (row, y_name, y_label) in ((0, "returns", "Return per trial"), (1, "steps_to_solve", "Steps to the first solved episode")):
        for (col, x_name, x_label) in ((0, "queries", "LLM queries per trial"), (1, "dollars", "US dollars per trial")):
            ax = axes[row][col]
            for _, family in curves:
                xs = [p.summary[x_name][0] for p in family]
                ys = [p.summary[y_name][0] for p in family]
                if len(family) > 1:
                    ax.plot(xs, ys, "-", color=colors[family[0].policy], alpha=0.6, linewidth=1.2)
            for p in points:
                color = colors[p.policy]
                x, xl, xh = p.summary[x_name]
                y, yl, yh = p.summary[y_name]
                xerr = [[max(x - xl, 0)], [max(xh - x, 0)]] if not math.isnan(xl) else None
                yerr = [[max(y - yl, 0)], [max(yh - y, 0)]] if not math.isnan(yl) else None
                hollow = p.miss_share > miss_threshold
                marker = markers[id(p)]
                size = 10 if marker == "*" else 6
                ax.errorbar(
                    [x], [y], xerr=xerr, yerr=yerr, fmt=marker, color=color, markersize=size,
                    markerfacecolor="white" if hollow else color, capsize=2, linewidth=0.8,
                )
                label = p.label + (f" = {PAPER_ROWS[p.policy]} *" if marker == "*" else "") + (" †" if hollow else "")
                # the legend shows the marker alone: error-bar caps drawn over it hid its shape
                handles.setdefault(label, Line2D(
                    [], [], marker=marker, linestyle="none", color=color, markersize=size,
                    markerfacecolor="white" if hollow else color,
                ))
            _zoom(ax, points, y_name)
            _spread(ax, [p.summary[x_name][0] for p in points])
            ax.set_xlabel(x_label + (" (estimated)" if x_name == "dollars" and any(p.estimated_dollars for p in points) else ""))
            ax.set_ylabel(y_label)
    # the legend's header explains exactly the marks its labels carry
    marks = ["policy (variant)"]
    if any(label.endswith((" *", " * †")) for label in handles):
        marks.append("* star: the paper's rows")
    if any(label.endswith(" †") for label in handles):
        marks.append(f"† hollow: > {100 * miss_threshold:.0f}% of answers from the fallback")
    figure.legend(
        list(handles.values()), list(handles), loc="outside lower center", ncols=min(3, max(1, len(handles))),
        fontsize=8, title="; ".join(marks), title_fontsize=8,
    )
    figure.suptitle(title + "\nbars: 95% bootstrap CI of the mean over trials")
    return figure


def _spread(ax: Any, xs: Sequence[float]) -> None:
    """A symmetric-log x axis when the points span more than a factor of 5 (1 query and 30, or
    $0.01 and $0.3, on one axis): the cheap policies, which cluster near zero, spread out, and a
    point at 0 (never) stays on the axis (linear below the smallest positive value)."""
    positive = [x for x in xs if not math.isnan(x) and x > 0]
    if len(positive) >= 2 and max(positive) >= 5 * min(positive):
        ax.set_xscale("symlog", linthresh=min(positive), linscale=0.5)
        ax.set_xlim(left=-0.25 * min(positive))  # nothing is negative: no room for the mirror side


def _zoom(ax: Any, points: Sequence[Point], y_name: str) -> None:
    """When a point that never asks lies far from every asking policy (the plain RL agent's
    return is often a small fraction of a guided one's), zoom on the asking policies so their
    differences show, and name the points left off the axis."""
    asking = [p for p in points if p.summary["queries"][0] > 0]
    if len(asking) < 2:
        return
    bounds = [v for p in asking for v in p.summary[y_name] if not math.isnan(v)]
    low, high = min(bounds), max(bounds)
    span = max(high - low, 1e-9)
    off = [p for p in points if not low - 2 * span <= p.summary[y_name][0] <= high + 2 * span]
    if not off:
        return
    ax.set_ylim(low - 0.15 * span, high + 0.25 * span)
    text = "; ".join(_off_axis(p, y_name) for p in off)
    ax.text(0.01, 0.01, f"off the axis: {text}", transform=ax.transAxes, fontsize=7, va="bottom")


def _off_axis(p: Point, y_name: str) -> str:
    """A point left off the axis, in words. Steps to the first solved episode of a trial that
    never solved are its whole length (a censoring cap, not a measurement), and say so."""
    value = p.summary[y_name][0]
    unsolved = int((~p.solved.astype(bool)).sum())
    if y_name != "steps_to_solve" or not unsolved:
        return f"{p.label}: {value:.4g}"
    n = len(p.solved)
    if unsolved == n:
        return f"{p.label}: no trial solved (0 of {n}; mean {value:.4g} = the trials' length, a censoring cap)"
    return f"{p.label}: {value:.4g} ({unsolved} of {n} trials never solved, counted at their length: a lower bound)"


def draw_profiles(points: Sequence[Point], title: str) -> Figure:
    """Performance profiles of the per-trial return (fraction of trials above each return)."""
    figure = Figure(figsize=(6.4, 4.4), layout="constrained")
    ax = figure.add_subplot()
    asking = [p for p in points if p.summary.get("queries", (1.0,))[0] > 0] or list(points)
    every = np.concatenate([p.returns for p in asking]) if asking else np.zeros(1)
    least, most = float(every.min()), float(every.max())
    pad = max(most - least, 1e-9) * 0.05
    taus = np.linspace(least - pad, most + pad, 80)  # over the asking policies' returns (never's are often far below)
    for i, p in enumerate(points):
        profile, low, high = stats.performance_profile_ci([p.returns], taus, stats.generator(f"frontier/{p.label}/profile"), 500)
        color = COLORS[i % len(COLORS)]
        # a line style and markers of its own per policy, each later line narrower than the one
        # before: equal profiles (always and oracle on the same returns) show as a wide line with
        # a thin one on top instead of hiding one another
        ax.plot(
            taus, profile, color=color, label=p.label, linestyle=PROFILE_STYLES[i % len(PROFILE_STYLES)],
            marker=MARKERS[i % len(MARKERS)], markevery=(2 * i % 16, 16), markersize=max(3.5, 8.0 - i),
            markerfacecolor="none", linewidth=max(1.0, 4.0 - 0.6 * i),
        )
        if not np.isnan(low).all():
            ax.fill_between(taus, low, high, color=color, alpha=0.12)
    # "threshold", not tau: tau is the LLM's temperature everywhere else in lagrseq
    ax.set_xlabel("Return threshold r (per trial)")
    ax.set_ylabel("Fraction of trials with return > r")
    ax.set_title(title)
    ax.legend(fontsize=7)
    return figure


@dataclass(frozen=True)
class FrontierReport:
    written: list[Path]
    tables: list[Table]
    warnings: tuple[str, ...]


def report(
    roots: Sequence[str | Path], out: Path, price: Price | None = None, miss_threshold: float = MISS_THRESHOLD
) -> FrontierReport:
    """Read every trial log under ``roots`` and write, per (task, preset, provider, seed): the
    frontier PNG, the performance-profile PNG, and the table as Markdown and CSV."""
    import matplotlib

    logs = load(roots)
    runs = [r for r in logs.runs if r.key.kind == "trial"]
    if not runs:  # one line, as replay: every log left out is named in it
        detail = f" ({'; '.join(logs.warnings)})" if logs.warnings else ""
        raise LogError(f"no complete lagrseq trial logs under {', '.join(map(str, roots))}{detail}")
    panels: dict[tuple[str, str, str, int], list[Run]] = {}
    for run in runs:
        panels.setdefault(_panel_key(run), []).append(run)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    tables: list[Table] = []
    with matplotlib.rc_context(STYLE):  # type: ignore[arg-type]
        for key, group in sorted(panels.items()):
            points = points_of(group, price)
            task, preset, provider, seed = key
            stem = "-".join([task, preset, _slug(provider), f"seed{seed}"])
            shown = table(points, miss_threshold)
            tables.append(shown)
            for suffix, text in ((".md", to_markdown(shown)), (".csv", to_csv(shown.data))):
                path = out / f"{stem}{suffix}"
                path.write_text(text, encoding="utf-8", newline="\n")
                written.append(path)
            for suffix, figure in (
                (".png", draw(points, shown.title, miss_threshold)),
                ("-profiles.png", draw_profiles(points, f"{task}: performance profiles of the return")),
            ):
                path = out / f"{stem}{suffix}"
                figure.savefig(path, format="png", dpi=DPI, metadata={"Software": None})
                written.append(path)
    return FrontierReport(written, tables, logs.warnings)


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in text).strip("-")[-60:]
