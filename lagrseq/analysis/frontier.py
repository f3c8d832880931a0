"""The query-efficiency frontier: return against queries and dollars per trial, one point per
asking policy, from the MCAP logs alone.

Each run found under the given directories is one point: its policy comes from the configuration
stored in its logs (``baseline`` is ``never``, ``lagr`` is ``always``, ``lagr-seq`` is
``secondary.policy`` with its knobs). Per trial: total return, steps to the end of the first
solved episode (the trial's length when none was solved), queries, dollars, and answers that a
fallback gave because the recorded store missed them. Points carry the tables' 95% Student-t
intervals of the mean on both axes, on the log scale for the quantities that cannot be negative
(queries, dollars, steps, episodes solved: an interval that never reaches below 0; the return on
its own scale); the variants of one policy (a swept knob) are joined into a curve. Tables give means
with intervals, the interquartile mean of the return with a stratified bootstrap interval, and
the probability that a trial of the policy returns more than one of ``always``. The paper's SEQ
(``seq`` with no knob changed) and LaGR (``always``) rows are marked.

The protocol (docs/frontier.md). Primary outcomes: steps to the end of the first solved episode
(lower is better; a trial that solves none counts at the step cap, :func:`horizon`) and episodes
solved per trial; the return is secondary. The points of a panel run the same (seed, trial) pairs,
so trial ``i`` of every policy saw the same environment draws (common random numbers); where the
logs show two points ran the same seed and the same trials (:func:`paired_order`) each asking
point is judged against ``always`` on steps to the first solve by two estimands of
:mod:`lagrseq.analysis.paired`, each with bounds that hold their level for every distribution of
the capped times:

* the **mean per-pair log ratio** ``mean(log(policy_i / always_i))`` with one-sided 95% betting
  bounds (:func:`lagrseq.analysis.paired.slowdown`; relative margin 10%, :data:`MARGIN`, so the
  upper bound must lie below ``log(1.1)``), and
* the **tail share**: the share of pairs in which the policy is more than 10% later than always,
  with exact Clopper-Pearson bounds, judged at a tail margin of 10% fixed in advance and shown at
  5%, 10% and 20%; censored pairs (neither arm solved by the cap) are counted apart, and a tail
  verdict needs the same answer with them counted as late and as on time.

Below :data:`lagrseq.analysis.paired.MIN_PAIRS` pairs every verdict reads ``provisional``. Where
the logs do not pair the points (another seed, a trial missing in either), there is no verdict.
Each learning policy's point is also compared with ``random`` asking at the point's own mean query
rate (queries / decisions, from its logs; the random run is found by its ``ask_probability``,
:func:`lagrseq.frontier_protocol.matched_probability`): it *beats* it when the upper bound of the
mean log ratio against that run lies below 0. A point is *credited* only when it is non-inferior to
always on the mean log ratio **and** on the tail share **and** beats random at the matched rate
(an intersection-union test at level 0.05), none of them provisional, **and** its run seed is an
evaluation seed of its policy (:func:`seed_role`: a seed the policy's rule was read from, its
design seed, or one ``--tune`` chose its knob on is "not evidence"). The oracle (it peeks at the
answer before deciding) is shown as the bound and never credited, and points whose run answered
store misses with the mock or a calibrated draw get no verdict. Episodes solved per trial get the
paired t test of :func:`lagrseq.analysis.inference.paired_noninferiority` (margin 10% of always's
mean), shown beside the verdicts but not entering the credit. Runs are grouped into panels by
task, preset, provider, seed, ``lagr.solution_scope`` and ``run.stop_at`` (trials stopped at their
first solve make their own panel, whose query column counts the queries to the first solve).

Dollars: a query's logged ``cost_usd`` when it has one; else its logged token usage priced by
``price``; else (answers imported from the authors' caches carry no usage) the median token
usage of the queries of the same task that have one (the mock estimates about 4 characters a
token), marked as estimated. No usage anywhere: NaN.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

from lagrseq import outputs
from lagrseq.analysis import inference, paired, stats
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.figures import COLORS, STYLE
from lagrseq.analysis.loading import Run, load
from lagrseq.analysis.misses import missed, on_store, percent
from lagrseq.analysis.tables import Table, number, to_csv, to_markdown
from lagrseq.errors import LogError
from lagrseq.frontier_protocol import TUNING_NOTE, matched_probability, wants_match
from lagrseq.logs.reader import read_info
from lagrseq.registry import CALIBRATED_MISS, kind_of, paid_sources

Price = Callable[[str, int, int], float | None]
MISS_THRESHOLD = 0.1
"""Default: a point whose answers came from a fallback for more than this share is marked."""
PAPER_ROWS = {"seq": "SEQ (paper)", "always": "LaGR (paper)"}
ORACLE_LABEL = "oracle (peeks at the answer)"
"""The oracle decides after looking at the answer: a bound on queries, not a policy."""
MARGIN = 0.10
"""Non-inferiority margin on the mean per-pair log ratio of steps to the first solved episode:
``log(1.1)``, a policy at most 10% later than always on the geometric mean. A policy that
reaches its first solve at most 10% later than asking at every trigger has kept what guidance is
for (the paper's claim is sample efficiency), and 10% is the relative margin the reproduction's
other verdicts use (:data:`lagrseq.analysis.inference.RELATIVE_MARGIN`). The same 10% margin
on episodes solved per trial is 10% of always's mean."""
LATE = paired.LATE
"""The tail estimand: a pair is late when the policy's first solve is more than 10% later."""
TAIL_MARGIN = paired.TAIL_MARGIN
"""The tail verdict's margin, fixed in advance: the late share's exact upper bound must lie below
10% (:data:`lagrseq.analysis.paired.TAIL_MARGIN`)."""
ALPHA = inference.ALPHA
STOP_TEXT = {"first_solve": "trials stopped at the first solve"}
"""``run.stop_at`` as a panel's title says it (the default, "", says nothing)."""

DPI = 150
_DEFAULTS = {"query_cost": 0.0, "budget": 0, "ask_probability": 0.5, "thompson_prior": [1.0, 1.0], "min_progress": 0, "stall_steps": 64}


def _knob_text(name: str, value: Any) -> str:
    """A plugin knob as a point's label shows it: ``flag yes``/``flag no`` for a boolean,
    ``factor 0.25`` for a number."""
    if isinstance(value, bool):
        return f"{name} {'yes' if value else 'no'}"
    return f"{name} {value:g}" if isinstance(value, float) else f"{name} {value}"


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
    if name == "seq":
        knobs.append(_learning_text(config))
    if name == "advance":
        knobs.append(f"stall {section.get('stall_steps', 64)}")
        if section.get("reask_decay", 0.0):
            knobs.append(f"reask {section['reask_decay']:g}")
    if name == "thompson" and list(section.get("thompson_prior", [1.0, 1.0])) != [1.0, 1.0]:
        a, b = section["thompson_prior"]
        knobs.append(f"prior {a:g},{b:g}")
    if section.get("query_cost", 0.0):
        knobs.append(f"cost {section['query_cost']:g}")
    if section.get("budget", 0):
        knobs.append(f"budget {section['budget']}/{section.get('budget_scope', 'trial')}")
    if section.get("min_progress", 0):
        knobs.append(f"gate {section['min_progress']}")
    own = section.get("knobs") or {}  # a plugin policy's own knobs, where set
    knobs += [_knob_text(k, v) for k, v in sorted(own.items())]
    return name, " ".join(k for k in knobs if k)


EPSILON_FIELDS = ("epsilon_schedule", "epsilon_start", "epsilon_min", "epsilon_decay", "epsilon_unit")
"""The SEQ bandit's exploration schedule: a seq point whose schedule is not its preset's says so."""


@functools.lru_cache(maxsize=32)
def _preset_epsilon(task: str, preset: str) -> tuple[Any, ...] | None:
    from lagrseq import config as cfg

    try:
        section = cfg.load(task, "lagr-seq", preset).secondary
    except Exception:  # a task or preset this installation does not know: nothing to compare with
        return None
    return tuple(getattr(section, f) for f in EPSILON_FIELDS)


def _learning_text(config: dict[str, Any]) -> str:
    """``epsilon exponential 0.998/step`` for a seq run whose exploration schedule differs from
    its preset's (the learning SEQ on the grids, whose upstream SEQ never decays); ""
    where it is the preset's own (so the paper's rows keep their names)."""
    section = config.get("secondary", {})
    task = (config.get("task") or {}).get("name")
    preset = config.get("preset")
    if not isinstance(task, str) or not isinstance(preset, str):
        return ""
    own = _preset_epsilon(task, preset)
    given = tuple(section.get(f) for f in EPSILON_FIELDS)
    if own is None or given == own or None in given:
        return ""
    schedule, start, minimum, decay, unit = given
    if schedule == "constant":
        return f"epsilon {start:g}"
    if schedule == "exponential":
        return f"epsilon exponential {decay:g}/{unit}, min {minimum:g}"
    return f"epsilon {schedule}, min {minimum:g}"


def _knob_value(config: dict[str, Any]) -> float:
    """The value a policy's curve is ordered by (its swept knob, whichever differs)."""
    section = config.get("secondary", {})
    own = [float(v) for _, v in sorted((section.get("knobs") or {}).items()) if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return (
        float(section.get("query_cost", 0.0)) + float(section.get("budget", 0)) * 1e-6
        + float(section.get("ask_probability", 0.5)) * 1e-9 + float(section.get("min_progress", 0)) * 1e-3
        + float(section.get("stall_steps", 64)) * 1e-13 + float(section.get("reask_decay", 0.0)) * 1e-15 + sum(own) * 1e-12  # a plugin policy's own knobs, last
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
    episodes_solved: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Solved episodes per trial (a primary outcome)."""
    outside: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    """Per trial: its first accepted answer came from outside the recorded store (a fallback)."""
    decisions: float = 0.0
    """Secondary decisions (asked or not) over all trials: the denominator of the query rate."""
    on_miss: str = ""
    """``recorded:STORE`` runs: what answered store misses (error, mock, refuse, live)."""
    tuning: dict[str, Any] = field(default_factory=dict)
    """``lagrseq frontier --tune``'s note in the run's metadata (empty: knobs as given)."""

    @property
    def label(self) -> str:
        name = ORACLE_LABEL if self.policy == "oracle" else self.policy
        return f"{name} ({self.knobs})" if self.knobs else name

    @property
    def rate(self) -> float:
        """Queries per secondary decision, over all trials (NaN without decisions)."""
        return float(self.queries.sum()) / self.decisions if self.decisions else math.nan

    def flagged(self, threshold: float) -> bool:
        """More than ``threshold`` of its answers came from a fallback (refusals are no answers:
        a ``refuse`` run is never flagged)."""
        return self.on_miss != "refuse" and self.miss_share > threshold

    @property
    def fallback_labelled(self) -> bool:
        """At least one store miss was answered by the rule-based mock or a calibrated draw
        (fitted to the store's answers): no verdict. A run whose every answer came from the store
        is judged like a ``refuse`` run: its fallback decided nothing."""
        return self.on_miss in ("mock", CALIBRATED_MISS) and float(self.fallback.sum()) > 0

    @property
    def miss_share(self) -> float:
        total = float(self.queries.sum())
        return float(self.fallback.sum()) / total if total else 0.0


def _panel_key(run: Run) -> tuple[str, str, str, int, str, str]:
    return (run.key.task, run.key.preset, run.key.provider, run.key.seed, scope_of(run.config), stop_of(run.config))


def stop_of(config: dict[str, Any]) -> str:
    """Where a trial stops early (``run.stop_at``): "" (never: the full horizon), ``first_solve``."""
    return str(config.get("run", {}).get("stop_at", "") or "")


def horizon(*points: Point) -> float:
    """The step cap of ``points``' trials, the horizon of the restricted mean and the range of the
    log ratio, fixed by the configuration before any trial ran: ``run.max_steps`` where set, else
    ``run.episodes`` times ``env.horizon`` (the cube: 100 episodes of at most 100 steps); never
    less than the longest trial logged (a configuration without either: the longest trial)."""
    cap = 0.0
    for p in points:
        config = p.run.config
        steps = float(config.get("run", {}).get("max_steps", 0) or 0)
        episodes = float(config.get("run", {}).get("episodes", 0) or 0)
        length = float(config.get("env", {}).get("horizon", 0) or 0)
        cap = max(cap, steps if steps > 0 else episodes * length)
        if len(p.steps_to_solve):
            cap = max(cap, float(np.nanmax(p.steps_to_solve)))
    return cap if cap > 0 else math.inf


def scope_of(config: dict[str, Any]) -> str:
    """How long an accepted answer is kept: ``episode`` or ``trial`` (``lagr.solution_scope``)."""
    return str(config.get("lagr", {}).get("solution_scope", "trial"))


SCOPE_TEXT = {"episode": "answer kept for one episode", "trial": "answer kept for the trial"}


def _metadata(run: Run) -> dict[str, str]:
    """The run metadata record of the run's first trial log (empty when unreadable)."""
    if not run.paths:
        return {}
    try:
        return dict(read_info(run.paths[0]).run)
    except (LogError, OSError, ValueError):
        return {}


def _json_field(text: str | None) -> dict[str, Any]:
    import json

    if not text:
        return {}
    try:
        value = json.loads(text)
    except ValueError:
        return {}
    return value if isinstance(value, dict) else {}


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
    paid = paid_sources()
    asked = str(run.config.get("llm", {}).get("model", ""))  # what a live run would pay for
    for trial, model, source, cost, prompt, completion in zip(
        sent["trial"], sent["model"], sent["source"], sent["cost_usd"], sent["prompt_tokens"],
        sent["completion_tokens"], strict=True,
    ):
        usd: float | None = None
        if source in paid and not _nan(cost):
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
    a token): the task's registered ``estimated_tokens`` (None: the task has no estimate)."""
    from lagrseq.registry import TASKS

    task = config.get("task", {})
    spec = TASKS.find(str(task.get("name"))) if isinstance(task, dict) else None
    if spec is None or spec.estimated_tokens is None:
        return None
    return spec.estimated_tokens(config)


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
    returns, steps, solved, count = [], [], [], []
    for trial in trials:
        rows = episodes[episodes["trial"] == trial].sort_values("episode")
        returns.append(float(rows["return"].sum()))
        done = rows[rows["solved"].astype(bool)]
        solved.append(not done.empty)
        count.append(float(len(done)))
        steps.append(float(done["global_step"].iloc[0]) if not done.empty else float(rows["length"].sum()))
    q = run.queries
    sent = q[q["queried"].astype(bool)] if not q.empty else q
    kind = kind_of(str(run.key.provider))
    recorded = kind is not None and kind.replays
    queries = np.array([float((sent["trial"] == t).sum()) if len(sent) else 0.0 for t in trials])
    if kind is not None and kind.replays and len(sent):
        missing = missed(sent["source"])
        fallback = np.array([float(((sent["trial"] == t) & missing).sum()) for t in trials])
    else:
        fallback = np.zeros(len(trials))
    outside = np.array(prov.decided_by_fallback(run), dtype=bool)
    dollars, estimated = _dollars(run, price, fallback_tokens)
    metadata = _metadata(run)
    return Point(
        policy, knobs, run, np.array(returns), np.array(steps), np.array(solved), queries, dollars, fallback, estimated,
        episodes_solved=np.array(count), outside=outside, decisions=float(len(q)) if not q.empty else 0.0,
        on_miss=str(_json_field(metadata.get("provider_options")).get("on_miss", "")) if recorded else "",
        tuning=_json_field(metadata.get(TUNING_NOTE)),
    )


def _misses_cell(p: Point) -> str:
    """A point's store misses as every table shows them ("misses: k of n answers (x%)", with what
    answered them: refused, or a fallback that can be right); "—" for a point on no store."""
    if not on_store(str(p.run.key.provider)):
        return "—"
    missed_answers, answers = int(p.fallback.sum()), int(p.queries.sum())
    line = f"misses: {missed_answers} of {answers} answers ({percent(missed_answers, answers)})"
    if p.on_miss == "refuse":
        return line + ", refused"
    if missed_answers and p.on_miss:
        return line + f", answered by the {p.on_miss} fallback, which can be right"
    return line


def policy_order(name: str) -> int:
    """Where a policy goes in tables and figures: its registered ``order`` (unknown ones last)."""
    from lagrseq.registry import POLICIES

    spec = POLICIES.find(name)
    return 1000 if spec is None else spec.order


def points_of(runs: Sequence[Run], price: Price | None) -> list[Point]:
    """One summarised point per run, in the tables' order (policy, then the swept knob)."""
    tokens = _median_tokens(runs)
    points = [point_of(run, price, tokens) for run in runs]
    points.sort(key=lambda p: (policy_order(p.policy), _knob_value(p.run.config), p.knobs))
    summarise(points)
    return points


NON_NEGATIVE = ("steps_to_solve", "queries", "dollars", "episodes_solved")
"""The point quantities that cannot be negative: their intervals are taken on the log scale."""
MIN_TRIALS_FOR_INTERVAL = 3
"""Trials below which a cell shows no interval (at 2 the t quantile makes it span orders of magnitude)."""


def summarise(points: Sequence[Point]) -> None:
    """Means with the tables' 95% Student-t intervals, on the log scale for :data:`NON_NEGATIVE`
    quantities (:func:`lagrseq.analysis.stats.summarize_t`), so an interval never reaches below 0,
    and steps to the first solve never above the trials' step budget (``run.max_steps``, where one
    is set); values without spread have the value itself as both bounds; below
    :data:`MIN_TRIALS_FOR_INTERVAL` trials, no interval (NaN)."""
    for p in points:
        for name in ("returns", "steps_to_solve", "queries", "dollars", "episodes_solved"):
            values = np.asarray(getattr(p, name), dtype=float)
            if len(values) < MIN_TRIALS_FOR_INTERVAL or np.isnan(values).any():
                p.summary[name] = (float(np.mean(values)) if len(values) else math.nan, math.nan, math.nan)
                continue
            found = stats.summarize_t(values, positive=name in NON_NEGATIVE)
            low, high = found.ci_low, found.ci_high
            cap = float(p.run.config.get("run", {}).get("max_steps", 0) or 0)
            if name == "steps_to_solve" and cap > 0 and math.isfinite(high):
                high = min(high, cap)  # no trial solves past its step budget: the interval stays in range
            if np.all(values == values[0]):
                low = high = float(values[0])
            p.summary[name] = (found.mean, low, high)


def outward(low: float, high: float, digits: int) -> str:
    """``[low, high]`` rounded outward to ``digits`` decimals (the shown interval holds the
    computed one); ``n/a`` where there is none."""
    if math.isnan(low) or math.isnan(high):
        return "n/a"
    scale = 10.0**digits
    return f"[{math.floor(low * scale) / scale:.{digits}f}, {math.ceil(high * scale) / scale:.{digits}f}]"


def _cell(summary: tuple[float, float, float], digits: int) -> str:
    mean, low, high = summary
    shown = outward(low, high, digits)
    return f"{number(mean, digits)} {shown if shown != 'n/a' else f'(n < {MIN_TRIALS_FOR_INTERVAL}: no interval)'}"


DESIGN = "design"
TUNING = "tuning"
EVALUATION = "evaluation"


def design_seeds(policy: str) -> tuple[int, ...]:
    """The run seeds whose logs ``policy``'s rule or defaults were read from (its registry
    entry's ``design_seeds``; none for a policy this installation does not know)."""
    from lagrseq.registry import POLICIES

    spec = POLICIES.find(policy)
    return tuple(getattr(spec, "design_seeds", ())) if spec is not None else ()


def tuning_seeds(p: Point) -> tuple[int, ...]:
    """The run seeds ``--tune`` chose this point's knob on (from its logs' tuning note)."""
    if p.tuning.get("role") == "tuning":
        return (int(p.run.key.seed),)
    seed = p.tuning.get("tuning_seed")
    return (int(seed),) if isinstance(seed, int) else ()


def seed_role(p: Point) -> str:
    """The role of the point's run seed for its policy: ``design`` (its rule was read from that
    seed's logs), ``tuning`` (``--tune`` ran candidates on it) or ``evaluation``."""
    seed = int(p.run.key.seed)
    if seed in design_seeds(p.policy):
        return DESIGN
    if seed in tuning_seeds(p):
        return TUNING
    return EVALUATION


@dataclass(frozen=True)
class Verdict:
    """A point judged by the protocol (see the module): against always on the mean log ratio and
    on the tail share, and against random at its matched query rate, all on steps to the first
    solved episode."""

    against_always: paired.SlowdownVerdict | None
    """The mean per-pair log ratio against always (None: no verdict, the point is always itself
    or its misses were answered by the mock)."""
    tail: paired.TailVerdict | None
    """The share of pairs more than 10% later than always, with its exact bounds."""
    solved_against_always: inference.NonInferiority | None
    """The paired t test on episodes solved per trial (higher is better; shown, not used for credit)."""
    matched: Point | None
    """The random run at this point's query rate (None: not wanted, or not run)."""
    against_random: paired.SlowdownVerdict | None
    """Margin 0: ``non-inferior`` here means the mean log ratio's upper bound lies below 0 (the
    point beats random)."""
    credited: bool
    note: str
    role: str = EVALUATION
    """The run seed's role for the point's policy (:func:`seed_role`)."""

    @property
    def always_text(self) -> str:
        v = self.against_always
        if v is None:
            return self.note or "n/a"
        return f"{v.verdict} ({_slowdown_text(v)})"

    @property
    def tail_text(self) -> str:
        v = self.tail
        if v is None:
            return self.note or "n/a"
        if not v.n:
            return f"{v.verdict} ({v.reason})"
        censored = f", {v.censored} censored (bound {_percent_up(v.upper_if_late)} counted late)" if v.censored else ""
        return f"{v.verdict} ({v.late_pairs} of {v.n} pairs late{censored}, bound {_percent_up(v.upper)} vs {100 * v.margin:.0f}%)"

    @property
    def tail_margins_text(self) -> str:
        v = self.tail
        if v is None or not v.n:
            return self.note or "n/a"
        return "; ".join(f"{100 * m:.0f}%: {said}" for m, said in v.at_margins)

    @property
    def solved_text(self) -> str:
        if self.solved_against_always is None:
            return self.note or "n/a"
        return self.solved_against_always.verdict

    @property
    def beats_random(self) -> bool:
        return self.against_random is not None and self.against_random.verdict == paired.NON_INFERIOR

    @property
    def random_text(self) -> str:
        if self.matched is None:
            return "n/a"
        v = self.against_random
        assert v is not None
        if self.beats_random:
            said = "beats"
        elif v.n == 0 or v.verdict.startswith(paired.PROVISIONAL):
            said = "no verdict"
        else:
            said = "does not beat"
        return f"{said} ({_slowdown_text(v)})"

    @property
    def credit_text(self) -> str:
        if self.role != EVALUATION:
            return f"no ({self.role} seed: not evidence)"
        return "yes" if self.credited else "no"


PAIRS_MISSING = "pairs missing"
"""The reason of a comparison whose logs do not pair the trials (no verdict)."""


def _percent_up(share: float) -> str:
    """A bound of a share in percent, rounded up to 0.1 (outward for an upper bound)."""
    return f"{math.ceil(1000 * share) / 10:.1f}%"


def _slowdown_text(v: paired.SlowdownVerdict) -> str:
    """``ratio 1.02, 95% bounds [0.41, 2.43], margin 1.10, n = 30 pairs, 27 ties``: the
    geometric-mean time ratio, its one-sided betting bounds (rounded outward) and the margin on
    the ratio scale; or why there is none."""
    if v.n == 0:
        return v.reason
    low = math.floor(100 * paired._exp(v.lower)) / 100
    high = math.ceil(100 * paired._exp(v.upper)) / 100
    extra = "".join(
        f", {k} {what}" for k, what in ((v.ties, "ties"), (v.censored, "censored")) if k
    )
    return f"ratio {v.ratio:.3g}, {1 - v.alpha:.0%} bounds [{low:.2f}, {high:.2f}], margin {paired._exp(v.margin):.2f}, n = {v.n} pairs{extra}"


def paired_order(a: Point, b: Point) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the design pairs two points: index arrays that line up ``a``'s and ``b``'s per-trial
    values trial by trial. They pair when their logs name the same run seed and the same set of
    trials (every stream of a trial derives from (seed, trial), so trial ``i`` of both saw the
    same environment draws); None when a seed differs or a trial is missing from either."""
    if a.run.key.seed != b.run.key.seed:
        return None
    ta, tb = [int(t) for t in a.run.trials], [int(t) for t in b.run.trials]
    if len(ta) != len(set(ta)) or sorted(ta) != sorted(tb) or len(ta) != len(a.steps_to_solve) or len(tb) != len(b.steps_to_solve):
        return None
    return np.argsort(ta, kind="stable"), np.argsort(tb, kind="stable")


def compare(p: Point, q: Point, outcome: str, margin: float, higher_is_better: bool = True) -> inference.NonInferiority:
    """``p`` against ``q`` on ``outcome`` (a per-trial array of :class:`Point`) by the t tests of
    :mod:`lagrseq.analysis.inference`: the paired test where the logs pair them
    (:func:`paired_order`), else Welch's. The frontier uses it for episodes solved per trial
    only (shown, not credited); steps to the first solve go through :func:`slowdown`."""
    x, y = getattr(p, outcome), getattr(q, outcome)
    order = paired_order(p, q)
    if order is not None:
        return inference.paired_noninferiority(x[order[0]], y[order[1]], margin, higher_is_better=higher_is_better, alpha=ALPHA)
    return inference.noninferiority(x, y, margin, higher_is_better=higher_is_better, alpha=ALPHA)


def _missing(p: Point, q: Point) -> str:
    if p.run.key.seed != q.run.key.seed:
        return f"{PAIRS_MISSING}: seed {p.run.key.seed} against {q.run.key.seed}, no verdict"
    return f"{PAIRS_MISSING}: trials {len(p.steps_to_solve)} against {len(q.steps_to_solve)} do not match, no verdict"


def capped_times(p: Point, cap: float) -> np.ndarray:
    """Steps to the first solve with every trial that never solved at ``cap`` (the restricted
    mean's horizon; a trial that never solved is censored there)."""
    return np.where(p.solved.astype(bool), np.minimum(p.steps_to_solve, cap), cap)


def slowdown(p: Point, q: Point, margin: float = MARGIN, cap: float | None = None) -> paired.SlowdownVerdict:
    """``p`` against ``q`` on steps to the first solve: the mean per-pair log ratio with its
    betting bounds (:func:`lagrseq.analysis.paired.slowdown`, relative ``margin``, ``cap`` the
    restricted-mean horizon; None: the two points' :func:`horizon`). No pairs in the logs: an
    inconclusive verdict whose reason starts with :data:`PAIRS_MISSING`."""
    cap = horizon(p, q) if cap is None else cap
    order = paired_order(p, q)
    if order is None or not math.isfinite(cap) or cap <= 1.0:
        reason = _missing(p, q) if order is None else "no step cap in the logs, no verdict"
        return paired.SlowdownVerdict(paired.INCONCLUSIVE, math.nan, math.nan, math.nan, math.log1p(margin), 0, cap, reason)
    x, y = capped_times(p, cap)[order[0]], capped_times(q, cap)[order[1]]
    return paired.slowdown(x, y, cap, relative_margin=margin)


def tail(p: Point, q: Point, cap: float | None = None) -> paired.TailVerdict:
    """The share of pairs in which ``p`` reaches its first solve more than :data:`LATE` later
    than ``q``, censored pairs apart, with exact bounds and verdicts at :data:`TAIL_MARGIN`."""
    cap = horizon(p, q) if cap is None else cap
    order = paired_order(p, q)
    if order is None or not math.isfinite(cap) or cap <= 1.0:
        reason = _missing(p, q) if order is None else "no step cap in the logs, no verdict"
        return paired.TailVerdict(paired.INCONCLUSIVE, 0, 0, math.nan, math.nan, LATE, TAIL_MARGIN, reason)
    return paired.tail(capped_times(p, cap)[order[0]], capped_times(q, cap)[order[1]], cap, LATE, TAIL_MARGIN)


def _settled(verdict: str) -> str:
    """A verdict that counts: provisional ones do not."""
    return "" if verdict.startswith(paired.PROVISIONAL) else verdict


def judge(points: Sequence[Point]) -> dict[int, Verdict]:
    """id(point) -> its verdict (see the module: estimands, margins, seed roles, credit)."""
    reference = next((p for p in points if p.policy == "always" and not p.knobs), None)
    randoms: dict[float, Point] = {}
    for p in points:
        if p.policy == "random" and not p.fallback_labelled:
            randoms.setdefault(float(p.run.config.get("secondary", {}).get("ask_probability", 0.5)), p)
    cap = horizon(*points)  # the panel's step cap: one restricted-mean horizon for all its comparisons
    out: dict[int, Verdict] = {}
    for p in points:
        role = seed_role(p)
        if p.fallback_labelled:
            note = "no verdict: misses answered by the mock" if p.on_miss == "mock" else "no verdict: misses answered by a calibrated draw (fitted)"
            out[id(p)] = Verdict(None, None, None, None, None, False, note, role)
            continue
        if reference is None or p is reference:
            out[id(p)] = Verdict(None, None, None, None, None, False, "reference" if p is reference else "no always run", role)
            continue
        versus = slowdown(p, reference, cap=cap)
        late = tail(p, reference, cap=cap)
        solved = compare(p, reference, "episodes_solved", MARGIN * float(np.mean(reference.episodes_solved)))
        matched = against = None
        if wants_match(p.policy, p.knobs) and not math.isnan(p.rate) and p.rate > 0:
            rate = matched_probability(float(p.queries.sum()), p.decisions)
            matched = reference if rate >= 1.0 else randoms.get(rate)  # random at rate 1 is always
            if matched is not None:
                against = slowdown(p, matched, margin=0.0, cap=cap)
        credited = (
            p.policy != "oracle" and role == EVALUATION
            and _settled(versus.verdict) == paired.NON_INFERIOR and _settled(late.verdict) == paired.NON_INFERIOR
            and against is not None and _settled(against.verdict) == paired.NON_INFERIOR
        )
        out[id(p)] = Verdict(versus, late, solved, matched, against, credited, "", role)
    return out


EQUIVALENCE_COLUMN = "vs matched random: equivalence (geometric-mean ratio of steps to first solve, margin 10% either way)"


def equivalence_to_random(p: Point, verdict: Verdict, cap: float) -> paired.EquivalenceVerdict | None:
    """The point against random at its matched rate on steps to the first solve, by two one-sided
    betting bounds on the mean per-pair log ratio (:func:`lagrseq.analysis.paired.equivalence`,
    margin log(1.1) either way, each at level 0.05), with superiority (``faster``) beside it.
    None where there is no matched run, the two do not pair, or the logs give no step cap."""
    matched = verdict.matched
    if matched is None or not math.isfinite(cap) or cap <= 1.0:
        return None
    order = paired_order(p, matched)
    if order is None:
        return None
    return paired.equivalence(capped_times(p, cap)[order[0]], capped_times(matched, cap)[order[1]], cap, MARGIN)


def equivalence_text(e: paired.EquivalenceVerdict | None) -> str:
    """``equivalent (ratio 1.01, 90% [0.97, 1.05], n = 300 pairs)``; ``; faster`` where it beats:
    the TOST's two one-sided bounds as one (1 - 2 alpha) interval, rounded outward."""
    if e is None:
        return "n/a"
    if e.n == 0:
        return f"{e.verdict} ({e.reason})"
    low = math.floor(100 * paired._exp(e.lower)) / 100
    high = math.ceil(100 * paired._exp(e.upper)) / 100
    faster = "; faster" if e.faster else ""
    level = 1.0 - 2.0 * e.alpha
    return f"{e.verdict}{faster} (ratio {e.ratio:.2f}, {level:.0%} [{low:.2f}, {high:.2f}], n = {e.n} pairs)"


@dataclass(frozen=True)
class Row:
    """One frontier table row, each cell by name (the Markdown columns follow this order:
    :func:`column_names`; the CLI prints cells by name, never by position)."""

    label: str
    paper: str
    knobs_chosen: str
    seed_role: str
    trials: str
    queries: str
    query_rate: str
    usd: str
    steps: str
    episodes_solved: str
    solved_trials: str
    vs_always: str
    tail: str
    tail_margins: str
    matched_random: str
    vs_random: str
    credited: str
    vs_always_episodes_solved: str
    returns: str
    return_iqm: str
    p_improvement: str
    store_misses: str
    outside_store: str
    queries_vs_always: str
    equivalence: str


def column_names(cap: float, stopped: bool) -> tuple[str, ...]:
    """The table's column headers, in :class:`Row`'s field order."""
    names = {
        "label": "policy", "paper": "paper", "knobs_chosen": "knobs chosen",
        "seed_role": "seed (role: design, tuning or evaluation)", "trials": "trials",
        "queries": "queries to the first solve / trial [95% CI]" if stopped else "queries / trial [95% CI]",
        "query_rate": "query rate", "usd": "USD / trial [95% CI]", "steps": "steps to first solve [95% CI]",
        "episodes_solved": "episodes solved / trial [95% CI]", "solved_trials": "solved trials",
        "vs_always": f"vs always on steps to first solve: mean log ratio (margin 10%, horizon {number(cap, 0)} steps)",
        "tail": f"vs always: pairs > {100 * LATE:.0f}% later (exact bound, tail margin {100 * TAIL_MARGIN:.0f}%)",
        "tail_margins": "tail verdict at 5% / 10% / 20%",
        "matched_random": "random at the matched rate: steps to first solve",
        "vs_random": "vs matched random (mean log ratio < 0)", "credited": "credited",
        "vs_always_episodes_solved": "vs always on episodes solved (margin 10%)",
        "returns": "return / trial [95% CI]", "return_iqm": "return IQM [95% CI]",
        "p_improvement": "P(return > always) [95% CI]",
        "store_misses": "store misses (refused, or answered by a fallback)",
        "outside_store": "trials decided outside the store", "queries_vs_always": "queries vs always",
        "equivalence": EQUIVALENCE_COLUMN,
    }
    return tuple(names[f.name] for f in dataclasses.fields(Row))


@dataclass(frozen=True)
class Panel:
    """A frontier panel's table and its rows by name."""

    table: Table
    rows: tuple[Row, ...]


def table(points: Sequence[Point], miss_threshold: float = MISS_THRESHOLD, provider: str | None = None) -> Table:
    """The frontier table (:func:`panel`'s)."""
    return panel(points, miss_threshold, provider).table


def panel(points: Sequence[Point], miss_threshold: float = MISS_THRESHOLD, provider: str | None = None) -> Panel:
    """The frontier table: one row per policy variant (paper rows marked, the oracle as the
    bound), with the protocol's verdicts and every seed's role, and its rows by name.
    ``provider``: the one named in the title (default: the first point's)."""
    reference = next((p for p in points if p.policy == "always" and not p.knobs), None)
    verdicts = judge(points)
    cap = horizon(*points) if points else math.nan
    stopped = bool(points) and any(stop_of(p.run.config) == "first_solve" for p in points)
    made = [_row(p, verdicts[id(p)], reference, miss_threshold, cap) for p in points]
    rows = tuple(row for row, _ in made)
    shown = Table(
        _title(points, provider), column_names(cap, stopped), tuple(dataclasses.astuple(r) for r in rows),
        pd.DataFrame([data for _, data in made]),
    )
    return Panel(shown, rows)


def _title(points: Sequence[Point], provider: str | None) -> str:
    first = points[0].run.key if points else None
    if first is None:
        return "Frontier"
    shown = provider if provider is not None else first.provider
    # the regime of the panel's asking policies: ``never`` (the baseline) joins every panel and
    # asks nothing, so its own configuration names no regime
    asking = next((p for p in points if p.run.key.method != "baseline"), points[0])
    scope = SCOPE_TEXT.get(scope_of(asking.run.config), scope_of(asking.run.config))
    role = " (tuning seeds)" if any(p.tuning.get("role") == "tuning" for p in points) else ""
    stop = STOP_TEXT.get(stop_of(asking.run.config), "")
    title = f"Query-efficiency frontier: {first.task} ({first.preset}, {shown}, seed {first.seed}{role}; {scope}{'; ' + stop if stop else ''})"
    if points[0].run.config.get("env", {}).get("wrong_cube_reward") == "pre-revert":
        title += " [confound: the upstream environment rewards wrong cubes, which pays policies that guide fewer episodes]"
    return title


def _seed_text(p: Point, role: str) -> str:
    """``seed 1: design (advance's rule was read from it; not evidence)``."""
    seed = p.run.key.seed
    if role == DESIGN:
        return f"{seed}: design ({p.policy}'s rule was read from it; not evidence)"
    if role == TUNING:
        return f"{seed}: tuning (its knob was chosen on it; not evidence)"
    return f"{seed}: evaluation"


def _row(p: Point, verdict: Verdict, reference: Point | None, miss_threshold: float, cap: float) -> tuple[Row, dict[str, Any]]:
    iqm = stats.iqm_ci([p.returns], stats.generator(f"frontier/{p.label}/iqm"), 2000)
    poi = (math.nan, math.nan, math.nan)
    if reference is not None:
        poi = stats.probability_of_improvement_ci([p.returns], [reference.returns], stats.generator(f"frontier/{p.label}/poi"), 2000)
    q, d, r, s, e = (p.summary[n] for n in ("queries", "dollars", "returns", "steps_to_solve", "episodes_solved"))
    ratio = q[0] / reference.summary["queries"][0] - 1.0 if reference and reference.summary["queries"][0] else math.nan
    flagged = p.flagged(miss_threshold)
    paper = "bound" if p.policy == "oracle" else (PAPER_ROWS.get(p.policy, "") if not p.knobs else "")
    matched = verdict.matched
    same = equivalence_to_random(p, verdict, cap)
    row = Row(
        label=p.label + (" *" if flagged else "") + (f" (fallback: {p.on_miss})" if p.fallback_labelled else ""),
        paper=paper, knobs_chosen=_chosen(p), seed_role=_seed_text(p, verdict.role), trials=str(len(p.returns)),
        queries=_cell(q, 1), query_rate=number(p.rate, 3),
        usd=_cell(d, 4) + (" (est.)" if p.estimated_dollars else ""), steps=_cell(s, 0), episodes_solved=_cell(e, 1),
        solved_trials=f"{int(p.solved.sum())}/{len(p.solved)}", vs_always=verdict.always_text, tail=verdict.tail_text,
        tail_margins=verdict.tail_margins_text,
        matched_random=f"{matched.label}: {_cell(matched.summary['steps_to_solve'], 0)}" if matched is not None else "n/a",
        vs_random=verdict.random_text, credited=verdict.credit_text, vs_always_episodes_solved=verdict.solved_text,
        returns=_cell(r, 1), return_iqm=f"{number(iqm[0], 1)} {outward(iqm[1], iqm[2], 1)}",
        p_improvement=f"{number(poi[0], 2)} {outward(poi[1], poi[2], 2)}", store_misses=_misses_cell(p),
        outside_store=f"{int(p.outside.sum())}/{len(p.outside)}",
        queries_vs_always="n/a" if math.isnan(ratio) else f"{100 * ratio:+.0f}%", equivalence=equivalence_text(same),
    )
    data = {
        "policy": p.policy, "knobs": p.knobs, "paper": paper, "knobs_chosen": row.knobs_chosen,
        "seed": int(p.run.key.seed), "seed_role": verdict.role,
        "design_seeds": " ".join(map(str, design_seeds(p.policy))), "tuning_seeds": " ".join(map(str, tuning_seeds(p))),
        "solution_scope": scope_of(p.run.config), "on_miss": p.on_miss, "trials": len(p.returns), "query_rate": p.rate,
        "episodes_solved_mean": e[0], "episodes_solved_low": e[1], "episodes_solved_high": e[2],
        "stop_at": stop_of(p.run.config), "noninferiority_margin": math.log1p(MARGIN),
        **_verdict_data(verdict, cap), "vs_always_episodes_solved": verdict.solved_text,
        "vs_matched_random_equivalence": same.verdict if same is not None else "",
        "vs_matched_random_faster": same.faster if same is not None else False,
        "vs_matched_random_log_ratio_lower": same.lower if same is not None else math.nan,
        "vs_matched_random_log_ratio_upper": same.upper if same is not None else math.nan,
        "outside_store_trials": int(p.outside.sum()),
        "queries_mean": q[0], "queries_low": q[1], "queries_high": q[2],
        "usd_mean": d[0], "usd_low": d[1], "usd_high": d[2], "usd_estimated": p.estimated_dollars,
        "return_mean": r[0], "return_low": r[1], "return_high": r[2],
        "return_iqm": iqm[0], "return_iqm_low": iqm[1], "return_iqm_high": iqm[2],
        "p_improvement_vs_always": poi[0], "p_improvement_low": poi[1], "p_improvement_high": poi[2],
        "steps_to_solve_mean": s[0], "steps_to_solve_low": s[1], "steps_to_solve_high": s[2],
        "solved_trials": int(p.solved.sum()), "fallback_answers": int(p.fallback.sum()),
        "miss_share": p.miss_share, "miss_flagged": flagged, "queries_vs_always": ratio, "run": p.run.key.name,
    }
    return row, data


def _verdict_data(verdict: Verdict, cap: float) -> dict[str, Any]:
    """The CSV's columns of a point's verdicts against always and matched random."""
    vs, vt, vr, matched = verdict.against_always, verdict.tail, verdict.against_random, verdict.matched
    margins = dict(vt.at_margins) if vt is not None else {}
    out: dict[str, Any] = {
        "horizon_steps": vs.cap if vs is not None else cap,
        "vs_always": vs.verdict if vs is not None else verdict.note,
        "vs_always_reason": vs.reason if vs is not None else "",
        "vs_always_pairs": vs.n if vs is not None else 0,
        "vs_always_ties": vs.ties if vs is not None else 0,
        "vs_always_censored": vs.censored if vs is not None else 0,
        "vs_always_log_ratio": vs.log_ratio if vs is not None else math.nan,
        "vs_always_lower": vs.lower if vs is not None else math.nan,
        "vs_always_bound": vs.upper if vs is not None else math.nan,
        "vs_always_test": _test_name(vs),
        "tail_late_share_above": LATE, "tail_margin": TAIL_MARGIN,
        "vs_always_tail": vt.verdict if vt is not None else verdict.note,
        "tail_late_pairs": vt.late_pairs if vt is not None else 0,
        "tail_censored_pairs": vt.censored if vt is not None else 0,
        "tail_pairs": vt.n if vt is not None else 0,
        "tail_bound": vt.upper if vt is not None else math.nan,
        "tail_bound_censored_late": vt.upper_if_late if vt is not None else math.nan,
    }
    for m in paired.TAIL_MARGINS:
        out[f"tail_verdict_at_{100 * m:.0f}pct"] = margins.get(m, "")
    out |= {
        "matched_random": matched.label if matched is not None else "",
        "matched_random_steps_mean": matched.summary["steps_to_solve"][0] if matched is not None else math.nan,
        "vs_matched_random": vr.verdict if vr is not None else "",
        "vs_matched_random_log_ratio": vr.log_ratio if vr is not None else math.nan,
        "vs_matched_random_bound": vr.upper if vr is not None else math.nan,
        "vs_matched_random_test": _test_name(vr),
        "beats_matched_random": verdict.beats_random,
        "credited": verdict.credited,
    }
    return out


def _test_name(v: paired.SlowdownVerdict | None) -> str:
    """The CSV's name of a comparison's test: the paired betting bound of the log ratio, or no
    test where the logs do not pair the trials."""
    if v is None:
        return ""
    return "paired betting bound (log ratio)" if v.n else "no pairs"


def _chosen(p: Point) -> str:
    """How the point's knobs were set: as given (the same on every task), or by ``--tune``."""
    if p.tuning.get("role") == "tuned":
        return f"tuned on seed {p.tuning.get('tuning_seed')} ({p.tuning.get('rule', '')})"
    if p.tuning.get("role") == "tuning":
        return "tuning candidate"
    return "given"


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
    trial; the tables' 95% t intervals on both axes (log scale for the non-negative quantities); a policy's variants joined as a curve, one colour
    per policy and one marker per variant, named in a legend below the panels (labels beside
    the points overlapped where policies cluster); hollow markers: more than ``miss_threshold``
    of the answers came from a fallback. ``figure``: draw into this (sub)figure instead of a new
    one; returns the figure drawn into."""
    figure = figure if figure is not None else Figure(figsize=(11.5, 9.2), layout="constrained")
    axes = figure.subplots(2, 2)
    curves = _curves(points)
    colors = {name: COLORS[i % len(COLORS)] for i, name in enumerate(dict.fromkeys(p.policy for p in points))}
    markers = _markers(points)
    verdicts = judge(points)
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
                hollow = p.flagged(miss_threshold)
                marker = markers[id(p)]
                size = 10 if marker == "*" else 6
                # the paper's rows (stars) above the other policies' points: a policy that lands
                # where always does (thompson at a high query rate) hid always's star
                ax.errorbar(
                    [x], [y], xerr=xerr, yerr=yerr, fmt=marker, color=color, markersize=size,
                    markerfacecolor="white" if hollow else color, capsize=2, linewidth=0.8,
                    zorder=3.5 if marker == "*" else 2.5,
                )
                credited = verdicts[id(p)].credited
                if credited:  # ringed: credited by the protocol
                    ax.scatter([x], [y], s=260, facecolors="none", edgecolors="black", linewidths=1.4, zorder=5)
                label = (
                    p.label + (f" = {PAPER_ROWS[p.policy]} *" if marker == "*" else "") + (" †" if hollow else "")
                    + (" (credited, ringed)" if credited else "")
                )
                # the legend shows the marker alone: error-bar caps drawn over it hid its shape
                handles.setdefault(label, Line2D(
                    [], [], marker=marker, linestyle="none", color=color, markersize=size,
                    markerfacecolor="white" if hollow else color,
                    markeredgecolor="black" if credited else color,
                ))
            _zoom(ax, points, y_name)
            _spread(ax, [p.summary[x_name][0] for p in points])
            ax.set_xlabel(x_label + (" (estimated)" if x_name == "dollars" and any(p.estimated_dollars for p in points) else ""))
            ax.set_ylabel(y_label)
    # the legend's header explains exactly the marks its labels carry
    marks = ["policy (variant)"]
    if any(" *" in label for label in handles):
        marks.append("* star: the paper's rows")
    if any(" †" in label for label in handles):
        marks.append(f"† hollow: > {100 * miss_threshold:.0f}% of answers from the fallback")
    if any(label.endswith("(credited, ringed)") for label in handles):
        marks.append(
            "ringed: credited (non-inferior to always on steps to the first solve, on the mean log ratio and on the share of pairs"
            f" > {100 * LATE:.0f}% later, and beats random at its query rate, on an evaluation seed)"
        )
    figure.legend(
        list(handles.values()), list(handles), loc="outside lower center", ncols=min(3, max(1, len(handles))),
        fontsize=8, title="; ".join(marks), title_fontsize=8,
    )
    figure.suptitle(
        textwrap.fill(title, 120)
        + "\nbars: the table's 95% t interval of the mean over trials (log scale for queries, dollars and steps)"
    )
    return figure


def _spread(ax: Any, xs: Sequence[float]) -> None:
    """A symmetric-log x axis when the points span more than a factor of 5 (1 query and 30, or
    $0.01 and $0.3, on one axis): the cheap policies, which cluster near zero, spread out, and a
    point at 0 (never) stays on the axis (linear below the smallest positive value)."""
    positive = [x for x in xs if not math.isnan(x) and x > 0]
    if len(positive) >= 2 and max(positive) >= 5 * min(positive):
        threshold = min(positive)
        ax.set_xscale("symlog", linthresh=threshold, linscale=0.5)
        ax.set_xlim(left=-0.25 * threshold)  # nothing is negative: no room for the mirror side
        ticks = symlog_ticks(threshold, max(positive))
        ax.xaxis.set_major_locator(FixedLocator(ticks))
        ax.xaxis.set_major_formatter(FuncFormatter(_plain_number))  # a module function: figures are pickled to the drawing worker
        ax.xaxis.set_minor_locator(NullLocator())


def _plain_number(value: float, _position: int | None = None) -> str:
    return f"{value:g}"


def symlog_ticks(threshold: float, largest: float) -> list[float]:
    """Ticks of a symmetric-log axis from 0 to ``largest``: 0, then 1, 2 and 5 times each power
    of ten from ``threshold`` on (the default put ticks only at 0, 10 and 100, and a
    decade tick inside the linear part, 10^-1 next to 0, overlapped the 0). Where that gives more
    than 10 ticks, the powers of ten alone."""
    low = math.floor(math.log10(threshold))
    high = math.ceil(math.log10(largest * 1.2))
    steps = [m * 10.0**k for k in range(low, high + 1) for m in (1, 2, 5)]
    inside = [v for v in steps if threshold <= v <= largest * 1.2]
    if len(inside) > 10:
        inside = [v for v in inside if math.log10(v).is_integer()] or inside[:: max(1, len(inside) // 6)]
    return [0.0, *inside]


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
    panels: tuple[Panel, ...] = ()
    """Each table with its rows by name (what the CLI prints)."""


def report(
    roots: Sequence[str | Path], out: Path, price: Price | None = None, miss_threshold: float = MISS_THRESHOLD
) -> FrontierReport:
    """Read every trial log under ``roots`` and write, per (task, preset, provider, seed, regime,
    ``run.stop_at``): the frontier PNG, the performance-profile PNG, and the table as Markdown and CSV."""
    import matplotlib

    logs = load(roots)
    runs = [r for r in logs.runs if r.key.kind == "trial"]
    if not runs:  # one line, as replay: every log left out is named in it
        detail = f" ({'; '.join(logs.warnings)})" if logs.warnings else ""
        raise LogError(f"no complete lagrseq trial logs under {', '.join(map(str, roots))}{detail}")
    panels: dict[tuple[str, str, str, int, str, str], list[Run]] = {}
    for run in runs:
        panels.setdefault(_panel_key(run), []).append(run)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    tables: list[Table] = []
    made: list[Panel] = []
    with matplotlib.rc_context(STYLE):  # type: ignore[arg-type]
        for key, group in sorted(panels.items()):
            points = points_of(group, price)
            task, preset, provider, seed, scope, stop = key
            # a panel of trials stopped early is named by it; the full-horizon panel keeps its name
            stem = "-".join([task, preset, _slug(provider), f"seed{seed}", scope, *([stop.replace("_", "-")] if stop else [])])
            found = panel(points, miss_threshold)
            shown = found.table
            made.append(found)
            tables.append(shown)
            for suffix, text in ((".md", to_markdown(shown)), (".csv", to_csv(shown.data))):
                path = out / f"{stem}{suffix}"
                outputs.write_text(path, text, "--out")
                written.append(path)
            for suffix, figure in (
                (".png", draw(points, shown.title, miss_threshold)),
                ("-profiles.png", draw_profiles(points, f"{task}: performance profiles of the return")),
            ):
                path = out / f"{stem}{suffix}"
                outputs.save_figure(figure, path, "--out", format="png", dpi=DPI, metadata={"Software": None})
                written.append(path)
    return FrontierReport(written, tables, logs.warnings, tuple(made))


def _slug(text: str) -> str:
    """A file-name part for ``text``: at most 60 characters; a longer one keeps its start and a
    hash of the whole (cutting it from the left named ``recorded:...`` providers ``ecorded-...``)."""
    import hashlib

    slug = "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in text).strip("-")
    if len(slug) <= 60:
        return slug
    return f"{slug[:51].rstrip('-')}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"
