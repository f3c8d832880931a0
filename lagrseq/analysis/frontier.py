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

The protocol (issues 20 and 35). Primary outcomes: steps to the end of the first solved episode
(lower is better; a trial that solves none counts its full length) and episodes solved per trial;
the return is secondary. The points of a panel run the same (seed, trial) pairs, so trial ``i`` of
every policy saw the same environment draws (common random numbers); where the logs show two
points ran the same seed and the same trials (:func:`paired_order`) each asking point is judged
against ``always`` on steps to the first solve by two estimands of :mod:`lagrseq.analysis.paired`:

* the **mean per-pair log ratio** ``mean(log(policy_i / always_i))`` with a one-sided studentized
  bootstrap bound at the calibrated nominal 97.5% (:data:`lagrseq.analysis.paired.BOUND_ALPHA`:
  it covers at least 93% at 30 pairs on the skewed generators of ``benchmarks/coverage.py
  --paired``) (:func:`lagrseq.analysis.paired.slowdown`; relative margin 10%, :data:`MARGIN`,
  so the bound must lie below ``log(1.1)``; the trials' step cap is the restricted-mean horizon,
  :func:`horizon`, and a trial that never solved counts at its length; at least 10 pairs; no
  verdict from differences without spread), and
* the **tail share**: the share of pairs in which the policy is more than 10% later than always,
  with an exact Clopper-Pearson upper bound, non-inferior when it lies below a tail margin of 20%
  (:func:`lagrseq.analysis.paired.tail`).

Each bootstrap draws from a generator seeded by the two runs and the outcome
(:func:`_generator`), so a replay of the same logs gives the same bounds to the bit. Where the logs
do not pair the points (another seed, a trial missing in either), there is no verdict: both
estimands are per pair, and the table says ``inconclusive (pairs missing: ..., no verdict)``. Each learning policy's
point is also compared with ``random`` asking at the point's own mean query rate (queries /
decisions, from its logs; the random run is found by its ``ask_probability``,
:func:`lagrseq.frontier_protocol.matched_probability`): it *beats* it when the upper bound of the
mean log ratio against that run lies below 0 (margin 0). A point is *credited* only when it is
non-inferior to always on the mean log ratio **and** on the tail share **and** beats random at the
matched rate (an intersection-union test: each at level 0.05, so the credit is at level 0.05);
the oracle (it peeks at the answer before deciding) is shown as the bound and never credited, and
points whose run answered store misses with the rule-based mock (``--on-miss mock``) get no
verdict. Episodes solved per trial get the paired t test of
:func:`lagrseq.analysis.inference.paired_noninferiority` (margin 10% of always's mean), shown
beside the verdicts but not entering the credit. Runs are grouped into panels by task, preset,
provider, seed, ``lagr.solution_scope`` (answer kept for one episode or for the trial) and
``run.stop_at`` (trials stopped at their first solve make their own panel, whose query column
counts the queries to the first solve).

Dollars: a query's logged ``cost_usd`` when it has one; else its logged token usage priced by
``price``; else (answers imported from the authors' caches carry no usage) the median token
usage of the queries of the same task that have one (the mock estimates about 4 characters a
token), marked as estimated. No usage anywhere: NaN.
"""

from __future__ import annotations

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
from lagrseq.analysis.tables import Table, interval, number, to_csv, to_markdown
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
"""The tail verdict's margin: the late share's exact upper bound must lie below 20%."""
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
    its preset's (the learning SEQ on the grids, whose upstream SEQ never decays: issue 35); ""
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
        + float(section.get("stall_steps", 64)) * 1e-13 + sum(own) * 1e-12  # a plugin policy's own knobs, last
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
        """Its store misses were answered by the rule-based mock or a calibrated draw (fitted to
        the store's answers): no verdict."""
        return self.on_miss in ("mock", CALIBRATED_MISS)

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
    """The step cap of ``points``' trials, the horizon of the restricted mean: ``run.max_steps``
    where the configuration sets one, and never less than the longest trial logged (a trial that
    never solved counts at its length; an episode-limited trial's cap is its longest)."""
    cap = 0.0
    for p in points:
        cap = max(cap, float(p.run.config.get("run", {}).get("max_steps", 0) or 0))
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


def summarise(points: Sequence[Point]) -> None:
    """Means with the tables' 95% Student-t intervals (issue 34: the percentile bootstrap
    under-covers at these n, ``benchmarks/coverage.py``), on the log scale for
    :data:`NON_NEGATIVE` quantities (:func:`lagrseq.analysis.stats.summarize_t`), so an interval
    never reaches below 0, and steps to the first solve never above the trials' step budget
    (``run.max_steps``, where one is set); values without spread have the value itself as both bounds."""
    for p in points:
        for name in ("returns", "steps_to_solve", "queries", "dollars", "episodes_solved"):
            values = np.asarray(getattr(p, name), dtype=float)
            if not len(values) or np.isnan(values).any():
                p.summary[name] = (float(np.mean(values)) if len(values) else math.nan, math.nan, math.nan)
                continue
            found = stats.summarize_t(values, positive=name in NON_NEGATIVE)
            low, high = found.ci_low, found.ci_high
            cap = float(p.run.config.get("run", {}).get("max_steps", 0) or 0)
            if name == "steps_to_solve" and cap > 0 and math.isfinite(high):
                high = min(high, cap)  # no trial solves past its step budget: the interval stays in range
            if len(values) >= 2 and np.all(values == values[0]):
                low = high = float(values[0])
            p.summary[name] = (found.mean, low, high)


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
        return (
            f"{v.verdict} ({v.late_pairs} of {v.n} pairs late, bound {100 * v.upper:.1f}% vs {100 * v.margin:.0f}%"
            + (f"; {v.reason}" if v.n < paired.MIN_PAIRS else "") + ")"
        )

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
        elif v.n < paired.MIN_PAIRS or v.reason.startswith(PAIRS_MISSING):
            said = "no verdict"
        else:
            said = "does not beat"
        return f"{said} ({_slowdown_text(v)})"


PAIRS_MISSING = "pairs missing"
"""The reason of a comparison whose logs do not pair the trials (no verdict)."""


def _slowdown_text(v: paired.SlowdownVerdict) -> str:
    """``ratio 1.02, bound 1.07 < 1.10, n = 30 pairs``: the geometric-mean time ratio, its
    one-sided upper bound (at the calibrated nominal 97.5%, :data:`lagrseq.analysis.paired.BOUND_ALPHA`)
    and the margin on the ratio scale; or why there is no bound."""
    if v.reason.startswith(PAIRS_MISSING) or not math.isfinite(v.upper):
        return v.reason + (f", n = {v.n} pairs" if v.n and not v.reason.startswith(PAIRS_MISSING) else "")
    def ratio_of(log: float) -> float:  # a ratio past the largest float is inf (shown so), never an OverflowError
        return math.inf if log > math.log(np.finfo(float).max) else math.exp(log)

    limit, bound, ratio = ratio_of(v.margin), ratio_of(v.upper), ratio_of(v.log_ratio)
    relation = "<" if bound < limit else ">="
    text = f"ratio {ratio:.3g}, bound {bound:.3g} {relation} {limit:.3g}, n = {v.n} pairs"
    return text if v.n >= paired.MIN_PAIRS else f"{text}; n < {paired.MIN_PAIRS}"


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


def _generator(p: Point, q: Point, outcome: str) -> np.random.Generator:
    """The bootstrap generator of ``p`` against ``q`` on ``outcome``: seeded by both runs' keys
    and the outcome alone, so a replay of the same logs draws the same resamples."""
    return stats.generator(f"frontier/{p.run.key.name}/vs/{q.run.key.name}/{outcome}")


def _missing(p: Point, q: Point) -> str:
    if p.run.key.seed != q.run.key.seed:
        return f"{PAIRS_MISSING}: seed {p.run.key.seed} against {q.run.key.seed}, no verdict"
    return f"{PAIRS_MISSING}: trials {len(p.steps_to_solve)} against {len(q.steps_to_solve)} do not match, no verdict"


def slowdown(p: Point, q: Point, margin: float = MARGIN, cap: float | None = None) -> paired.SlowdownVerdict:
    """``p`` against ``q`` on steps to the first solve: the mean per-pair log ratio with its
    studentized bootstrap bounds (:func:`lagrseq.analysis.paired.slowdown`, relative ``margin``,
    ``cap`` as the restricted-mean horizon; None: the two points' :func:`horizon`). No pairs in
    the logs: an inconclusive verdict whose reason starts with :data:`PAIRS_MISSING`."""
    cap = horizon(p, q) if cap is None else cap
    order = paired_order(p, q)
    if order is None:
        return paired.SlowdownVerdict(
            paired.INCONCLUSIVE, math.nan, math.nan, math.nan, math.log1p(margin), 0, cap, _missing(p, q)
        )
    x, y = p.steps_to_solve[order[0]], q.steps_to_solve[order[1]]
    return paired.slowdown(x, y, _generator(p, q, "steps_to_solve"), relative_margin=margin, cap=cap, alpha=paired.BOUND_ALPHA)


def tail(p: Point, q: Point) -> paired.TailVerdict:
    """The share of pairs in which ``p`` reaches its first solve more than :data:`LATE` later
    than ``q``, with exact bounds and a verdict against :data:`TAIL_MARGIN`."""
    order = paired_order(p, q)
    if order is None:
        return paired.TailVerdict(paired.INCONCLUSIVE, 0, 0, math.nan, math.nan, LATE, TAIL_MARGIN, _missing(p, q))
    return paired.tail(p.steps_to_solve[order[0]], q.steps_to_solve[order[1]], LATE, TAIL_MARGIN, ALPHA)


def judge(points: Sequence[Point]) -> dict[int, Verdict]:
    """id(point) -> its verdict (see the module: estimands, margins, credit)."""
    reference = next((p for p in points if p.policy == "always" and not p.knobs), None)
    randoms: dict[float, Point] = {}
    for p in points:
        if p.policy == "random" and not p.fallback_labelled:
            randoms.setdefault(float(p.run.config.get("secondary", {}).get("ask_probability", 0.5)), p)
    cap = horizon(*points)  # the panel's step cap: one restricted-mean horizon for all its comparisons
    out: dict[int, Verdict] = {}
    for p in points:
        if p.fallback_labelled:
            out[id(p)] = Verdict(None, None, None, None, None, False, "no verdict: misses answered by the mock" if p.on_miss == "mock" else "no verdict: misses answered by a calibrated draw (fitted)")
            continue
        if reference is None or p is reference:
            out[id(p)] = Verdict(None, None, None, None, None, False, "reference" if p is reference else "no always run")
            continue
        versus = slowdown(p, reference, cap=cap)
        late = tail(p, reference)
        solved = compare(p, reference, "episodes_solved", MARGIN * float(np.mean(reference.episodes_solved)))
        matched = against = None
        if wants_match(p.policy, p.knobs) and not math.isnan(p.rate) and p.rate > 0:
            rate = matched_probability(float(p.queries.sum()), p.decisions)
            matched = reference if rate >= 1.0 else randoms.get(rate)  # random at rate 1 is always
            if matched is not None:
                against = slowdown(p, matched, margin=0.0, cap=cap)
        credited = (
            p.policy != "oracle" and versus.verdict == paired.NON_INFERIOR and late.verdict == paired.NON_INFERIOR
            and against is not None and against.verdict == paired.NON_INFERIOR
        )
        out[id(p)] = Verdict(versus, late, solved, matched, against, credited, "")
    return out


EQUIVALENCE_COLUMN = "vs matched random: equivalence (geometric-mean ratio of steps to first solve, margin 10% either way)"


def equivalence_to_random(p: Point, verdict: Verdict) -> paired.EquivalenceVerdict | None:
    """The point against random at its matched rate on steps to the first solve, by two one-sided
    tests on the mean per-pair log ratio (:func:`lagrseq.analysis.paired.equivalence`, margin
    log(1.1) either way, studentized bootstrap bounds at level 0.05 each), with superiority
    (``faster``) beside it: "no better than random at its rate" measured either way (issue 35).
    None where there is no matched run or the two do not pair."""
    matched = verdict.matched
    if matched is None:
        return None
    order = paired_order(p, matched)
    if order is None:
        return None
    cap = float(p.run.config.get("run", {}).get("max_steps") or 0) or math.inf
    return paired.equivalence(
        p.steps_to_solve[order[0]], matched.steps_to_solve[order[1]],
        stats.generator(f"frontier/{p.label}/equivalence"), MARGIN, cap,
    )


def equivalence_text(e: paired.EquivalenceVerdict | None) -> str:
    """``equivalent (ratio 1.01, 95% [0.97, 1.05], n = 10 pairs)``; ``; faster`` where it beats: the
    two one-sided bounds of the TOST, each at the calibrated level, as one (1 - 2 alpha) interval."""
    if e is None:
        return "n/a"
    if math.isnan(e.lower):
        return f"{e.verdict} ({e.reason})"
    low, high = (math.exp(v) if math.isfinite(v) else (0.0 if v < 0 else math.inf) for v in (e.lower, e.upper))
    faster = "; faster" if e.faster else ""
    level = 1.0 - 2.0 * e.alpha  # the TOST's two one-sided bounds at alpha each: a (1 - 2 alpha) interval
    return f"{e.verdict}{faster} (ratio {e.ratio:.2f}, {level:.0%} [{low:.2f}, {high:.2f}], n = {e.n} pairs)"


def table(points: Sequence[Point], miss_threshold: float = MISS_THRESHOLD, provider: str | None = None) -> Table:
    """The frontier table: one row per policy variant (paper rows marked, the oracle as the
    bound), with the protocol's verdicts. ``provider``: the one named in the title (default: the
    first point's)."""
    reference = next((p for p in points if p.policy == "always" and not p.knobs), None)
    verdicts = judge(points)
    cap = horizon(*points) if points else math.nan
    stopped = bool(points) and any(stop_of(p.run.config) == "first_solve" for p in points)
    queries_name = "queries to the first solve / trial [95% CI]" if stopped else "queries / trial [95% CI]"
    columns = (
        "policy", "paper", "knobs chosen", "trials", queries_name, "query rate", "USD / trial [95% CI]",
        "steps to first solve [95% CI]", "episodes solved / trial [95% CI]", "solved trials",
        f"vs always on steps to first solve: mean log ratio (margin 10%, horizon {number(cap, 0)} steps)",
        f"vs always: pairs > {100 * LATE:.0f}% later (exact bound, tail margin {100 * TAIL_MARGIN:.0f}%)",
        "random at the matched rate: steps to first solve",
        "vs matched random (mean log ratio < 0)", "credited", "vs always on episodes solved (margin 10%)", "return / trial [95% CI]", "return IQM [95% CI]", "P(return > always) [95% CI]",
        "store misses (refused, or answered by a fallback)", "trials decided outside the store", "queries vs always",
        EQUIVALENCE_COLUMN,
    )
    rows: list[tuple[str, ...]] = []
    data: list[dict[str, Any]] = []
    for p in points:
        verdict = verdicts[id(p)]
        iqm, iqm_low, iqm_high = stats.iqm_ci([p.returns], stats.generator(f"frontier/{p.label}/iqm"), 2000)
        if reference is not None:
            poi, poi_low, poi_high = stats.probability_of_improvement_ci(
                [p.returns], [reference.returns], stats.generator(f"frontier/{p.label}/poi"), 2000
            )
        else:
            poi = poi_low = poi_high = math.nan
        q, d, r, s, e = (p.summary[n] for n in ("queries", "dollars", "returns", "steps_to_solve", "episodes_solved"))
        ratio = q[0] / reference.summary["queries"][0] - 1.0 if reference and reference.summary["queries"][0] else math.nan
        flagged = p.flagged(miss_threshold)
        usd = f"{number(d[0], 4)} {interval(d[1], d[2], 4)}" + (" (est.)" if p.estimated_dollars else "")
        paper = "bound" if p.policy == "oracle" else (PAPER_ROWS.get(p.policy, "") if not p.knobs else "")
        chosen = _chosen(p)
        matched = verdict.matched
        same = equivalence_to_random(p, verdict)
        shown_random = (
            f"{matched.label}: {number(matched.summary['steps_to_solve'][0], 0)} "
            f"{interval(*matched.summary['steps_to_solve'][1:], 0)}" if matched is not None else "n/a"
        )
        rows.append((
            p.label + (" *" if flagged else "") + (f" (fallback: {p.on_miss})" if p.fallback_labelled else ""),
            paper,
            chosen,
            str(len(p.returns)),
            f"{number(q[0], 1)} {interval(q[1], q[2], 1)}",
            number(p.rate, 3),
            usd,
            f"{number(s[0], 0)} {interval(s[1], s[2], 0)}",
            f"{number(e[0], 1)} {interval(e[1], e[2], 1)}",
            f"{int(p.solved.sum())}/{len(p.solved)}",
            verdict.always_text,
            verdict.tail_text,
            shown_random,
            verdict.random_text,
            "yes" if verdict.credited else "no",
            verdict.solved_text,
            f"{number(r[0], 1)} {interval(r[1], r[2], 1)}",
            f"{number(iqm, 1)} {interval(iqm_low, iqm_high, 1)}",
            f"{number(poi, 2)} {interval(poi_low, poi_high, 2)}",
            _misses_cell(p),
            f"{int(p.outside.sum())}/{len(p.outside)}",
            "n/a" if math.isnan(ratio) else f"{100 * ratio:+.0f}%",
            equivalence_text(same),
        ))
        vs = verdict.against_always
        vt = verdict.tail
        vr = verdict.against_random
        data.append({
            "policy": p.policy, "knobs": p.knobs, "paper": paper, "knobs_chosen": chosen,
            "solution_scope": scope_of(p.run.config), "on_miss": p.on_miss,
            "trials": len(p.returns),
            "query_rate": p.rate,
            "episodes_solved_mean": e[0], "episodes_solved_low": e[1], "episodes_solved_high": e[2],
            "stop_at": stop_of(p.run.config),
            "noninferiority_margin": math.log1p(MARGIN),
            "horizon_steps": vs.cap if vs is not None else cap,
            "vs_always": vs.verdict if vs is not None else verdict.note,
            "vs_always_reason": vs.reason if vs is not None else "",
            "vs_always_pairs": vs.n if vs is not None else 0,
            "vs_always_log_ratio": vs.log_ratio if vs is not None else math.nan,
            "vs_always_lower": vs.lower if vs is not None else math.nan,
            "vs_always_bound": vs.upper if vs is not None else math.nan,
            "vs_always_test": _test_name(vs),
            "tail_late_share_above": LATE,
            "tail_margin": TAIL_MARGIN,
            "vs_always_tail": vt.verdict if vt is not None else verdict.note,
            "tail_late_pairs": vt.late_pairs if vt is not None else 0,
            "tail_pairs": vt.n if vt is not None else 0,
            "tail_bound": vt.upper if vt is not None else math.nan,
            "matched_random": matched.label if matched is not None else "",
            "matched_random_steps_mean": matched.summary["steps_to_solve"][0] if matched is not None else math.nan,
            "vs_matched_random": vr.verdict if vr is not None else "",
            "vs_matched_random_log_ratio": vr.log_ratio if vr is not None else math.nan,
            "vs_matched_random_bound": vr.upper if vr is not None else math.nan,
            "vs_matched_random_test": _test_name(vr),
            "beats_matched_random": verdict.beats_random,
            "vs_matched_random_equivalence": same.verdict if same is not None else "",
            "vs_matched_random_faster": same.faster if same is not None else False,
            "vs_matched_random_log_ratio_lower": same.lower if same is not None else math.nan,
            "vs_matched_random_log_ratio_upper": same.upper if same is not None else math.nan,
            "credited": verdict.credited,
            "vs_always_episodes_solved": verdict.solved_text,
            "outside_store_trials": int(p.outside.sum()),
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
    title = "Frontier"
    if first:
        # the regime of the panel's asking policies: ``never`` (the baseline) joins every panel
        # and asks nothing, so its own configuration names no regime (issue 34: both blocks of a
        # grid frontier were titled "answer kept for the trial")
        asking = next((p for p in points if p.run.key.method != "baseline"), points[0])
        scope = SCOPE_TEXT.get(scope_of(asking.run.config), scope_of(asking.run.config))
        role = " (tuning seeds)" if any(p.tuning.get("role") == "tuning" for p in points) else ""
        stop = STOP_TEXT.get(stop_of(asking.run.config), "")
        title = f"Query-efficiency frontier: {first.task} ({first.preset}, {shown}, seed {first.seed}{role}; {scope}{'; ' + stop if stop else ''})"
        if points[0].run.config.get("env", {}).get("wrong_cube_reward") == "pre-revert":
            title += " [confound: the upstream environment rewards wrong cubes, which pays policies that guide fewer episodes]"
    return Table(title, columns, tuple(rows), pd.DataFrame(data))


def _test_name(v: paired.SlowdownVerdict | None) -> str:
    """The CSV's name of a comparison's test: the paired studentized bootstrap of the log ratio,
    or no test where the logs do not pair the trials."""
    if v is None:
        return ""
    return "no pairs" if v.reason.startswith(PAIRS_MISSING) else "paired bootstrap-t (log ratio)"


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
            f" > {100 * LATE:.0f}% later, and beats random at its query rate)"
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
    of ten from ``threshold`` on (issue 34: the default put ticks only at 0, 10 and 100, and a
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
    with matplotlib.rc_context(STYLE):  # type: ignore[arg-type]
        for key, group in sorted(panels.items()):
            points = points_of(group, price)
            task, preset, provider, seed, scope, stop = key
            # a panel of trials stopped early is named by it; the full-horizon panel keeps its name
            stem = "-".join([task, preset, _slug(provider), f"seed{seed}", scope, *([stop.replace("_", "-")] if stop else [])])
            shown = table(points, miss_threshold)
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
    return FrontierReport(written, tables, logs.warnings)


def _slug(text: str) -> str:
    """A file-name part for ``text``: at most 60 characters; a longer one keeps its start and a
    hash of the whole (cutting it from the left named ``recorded:...`` providers ``ecorded-...``)."""
    import hashlib

    slug = "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in text).strip("-")
    if len(slug) <= 60:
        return slug
    return f"{slug[:51].rstrip('-')}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"
