"""Paper items from runs: which runs feed an item, and one builder per kind of item.

:func:`match` finds, for each run an item of the suite lists, the logged run made with that
configuration (run length aside). A builder turns the matched runs into a figure (an ``Axes``,
unsaved), the numbers behind it, tables, and a line on how the item was made. Builders work for
any task: learning curves use episodes or environment steps on the x axis as the item says.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import PurePath
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.axes import Axes

from lagrseq import config as cfg
from lagrseq.analysis import figures, inference, stats
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.loading import ACCURACY_METHOD, Run
from lagrseq.analysis.misses import Misses, count_misses
from lagrseq.analysis.tables import Table, interval, number, plus_minus
from lagrseq.errors import ConfigError
from lagrseq.registry import kind_of
from lagrseq.suite import MISS_ROWS, Item, RunSpec, is_authors_provider, matches, miss_variant

Price = Callable[[str, int, int], float | None]
"""(model, prompt tokens, completion tokens) -> US dollars or None (unpriced)."""

CURVE_POINTS = 200
"""Points of a return-vs-steps curve (one every max_step / 200 steps)."""


@dataclass(frozen=True)
class Match:
    """One run an item needs and the logged run that provides it (None: missing, and why)."""

    spec: RunSpec
    label: str
    run: Run | None
    reason: str = ""
    provider: str = ""
    """The provider spec shown for this run (replaces ``{provider}`` in its row name)."""
    note: str = ""
    """Recorded runs: how many answers missed the store and what answered them ("misses: k of n
    answers (x%)", :func:`recorded_misses`)."""
    misses: Misses | None = None
    """Recorded runs: the count behind :attr:`note`."""

    @property
    def row(self) -> str:
        return (self.spec.row or "").replace("{provider}", self.provider)


@dataclass(frozen=True)
class ItemFailure:
    """An item whose runs were started but failed (``lagrseq reproduce``): the item is reported
    as failed, not made from what its runs left."""

    reason: str
    """One short line: which run failed and with what error (no absolute path)."""
    advice: str
    """What to do, by the cause (a store's miss is not cured by running again)."""
    rerun: str
    """The command that reruns this item alone."""
    runs: int = 1
    """How many of its runs failed."""
    folders: tuple[str, ...] = ()
    """The failed runs' folders, as the run was given them (for the terminal, which has said
    their errors already; never written to the report)."""

    def line(self) -> str:
        return f"FAILED: {self.reason}; {self.advice}; rerun it alone: `{self.rerun}`"


@dataclass
class Built:
    """What a builder made."""

    axes: Axes | None = None
    figure_data: pd.DataFrame | None = None
    tables: list[tuple[str, Table]] = field(default_factory=list)
    """(file stem, table)."""
    method: str = ""
    """How the numbers were computed (one sentence)."""


def _describe_spec(spec: RunSpec, provider: str) -> str:
    overrides = "".join(f" --set {o}" for o in spec.overrides)
    if spec.kind == "accuracy":
        return f"an accuracy probe of {spec.task} --preset {spec.preset} --provider {provider}{overrides}"
    return f"{spec.task} {spec.method} --preset {spec.preset} --provider {provider}{overrides}"


def match(
    item: Item,
    runs: Sequence[Run],
    default_provider: str,
    provider: str | None = None,
    unavailable: dict[str, str] | None = None,
) -> list[Match]:
    """The logged run for each run ``item`` lists.

    ``provider`` fixes the provider of the suite's default-provider runs; when None, any provider
    matches and the suite default (``default_provider``) is preferred. Among several matching
    runs the one with the most data wins, then the lowest seed. ``unavailable`` maps a run's
    provider spec to why it cannot run here (from ``lagrseq reproduce``).
    """
    out = []
    for spec in item.runs:
        wanted = spec.provider if spec.provider is not None else provider
        shown = wanted or default_provider
        try:
            resolved = spec.resolved_dict()
        except ConfigError as exc:
            task_missing = spec.task not in cfg.tasks()
            reason = f"task {spec.task} not available" if task_missing else str(exc)
            out.append(Match(spec, spec.display_label(shown), None, reason, shown))
            continue
        method = ACCURACY_METHOD if spec.kind == "accuracy" else spec.method
        candidates = [
            run
            for run in runs
            if run.key.kind == spec.kind
            and run.key.task == spec.task
            and run.key.method == method
            and run.key.preset == spec.preset
            and (wanted is None or run.key.provider == wanted)
            and (spec.kind != "trial" or run.key.variant == miss_variant(run.key.provider, spec.on_miss))
            and matches(run.config, resolved)
        ]
        if not candidates:
            reason = (unavailable or {}).get(shown, "")
            if not reason:
                reason = f"no logs of `{_describe_spec(spec, shown)}`"
            out.append(Match(spec, spec.display_label(shown), None, reason, shown))
            continue
        best = sorted(
            candidates,
            key=lambda r: (
                not _length_asked(spec, r.config),  # the item's own (full or quick) length first
                r.key.provider != default_provider,
                -r.size,
                r.key.seed,
                r.key.name,
            ),
        )[0]
        note = recorded_misses(best)
        short = shorter_than_asked(spec, resolved, best) if is_authors_provider(best.key.provider) else ""
        note = "; ".join(part for part in (short, note) if part)
        label = spec.display_label(best.key.provider) + (f" [{note}]" if note else "")
        out.append(Match(spec, label, best, "", best.key.provider, note, run_misses(best)))
    return _without_quick_copies(out)


def _without_quick_copies(matched: list[Match]) -> list[Match]:
    """``matched`` less the full-length copies (``full_horizon_trials``) that ``--quick`` does not
    run (``quick_full_horizon_trials = 0``) when every stopped run found is at the quick length
    alone (logs of the quick suite): not missing there. Logs of the full suite without them still
    name them missing."""
    unrun = [m for m in matched if m.spec.full_horizon and m.run is None and m.spec.quick_trials == 0]
    found = [m for m in matched if not m.spec.full_horizon and m.run is not None]
    if not unrun or not found or not all(_quick_length_only(m.spec, m.run.config) for m in found if m.run is not None):
        return matched
    return [m for m in matched if not any(m is u for u in unrun)]


def _quick_length_only(spec: RunSpec, config: dict[str, Any]) -> bool:
    """Whether a logged run has the item's ``--quick`` length and not its full one."""
    logged = config.get("run", {})
    try:
        quick, full = spec.resolved_dict(True).get("run", {}), spec.resolved_dict(False).get("run", {})
    except ConfigError:
        return False

    def same(lengths: dict[str, Any]) -> bool:
        return all(logged.get(name) == lengths.get(name) for name in ("episodes", "max_steps"))

    return same(quick) and not same(full)


def shorter_than_asked(spec: RunSpec, full: dict[str, Any], run: Run) -> str:
    """"shorter than the full suite: ..." when ``run`` has fewer trials, episodes or steps than
    the item's full length (``full``: the spec's configuration at that length), else empty: a
    row on the authors' answers made by ``reproduce --quick`` says it is not the paper's length."""
    asked, got = full.get("run", {}), run.config.get("run", {})
    shorter = len(run.trials) < spec.trials
    for field_name in ("episodes", "max_steps"):
        want, have = asked.get(field_name) or 0, got.get(field_name) or 0
        shorter = shorter or (want > 0 and (have == 0 or have < want))
    if not shorter:
        return ""

    def length(trials: int, values: dict[str, Any]) -> str:
        steps = values.get("max_steps") or 0
        return f"{trials} trials × {steps} steps" if steps else f"{trials} trials × {values.get('episodes')} episodes"

    return f"shorter than the full suite: {length(len(run.trials), got)} (full: {length(spec.trials, asked)})"


def recorded_misses(run: Run) -> str:
    """For a run on a recorded store: "misses: K of N answers (x%)" and what answered them
    (:meth:`lagrseq.analysis.misses.Misses.text`: refused, or a fallback that can be right), from
    its queries' ``source`` column; where a fallback that can be right answered misses, the trials
    whose first accepted answer came from it (a refusal is never accepted). Empty for other runs."""
    found = run_misses(run)
    if found is None:
        return ""
    if found.answers == 0:
        return "no queries"
    decided_text = ""
    if found.answered_by_fallback and run.key.method != ACCURACY_METHOD:  # an accuracy probe accepts nothing: no trial to decide
        decided, trials = fallback_decided(run)
        decided_text = f"; first accepted answer from the fallback in {decided}/{trials} trials"
    return found.text() + decided_text


def run_misses(run: Run) -> Misses | None:
    """The misses of a run on a recorded store (None for other runs)."""
    return count_misses(run.key.provider, run.queries)


def fallback_decided(run: Run) -> tuple[int, int]:
    """(trials whose first accepted answer came from a fallback rather than the recorded store,
    trials): in those trials the fallback, not the recorded model, decided when the agent first
    got a usable suggestion (:func:`lagrseq.analysis.provenance.decided_by_fallback`). A trial
    with no accepted answer counts as not decided by it."""
    decided = prov.decided_by_fallback(run)
    return sum(decided), len(decided)


def made_by(run: Run) -> str:
    """The provenance class of a run (:func:`lagrseq.analysis.provenance.of_run`)."""
    return prov.of_run(run).kind


def run_line(m: Match) -> str:
    """ "label: 10 trials x 100 episodes of RUN" for the index page."""
    run = m.run
    assert run is not None
    if run.key.kind == "accuracy":
        size = f"{run.samples} answers per prefix"
    else:
        size = f"{len(run.trials)} trials × {run.episodes_per_trial} episodes"
    return f"{m.label}: {size} of {run.key.name}"


# ------------------------------------------------------------------------------------------
# Builders
# ------------------------------------------------------------------------------------------
def _present(matched: Sequence[Match]) -> list[tuple[Match, Run]]:
    return [(m, m.run) for m in matched if m.run is not None]


def _episode_matrix(run: Run, window: int) -> tuple[np.ndarray, np.ndarray]:
    length = run.episodes_per_trial
    matrix = np.full((len(run.trials), length), np.nan)
    for row, (_, group) in enumerate(run.episodes.groupby("trial", sort=True)):
        values = group.sort_values("episode")["return"].to_numpy(dtype=float)
        matrix[row, : len(values)] = stats.moving_average(values, window)
    return np.arange(1, length + 1), matrix


def _step_matrix(run: Run, grid: np.ndarray, window: int) -> np.ndarray:
    """One row per trial of the run: its return-vs-steps curve from its finished episodes (an
    episode the step budget cut off is left out), 0 before its first one
    (:data:`stats.BEFORE_FIRST_EPISODE`), so that every point averages every trial."""
    budget = int(run.config.get("run", {}).get("max_steps", 0) or 0)
    horizon = _episode_horizon(run)
    matrix = np.full((len(run.trials), len(grid)), stats.BEFORE_FIRST_EPISODE)
    for row, (_, group) in enumerate(run.episodes.groupby("trial", sort=True)):
        ordered = group.sort_values("episode")
        steps = ordered["global_step"].to_numpy()
        solved = ordered["solved"].fillna(0).astype(bool).to_numpy()
        lengths = ordered["length"].fillna(0).to_numpy()
        keep = stats.finished_episodes(steps, solved, budget, lengths, horizon)
        matrix[row] = stats.step_curve(steps[keep], ordered["return"].to_numpy()[keep], grid, window)
    return matrix


def _episode_horizon(run: Run) -> int | None:
    """The most steps an episode of this run can take: the configuration's ``env.horizon`` where
    it has one, else the longest unsolved episode that was not its trial's last (it ended at its
    own limit, e.g. the image task's scans); None when neither is known."""
    horizon = run.config.get("env", {}).get("horizon")
    if isinstance(horizon, int) and not isinstance(horizon, bool) and horizon > 0:
        return horizon
    episodes = run.episodes
    if episodes.empty:
        return None
    last = episodes.groupby("trial")["episode"].transform("max") == episodes["episode"]
    unsolved = ~episodes["solved"].fillna(0).astype(bool)
    ended = episodes.loc[~last & unsolved, "length"].dropna()
    return int(ended.max()) if not ended.empty else None


def build_returns(item: Item, matched: Sequence[Match]) -> Built:
    """Fig. 5 and the appendix learning curves: mean return over trials with a band."""
    options = item.options
    x_axis = options.get("x", "episode")
    band = options.get("band", "std")
    window = int(options.get("window", 1))
    present = _present(matched)
    series = []
    frames = []
    if x_axis == "global_step":
        last = max(int(run.episodes["global_step"].max()) for _, run in present)
        stride = max(1, -(-last // CURVE_POINTS))
        grid = np.arange(stride, last + stride, stride)
    for m, run in present:
        if x_axis == "global_step":
            x, matrix = grid, _step_matrix(run, grid, window)
        else:
            x, matrix = _episode_matrix(run, window)
        curve = stats.curve(x, matrix)
        series.append(figures.Series(f"{m.label} [{made_by(run)}]", curve, len(run.trials)))
        frames.append(
            pd.DataFrame(
                {
                    "series": m.label,
                    "provenance": made_by(run),
                    x_axis: curve.x,
                    "trials": curve.n,
                    "mean": curve.mean,
                    "std": curve.std,
                    "se": curve.se,
                }
            )
        )
    xlabel = "Environment steps" if x_axis == "global_step" else "Episodes"
    axes = figures.returns(
        series,
        band=band,
        xlabel=xlabel,
        ylabel=str(options.get("ylabel", "Average return")),
        title=item.title,
    )
    smoothing = ""
    if x_axis == "global_step":
        smoothing = (
            f"; at each step, the mean of the last {window} episode returns finished by then "
            "(a trial with none yet counts 0; an episode cut off by the step budget is not a finished one), "
            "over every trial of the run"
        )
    elif window > 1:
        smoothing = f"; moving average over {window} episodes"
    spread = "one standard deviation" if band == "std" else "one standard error"
    method = f"Return per episode, mean over trials with a band of {spread}{smoothing}; each line says what made it (provenance)."
    return Built(axes, pd.concat(frames, ignore_index=True), [], method)


def _summary_row(label: str, values: np.ndarray, run: Run) -> tuple[stats.Interval, dict[str, Any]]:
    """Summary of per-trial counts with the interval of the mean of a positive quantity
    (:func:`lagrseq.analysis.inference.positive_mean_interval`: the same for one run in every table
    and figure that shows it; it never reaches below 0), and the provenance of the run."""
    s = _positive_summary(values)
    row = {
        "label": label,
        "provenance": made_by(run),
        "n": s.n,
        "mean": s.mean,
        "se": s.se,
        "std": s.std,
        "ci_low": s.ci_low,
        "ci_high": s.ci_high,
    }
    return s, row


def _positive_summary(values: np.ndarray) -> stats.Interval:
    """Mean, spread and the positive quantity's interval of per-trial values (none below
    :data:`lagrseq.analysis.inference.MIN_N_INTERVAL`)."""
    mean, std, se = stats.mean_std_se(values)
    shown = inference.positive_mean_interval(values)
    return stats.Interval(int(np.asarray(values).size), mean, shown.low, shown.high, shown.level, std, se)


def build_query_bars(item: Item, matched: Sequence[Match]) -> Built:
    """Fig. 6 and the binary-reward appendix figure: LLM queries per trial, mean ± s.e."""
    bars = []
    rows = []
    display = []
    for m, run in _present(matched):
        values = np.array(list(run.total_per_trial("queries").values()))
        summary, row = _summary_row(m.label, values, run)
        bars.append(figures.Bar(f"{m.label} [{made_by(run)}]", summary))
        rows.append(row)
        display.append(
            (
                m.label,
                made_by(run),
                str(summary.n),
                plus_minus(summary.mean, summary.se),
                number(summary.std),
                interval(summary.ci_low, summary.ci_high),
            )
        )
    axes = figures.bars(bars, title=item.title)
    table = Table(
        f"{item.title}: LLM queries per trial",
        ("", "made by", "trials", "mean ± s.e.", "std", "95% interval (modified Cox)"),
        tuple(display),
        pd.DataFrame(rows),
    )
    method = "LLM queries per trial (summed over its episodes): bars are means, error bars the table's 95% interval of the mean (modified Cox, from the logs of the per-trial values: asymmetric, never below 0, none below 3 trials; the table also gives mean ± s.e.); each bar says what made it (provenance)."
    return Built(axes, pd.DataFrame(rows), [(item.id, table)], method)


def _length_asked(spec: RunSpec, config: dict[str, Any]) -> bool:
    """Whether a logged run has the length the item asks for, full or --quick (several items may
    share one configuration at different lengths, e.g. 200-step and extended arrangement runs)."""
    run = config.get("run", {})
    for _trials, episodes, max_steps in (spec.length(False), spec.length(True)):
        if (episodes <= 0 or run.get("episodes") == episodes) and (
            max_steps < 0 or run.get("max_steps") == max_steps
        ):
            return True
    return False


def _reference(item: Item, key: str) -> str:
    reference = item.options.get("reference", {})
    return str(reference.get(key, "")) if isinstance(reference, dict) else ""


def _rows_columns(matched: Sequence[Match]) -> tuple[list[str], list[str]]:
    rows: list[str] = []
    columns: list[str] = []
    for m in matched:
        if m.spec.row is not None and m.row not in rows:
            rows.append(m.row)
        if m.spec.column is not None and m.spec.column not in columns:
            columns.append(m.spec.column)
    return rows, columns


def build_query_table(item: Item, matched: Sequence[Match]) -> Built:
    """Table 2 and Table 3: queries per run, mean ± s.e., one cell per (row, column) run."""
    rows, columns = _rows_columns(matched)
    reference = item.options.get("reference", {})
    for key in reference if isinstance(reference, dict) else ():
        row = str(key).split("|", 1)[0]
        if "|" in str(key) and row not in rows:
            rows.append(row)  # a row the paper has and these runs do not: its values, for scale
    cells: dict[tuple[str, str], stats.Interval] = {}
    notes: dict[tuple[str, str], str] = {}
    makers: dict[str, list[str]] = {}
    data = []
    for m, run in _present(matched):
        row, column = m.row, m.spec.column or ""
        notes[(row, column)] = m.note
        if made_by(run) not in makers.setdefault(row, []):
            makers[row].append(made_by(run))
        values = np.array(list(run.total_per_trial("queries").values()))
        summary, record = _summary_row(m.label, values, run)
        cells[(row, column)] = summary
        data.append(
            {"row": row, "column": column, **record, "paper": _reference(item, f"{row}|{column}")}
        )
    header = str(item.options.get("row_header", ""))
    display = []
    for row in rows:
        line = [row, " / ".join(makers.get(row, [])) or "—"]
        for column in columns:
            s = cells.get((row, column))
            note = notes.get((row, column), "")
            line.append("not run" if s is None else f"{plus_minus(s.mean, s.se)} (n={s.n})" + (f"; {note}" if note else ""))
        line += [_reference(item, f"{row}|{column}") or "—" for column in columns]
        display.append(tuple(line))
    table = Table(
        f"{item.title}: LLM queries per run, mean ± s.e.",
        (header, "made by", *columns, *(f"paper: {c}" for c in columns)),
        tuple(display),
        pd.DataFrame(data),
    )
    method = "LLM queries per run (trial), mean ± standard error over trials (n per cell), next to the paper's values, each row with what made it (provenance); the CSV adds the standard deviation and a 95% interval of the mean (modified Cox, from the logs of the per-trial values: it never reaches below 0; none below 3 trials). On recorded answers, each cell shows its misses (answers the store lacked: k of n, refused or answered by a fallback that can be right) and, for such a fallback, the trials whose first accepted answer came from it."
    stopped = [run for _, run in _present(matched) if (run.config.get("run") or {}).get("stop_at") == "first_accepted"]
    if stopped:
        kept = all((run.config.get("lagr") or {}).get("solution_scope") == "trial" for run in stopped)
        method += (
            f" {len(stopped)} of its runs end each trial with the step of its first accepted answer (run.stop_at = "
            "first_accepted): " + (
                "an accepted answer is kept for the trial (lagr.solution_scope = trial) and nothing is asked after it, "
                "so their queries per run are those of the whole trial."
                if kept else "their queries per run are the queries until the first accepted answer."
            )
        )
    if any(m.row.endswith(f"({MISS_ROWS['calibrated']})") for m in matched):
        method += (
            " Rows on the authors' answers are made three ways, by what answered a prompt the store lacks: a refusal "
            "(never accepted: an upper bound), a calibrated draw (accepted at a rate for prompts with as many cells shown, "
            "drawn per trial from the Beta posterior of the authors' answers' rate, then fixed per prompt: fitted; read it as "
            "consistent with the paper where the interval holds the paper's value, compare its spread with the paper's ±, and "
            "mind that the rates were fitted to the images the authors' runs met and that most of its trials are decided by a "
            "draw, as each cell counts), or the rule-based mock: a sensitivity band."
        )
    return Built(None, None, [(item.id, table)], method)


def build_ratio_table(item: Item, matched: Sequence[Match]) -> Built:
    """Appendix table: performance ratio (total return of one method over another, per trial).

    The main ratio is the item's ``numerator`` over its ``denominator`` (the stack-size table:
    LaGR's over Q-learning's, as the paper's caption defines it); every other column of the item
    gets its own ratio over the same denominator beside it, labelled (LaGR-SEQ / Q-learning)."""
    numerator = str(item.options.get("numerator", ""))
    denominator = str(item.options.get("denominator", ""))
    rows, columns = _rows_columns(matched)
    others = [c for c in columns if c not in (numerator, denominator)]
    runs = {(m.row, m.spec.column): run for m, run in _present(matched)}
    notes = {(m.row, m.spec.column): m.note for m in matched}
    display = []
    data: list[dict[str, Any]] = []
    for row in rows:
        paper = _reference(item, row)
        main = _run_ratio(runs, row, numerator, denominator)
        beside = [_run_ratio(runs, row, c, denominator) for c in others]
        used = [prov.of_run(r) for x in (main, *beside) if x is not None for r in x[1:]]
        makers = prov.combined(used).kind if used else ""
        line = [row, makers or "—", _ratio_cell(main, notes.get((row, numerator))),
                *(_ratio_cell(b, notes.get((row, c))) for b, c in zip(beside, others, strict=True))]
        for column in (numerator, *others, denominator):
            run = runs.get((row, column))
            if run is None:
                line.append("not run")
                continue
            t_mean, _, t_se = stats.mean_std_se(list(run.total_per_trial("return").values()))
            line.append(f"{plus_minus(t_mean, t_se, 1)} (n={len(run.trials)})")
        line.append(paper or "—")
        display.append(tuple(line))
        for column, result in ((numerator, main), *zip(others, beside, strict=True)):
            if result is not None:
                data.append(_ratio_data(row, column, numerator, denominator, result, paper))
    table = _ratio_table(item, numerator, denominator, others, display, data)
    beside_text = "".join(f"; {c}'s ratio over the same trials beside it" for c in others)
    method = (
        f"Per trial, the total return of {numerator} divided by that of {denominator} with the same trial index "
        f"(same seed){beside_text}; mean ± standard error over trials (n per cell), and a 95% interval of the mean in the CSV (modified Cox, from the logs of the per-trial ratios: a ratio of returns is positive and the interval stays so; none below 3 trials)."
    )
    return Built(None, None, [(item.id, table)], method)


_Ratio = tuple[stats.Interval, Run, Run]


def _run_ratio(runs: Mapping[tuple[str, str | None], Run], row: str, top_column: str, denominator: str) -> _Ratio | None:
    """The per-trial return ratio of ``top_column`` over ``denominator`` in ``row``, with its two runs."""
    top, bottom = runs.get((row, top_column)), runs.get((row, denominator))
    if top is None or bottom is None:
        return None
    values = stats.paired_ratios(top.total_per_trial("return"), bottom.total_per_trial("return"))
    return _positive_summary(values), top, bottom


def _ratio_cell(made: _Ratio | None, note: str | None) -> str:
    """A ratio as its cell shows it: mean ± s.e. (n), with the cell's note."""
    if made is None:
        return "not run"
    s = made[0]
    return f"{plus_minus(s.mean, s.se, 3)} (n={s.n})" + (f"; {note}" if note else "")


def _ratio_data(row: str, column: str, numerator: str, denominator: str, result: _Ratio, paper: str) -> dict[str, Any]:
    """The CSV row of one ratio: its summary, provenance and the two mean returns."""
    s, top, bottom = result
    return {
        "row": row,
        "ratio": f"{column} / {denominator}",
        "main": column == numerator,
        "provenance": prov.combined([prov.of_run(top), prov.of_run(bottom)]).kind,
        "n": s.n,
        "ratio_mean": s.mean,
        "ratio_se": s.se,
        "ratio_std": s.std,
        "ci_low": s.ci_low,
        "ci_high": s.ci_high,
        "numerator_return": stats.mean_std_se(list(top.total_per_trial("return").values()))[0],
        "denominator_return": stats.mean_std_se(list(bottom.total_per_trial("return").values()))[0],
        "paper": paper if column == numerator else "",
    }


def _ratio_table(item: Item, numerator: str, denominator: str, others: Sequence[str], display: Sequence[tuple[Any, ...]],
                 data: Sequence[dict[str, Any]]) -> Table:
    """The ratio table: its title, columns, displayed rows and data."""
    header = str(item.options.get("row_header", ""))
    return Table(
        f"{item.title}: performance ratio {numerator} / {denominator}"
        + "".join(f" (beside it: {c} / {denominator})" for c in others),
        (
            header,
            "made by",
            f"performance ratio {numerator} / {denominator} (mean ± s.e.)",
            *(f"{c} / {denominator} (mean ± s.e.)" for c in others),
            *(f"{c} total return" for c in (numerator, *others, denominator)),
            f"paper: {numerator} / {denominator}",
        ),
        tuple(display),
        pd.DataFrame(data),
    )


def build_accuracy(item: Item, matched: Sequence[Match]) -> Built:
    """Fig. 4: the share of answers equal to the target at each fraction of the sequence shown."""
    lines = []
    frames = []
    for m, run in _present(matched):
        queries = run.queries[run.queries["queried"].astype(bool)]
        grouped = queries.groupby("prefix_length", sort=True)
        fraction = grouped["fraction"].first().to_numpy(dtype=float)
        correct = grouped["accepted"].apply(lambda a: int(a.fillna(False).astype(bool).sum()))
        count = grouped.size()
        accuracy = 100.0 * correct.to_numpy() / count.to_numpy()
        lines.append(figures.AccuracyLine(f"{m.label} [{made_by(run)}]", fraction, accuracy, run.samples))
        frames.append(
            pd.DataFrame(
                {
                    "series": m.label,
                    "provenance": made_by(run),
                    "prefix_length": count.index.to_numpy(),
                    "fraction": fraction,
                    "answers": count.to_numpy(),
                    "correct": correct.to_numpy(),
                    "accuracy_pct": accuracy,
                }
            )
        )
    axes = figures.accuracy(lines, title=item.title)
    method = "For each prefix of the target (1/N to N/N of the sequence), the percentage of the provider's answers that parse to exactly the target. A recorded store's answers are drawn without replacement (each prefix's recorded answers once each before any repeats), so a line of as many samples as the store holds shows the recorded counts."
    return Built(axes, pd.concat(frames, ignore_index=True), [], method)


def _flatten(config: dict[str, Any]) -> dict[str, str]:
    out: dict[str, str] = {}
    for section, values in config.items():
        if isinstance(values, dict):
            for name, value in values.items():
                out[f"{section}.{name}"] = json.dumps(value, ensure_ascii=False)
        else:
            out[section] = json.dumps(values, ensure_ascii=False)
    return out


def build_config_table(item: Item, matched: Sequence[Match]) -> Built:
    """The hyperparameter table: every configuration field of each run, as its log stores it."""
    present = _present(matched)
    flat = [_flatten(run.config) for _, run in present]
    fields: list[str] = []
    for values in flat:
        fields += [f for f in values if f not in fields]
    rows = []
    data = []
    for name in fields:
        cells = [values.get(name, "—") for values in flat]
        differs = len(set(cells)) > 1
        rows.append((f"{name} *" if differs else name, *cells))
        data.append(
            {
                "field": name,
                "differs": differs,
                **{m.label: c for (m, _), c in zip(present, cells, strict=True)},
            }
        )
    table = Table(
        f"{item.title}: configuration of each run (* = differs between runs)",
        ("field", *(m.label for m, _ in present)),
        tuple(rows),
        pd.DataFrame(data),
    )
    method = "Every field of each run's resolved configuration, read from the lagrseq.run metadata of its MCAP logs."
    return Built(None, None, [(item.id, table)], method)


def _policy_free(config: dict[str, Any]) -> dict[str, Any]:
    """A logged configuration without its asking policy (``[secondary]``'s policy fields) and
    method: what a matched-rate random run shares with the run it matches."""
    secondary = {k: v for k, v in dict(config.get("secondary", {})).items() if k not in cfg.POLICY_DEFAULTS}
    return {**{k: v for k, v in config.items() if k not in ("secondary", "method")}, "secondary": secondary}


def matched_randoms(panel: Sequence[Run], runs: Sequence[Run]) -> list[Run]:
    """The runs of ``random`` among ``runs`` at the query rate of one of the ``panel``'s learning
    policies (:func:`lagrseq.frontier_protocol.matched_probability` of its queries / decisions) that
    differ from it in the asking policy alone (the same task, preset, provider, seed, regime and
    every other field): ``lagrseq reproduce``'s second phase for the frontier items."""
    from lagrseq.frontier_protocol import matched_probability, wants_match

    wanted: list[tuple[float, dict[str, Any], Run]] = []
    for run in panel:
        policy = str(run.config.get("secondary", {}).get("policy", "seq"))
        if run.key.method != "lagr-seq" or not wants_match(policy, ()) or run.queries.empty:
            continue
        queries = int(run.queries["queried"].fillna(False).astype(bool).sum())
        if queries:
            wanted.append((matched_probability(queries, len(run.queries)), _policy_free(run.config), run))
    names = {run.key.name for run in panel}
    out = []
    for run in runs:
        secondary = run.config.get("secondary", {})
        if run.key.kind != "trial" or run.key.method != "lagr-seq" or secondary.get("policy") != "random" or run.key.name in names:
            continue
        for probability, rest, source in wanted:
            same = (run.key.task, run.key.preset, run.key.provider, run.key.seed) == (
                source.key.task, source.key.preset, source.key.provider, source.key.seed
            )
            if same and float(secondary.get("ask_probability", 0.5)) == probability and _policy_free(run.config) == rest:
                out.append(run)
                names.add(run.key.name)
                break
    return out


def build_frontier(item: Item, matched: Sequence[Match], price: Price | None = None, runs: Sequence[Run] = ()) -> Built:
    """The query-efficiency frontier of the item's asking-policy runs: ``lagrseq frontier``'s
    picture and table, made from the suite's logs. One panel per provider (the suite's default,
    and the authors' answers when ``reproduce --authors-caches`` added them) and regime
    (``lagr.solution_scope``); the ``never`` runs (which ask nothing, so any provider's and
    regime's serve) join every panel. The protocol's verdicts are in the table; the random runs
    at each learning policy's matched query rate that ``lagrseq reproduce`` ran after the
    policies (found among ``runs``, :func:`matched_randoms`) join their panel, so points can be
    credited."""
    from matplotlib.figure import Figure

    from lagrseq.analysis import frontier

    present = _present(matched)
    never = [run for _, run in present if run.key.method == "baseline"]
    # one panel per provider, regime and run.stop_at (an item whose trials stop at the first solve
    # has a panel of those and one of its full-length copies, each with its own never)
    panels: dict[tuple[str, str, str], list[Run]] = {}
    for _, run in present:
        if run.key.method != "baseline":
            panels.setdefault((run.key.provider, frontier.scope_of(run.config), frontier.stop_of(run.config)), []).append(run)
    for members in panels.values():
        members += matched_randoms(members, runs)
    if not panels:
        panels[(never[0].key.provider, frontier.scope_of(never[0].config), frontier.stop_of(never[0].config))] = []
    figure = Figure(figsize=(11.5, 9.2 * len(panels)), layout="constrained")
    made: Any = figure.subfigures(len(panels), 1) if len(panels) > 1 else None
    targets: list[Any] = [figure] if made is None else list(made)
    tables: list[tuple[str, Table]] = []
    frames = []
    scoped = len({scope for _, scope, _ in panels}) > 1  # name the regime only where there are several
    stopping = len({stop for _, _, stop in panels}) > 1
    counts: list[int] = []
    for n, (target, ((provider, scope, stop), members)) in enumerate(zip(targets, panels.items(), strict=True)):
        points = frontier.points_of([*(run for run in never if frontier.stop_of(run.config) == stop), *members], price)
        counts += [len(p.returns) for p in points]
        shown = frontier.table(points, provider=provider)
        frontier.draw(points, shown.title, figure=target)
        name = item.id if n == 0 else f"{item.id}-{_slug(provider)}" + (f"-{scope}" if scoped else "")
        if n and stopping:  # a stopped panel and its full-length copies' panel: named apart
            name += f"-{stop.replace('_', '-')}" if stop else "-full-horizon"
        tables.append((name, shown))
        frames.append(shown.data.assign(provider=provider))
    method = (
        "One point per asking policy: mean LLM queries (and US dollars: logged cost, else logged or estimated "
        "tokens at the price table) per trial against steps to the first solved episode (the primary outcome) "
        "and the return, 95% Student-t intervals of the mean on both axes (on the log scale for queries, dollars and steps, which cannot be negative). The table adds episodes solved per trial, "
        "two one-sided non-inferiority verdicts against always on steps to the first solve, on the pairs of "
        "trials the logs show ran the same seed and trial (no verdict where they do not pair): the mean per-pair "
        "log ratio (betting bound, valid for every distribution of the capped times, below log 1.1, a 10% margin; "
        "a trial that never solved counts at the step cap, the restricted-mean horizon) and the share of pairs more "
        "than 10% later (exact Clopper-Pearson bound below a 10% tail margin, shown at 5%, 10% and 20%; censored pairs "
        "counted apart), alpha 0.05, fewer than 10 pairs: provisional; every seed's role (a design or tuning seed "
        "of the policy is never credited); random at each "
        "learning policy's matched query rate (run by lagrseq reproduce after the policies, on the same seed and "
        "trials) and whether the policy beats it (the log ratio's bound below 0), credit (all three), trials "
        "whose first accepted answer came "
        "from outside the store, the interquartile mean of the return and the probability of improvement over "
        "always (lagrseq frontier --replay draws the same from these logs)."
    )
    if stopping:
        method += (
            " Trials of the panels titled 'trials stopped at the first solve' end with their first solved episode "
            "(queries counted to it; the matched random runs stop there too): their verdicts on steps to the first "
            "solve are the item's. The full-horizon panels hold the same policies' full-length trials on fewer pairs "
            "(queries and return over the whole trial; verdicts below 10 pairs provisional)."
        )
    if counts and max(counts) < inference_min_n():
        method += (
            f" Every verdict on this page is provisional: at most {max(counts)} trials per point, fewer than the "
            f"{inference_min_n()} a verdict needs (lagrseq reproduce without --quick runs more)."
        )
    return Built(figure.axes[0], pd.concat(frames, ignore_index=True), tables, method)


def inference_min_n() -> int:
    """Pairs below which every frontier verdict is provisional."""
    from lagrseq.analysis.paired import MIN_PAIRS

    return MIN_PAIRS


def _slug(provider: str) -> str:
    """A file-name part for a provider spec: ``mock-authors-t0``; a recorded store by its folder
    or file name alone (``recorded-authors-answers``), so names do not depend on where it is."""
    kind, _, argument = provider.partition(":")
    found = kind_of(provider)
    text = f"{kind}-{PurePath(argument).name}" if found is not None and found.replays else provider
    return "".join(ch if ch.isalnum() else "-" for ch in text).strip("-")[-40:]


def build(item: Item, matched: Sequence[Match], price: Price | None = None, runs: Sequence[Run] = ()) -> Built:
    """The item's builder (``item.render``) applied to its matched runs (``runs``: every logged
    run, where the frontier finds its matched-rate random runs)."""
    if item.render == "frontier":
        return build_frontier(item, matched, price, runs)
    return BUILDERS[item.render](item, matched)


BUILDERS: dict[str, Callable[[Item, Sequence[Match]], Built]] = {
    "returns": build_returns,
    "query-bars": build_query_bars,
    "query-table": build_query_table,
    "ratio-table": build_ratio_table,
    "accuracy": build_accuracy,
    "config-table": build_config_table,
    "frontier": build_frontier,  # also takes the price table (see :func:`build`)
}
