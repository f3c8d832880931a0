"""The report's plain-language answer: did the paper reproduce, and what did the studies beyond it find.

Everything here is built from tables the report already computes: the scoreboard's rows
(:func:`lagrseq.analysis.scoreboard.build`, one per number the paper states or lagrseq adds) and
the data of the frontier and open-model tables. Nothing is measured here and nothing is typed in
by hand: :func:`headline` gives the five lines that open ``index.html`` and ``index.md``, and
:func:`page` the ``findings.md`` page, one sentence per claim of the paper and per study beyond it,
each with its n, its interval, its verdict and where its answers came from.

Verdict labels are read from the rows (their ``verdict`` field) and counted as they come, so a
new label shows up in the tally without a change here; :data:`VERDICTS` only orders the known
ones and says in a few words what each means.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from lagrseq.analysis.tables import Table

PAGE = "findings.md"
"""The findings page's file name in a report folder."""

VERDICTS: dict[str, str] = {
    "reproduced": "lagrseq's value is within the stated margin of the paper's",
    "differs": "lagrseq's value is outside the stated margin",
    "consistent but not testable": "consistent with the paper, but the data cannot decide at the stated margin",
    "inconclusive": "the data cannot decide at the stated margin",
    "fitted": "made by a mock calibrated on the authors' answers, so agreement checks the fit, not the paper",
    "no verdict": "no test applies (no margin, too few trials, or a fallback decided a trial)",
    "failed": "a run it needs failed",
}
"""Known verdict labels in the order the tally shows them, each with its meaning in a few words.
A label not listed here is counted too, after these, in alphabetical order."""


def label(verdict: object) -> str:
    """A verdict's label: its words before any reason (``"✗ differs (margin ...)"`` -> ``differs``)."""
    text = str(verdict or "").strip().lstrip("✗").strip()
    text = re.split(r"\s\(|:|;", text, maxsplit=1)[0].strip().lower()
    return text or "no verdict"


def _finite(value: object) -> bool:
    try:
        return value is not None and math.isfinite(float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


def paper_claims(board: Table) -> list[Mapping[str, Any]]:
    """The scoreboard rows that test a number the paper states (and the rows of items that failed)."""
    rows = board.data.to_dict("records") if len(board.data) else []
    return [r for r in rows if _finite(r.get("paper_value")) or label(r.get("verdict")) == "failed"]


def own_measures(board: Table) -> list[Mapping[str, Any]]:
    """The scoreboard rows of lagrseq's own measures (the paper gives no value of them)."""
    rows = board.data.to_dict("records") if len(board.data) else []
    return [r for r in rows if not _finite(r.get("paper_value")) and label(r.get("verdict")) != "failed"]


def tally(rows: Iterable[Mapping[str, Any]]) -> Counter[str]:
    """How many rows carry each verdict label."""
    return Counter(label(r.get("verdict")) for r in rows)


def _ordered(counts: Mapping[str, int]) -> list[str]:
    known = [name for name in VERDICTS if counts.get(name)]
    return known + sorted(name for name in counts if name not in VERDICTS and counts[name])


def tally_text(counts: Mapping[str, int]) -> str:
    """``"2 reproduced, 5 differs, 15 fitted"``: the counts in :data:`VERDICTS`' order."""
    return ", ".join(f"{counts[name]} {name}" for name in _ordered(counts)) or "nothing tested"


def headline(board: Table | None, studies: int = 0) -> list[str]:
    """Five lines that answer "did the paper reproduce?" before any table (Markdown)."""
    claims = paper_claims(board) if board is not None else []
    if not claims:
        return [
            "**Did the paper reproduce?** These logs hold no run that stands for a number the paper states.",
            f"One sentence per study: [findings]({PAGE}).",
        ]
    counts = tally(claims)
    by_item: dict[str, Counter[str]] = {}
    for row in claims:
        by_item.setdefault(str(row.get("title", row.get("item", ""))), Counter())[label(row.get("verdict"))] += 1
    meaning = "; ".join(f"{name}: {VERDICTS[name]}" for name in _ordered(counts) if name in VERDICTS)
    beyond = f"{studies} studies beyond the paper" if studies != 1 else "1 study beyond the paper"
    own = len(own_measures(board)) if board is not None else 0
    stated = f"Of the {len(claims)} numbers the paper states" if len(claims) != 1 else "Of the 1 number the paper states"
    return [
        f"**Did the paper reproduce?** {stated} that these logs test: {tally_text(counts)}.",
        "By paper item: " + "; ".join(f"{title}: {tally_text(c)}" for title, c in by_item.items()) + ".",
        f"What the verdicts mean: {meaning}." if meaning else "Verdicts as the scoreboard gives them.",
        f"Beyond the paper: {beyond} and {own} measure{'s' if own != 1 else ''} of lagrseq's own, "
        "each in one sentence on the findings page.",
        f"Every claim in one sentence: [findings]({PAGE}); every test in full: the scoreboard "
        "([Markdown](scoreboard.md), [CSV](tables/scoreboard.csv)).",
    ]


# ------------------------------------------------------------------------------------------
# one sentence per row
# ------------------------------------------------------------------------------------------
def _number(value: object, digits: int = 1) -> str:
    return f"{float(value):.{digits}f}" if _finite(value) else "n/a"  # type: ignore[arg-type]


def _interval(row: Mapping[str, Any], mean: str, low: str, high: str, digits: int = 1) -> str:
    if not _finite(row.get(low)):
        return f"{_number(row.get(mean), digits)} (no interval)"
    return f"{_number(row.get(mean), digits)} [{_number(row.get(low), digits)}, {_number(row.get(high), digits)}]"


def _digits(row: Mapping[str, Any]) -> int:
    value = row.get("mean")
    return 3 if _finite(value) and abs(float(str(value))) < 10 else 1


def claim_sentence(row: Mapping[str, Any]) -> str:
    """One scoreboard row as a sentence: the paper's value, lagrseq's with n and interval, the
    verdict and its reason, and the source of the answers."""
    title, what = row.get("title", ""), row.get("what", "")
    verdict = label(row.get("verdict"))
    reason = str(row.get("verdict_reason") or "").strip()
    if verdict == "failed":
        return f"{title}, {what}: not measured ({reason}). Verdict: **failed**."
    d = _digits(row)
    paper = row.get("paper", "")
    paper_text = f"the paper reports {paper}" if _finite(row.get("paper_value")) else "the paper gives no value"
    return (
        f"{title}, {what}: {paper_text}; lagrseq measures "
        f"{_interval(row, 'mean', 'ci_low', 'ci_high', d)} (95% interval, n = {row.get('trials', 0)} trials) "
        f"on answers from {row.get('source') or 'no LLM'} ({row.get('provenance', '')}). "
        f"Verdict: **{verdict}**" + (f" ({reason})." if reason else ".")
    )


_TITLE = re.compile(r"^(?P<name>[^(]*)\((?P<preset>[^,]+), (?P<source>.+?), seed (?P<seed>\d+)(?P<role> \(tuning seeds\))?;(?P<rest>[^)]*)")


def seed_role(table: Table) -> str:
    """The role of a frontier's seed: the one it evaluates on with knobs as given, held out
    from the seed its knobs were tuned on, or a tuning seed (whose runs choose, not judge)."""
    match = _TITLE.match(table.title)
    seed = match.group("seed") if match else "?"
    if match and match.group("role"):
        return f"seed {seed} is a tuning seed: these runs choose the knobs and are not evidence for them"
    chosen = [str(c) for c in table.data.get("knobs_chosen", []) if str(c).startswith("tuned on seed")]
    if chosen:
        return f"seed {seed} is held out: the knobs were {chosen[0]}, so this seed judges them"
    return f"seed {seed} is the evaluation seed; every knob was given in advance, none tuned on it"


def _text(value: object) -> str:
    """A data cell as text, empty for a missing one (NaN, None)."""
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


def _credited(row: Mapping[str, Any]) -> bool:
    return str(row.get("credited")).lower() in ("true", "yes")


def _plain_seq(row: Mapping[str, Any]) -> bool:
    """The paper's SEQ as the paper states it (no knob changed)."""
    return str(row.get("policy")) == "seq" and not _text(row.get("knobs"))


def frontier_sentences(stem: str, table: Table) -> list[str]:
    """The paper's SEQ against always asking, and each credited policy, on one frontier table."""
    match = _TITLE.match(table.title)
    task = stem.removeprefix("frontier-")
    source = match.group("source") if match else "see the table"
    preset = match.group("preset") if match else ""
    rows = table.data.to_dict("records") if len(table.data) else []
    by_policy = {str(r.get("policy")): r for r in rows}
    always = by_policy.get("always")
    regime = f"; {match.group('rest').strip()}" if match and match.group("rest").strip() else ""
    head = f"Frontier [{task}](tables/{stem}.md) ({preset} preset, answers from {source}{regime}; {seed_role(table)})"
    out = []
    chosen = [r for r in rows if _plain_seq(r) or _credited(r)]
    for row in chosen:
        against = (
            f" against always's {_interval(always, 'queries_mean', 'queries_low', 'queries_high')}"
            f" and step {_interval(always, 'steps_to_solve_mean', 'steps_to_solve_low', 'steps_to_solve_high', 0)}"
            if always is not None else ""
        )
        credited = "credited" if _credited(row) else "not credited"
        knobs = f" ({row.get('knobs')})" if _text(row.get("knobs")) else ""
        out.append(
            f"{head}: `{row.get('policy')}`{knobs} asks {_interval(row, 'queries_mean', 'queries_low', 'queries_high')} "
            f"queries a trial and first solves at step "
            f"{_interval(row, 'steps_to_solve_mean', 'steps_to_solve_low', 'steps_to_solve_high', 0)}"
            f"{against} (95% intervals, n = {row.get('trials')} trials); against always: "
            f"**{label(row.get('vs_always'))}** ({row.get('vs_always_reason') or row.get('vs_always')}); {credited}."
        )
    if not out:
        out.append(f"{head}: neither the paper's SEQ nor any credited policy is in this table.")
    return out


def open_model_sentences(table: Table) -> list[str]:
    """One sentence per model, task and prompt set of the open-model screen."""
    out = []
    rows = table.data.to_dict("records") if len(table.data) else []
    for row in (r for r in rows if str(r.get("shown", "all")) == "all"):  # not the per-prefix cells
        shown = f" ({row.get('prompt_set')})" if _text(row.get("prompt_set")) not in ("-", "") else ""
        interval = (
            f"{_number(100 * float(row['low']), 0)}-{_number(100 * float(row['high']), 0)}% ({row.get('interval')})"
            if _finite(row.get("low")) else f"no interval ({row.get('interval')})"
        )
        out.append(
            f"Open model {row.get('model')} on {row.get('task')}{shown} at τ = {row.get('temperature')}: right on "
            f"{row.get('correct')} of {row.get('answers')} recorded answers over {row.get('prompts')} prompts, "
            f"{interval}. Verdict: **no verdict** (a screen, not a test against the paper). "
            "Answers: recorded from the model (recorded_llm/)."
        )
    return out


def temperature_sentences(table: Table) -> list[str]:
    """One sentence per model and temperature of the test of Table 2's temperature model."""
    out = []
    for row in table.data.to_dict("records") if len(table.data) else []:
        out.append(
            f"The temperature model behind Table 2's fitted rows, tested on {row.get('answers')} real answers of "
            f"{row.get('model')} at τ = {row.get('tau')} over {row.get('prefixes')} prefixes (nothing refitted): "
            f"parametric bootstrap p {row.get('p_bootstrap')}. Verdict: **{label(row.get('result'))}** "
            f"({row.get('result')})."
        )
    return out


def studies(tables: Sequence[tuple[str, Table]]) -> list[tuple[str, list[str]]]:
    """The studies beyond the paper that ``tables`` (stem, table) hold, each with its sentences."""
    found: list[tuple[str, list[str]]] = []
    stems = {stem for stem, _ in tables}
    for stem, table in tables:
        # a frontier's block tables repeat the rows of its whole table (frontier-TASK) when it is there
        covered = any(stem != other and stem.startswith(other + "-") for other in stems if other.startswith("frontier-"))
        if stem.startswith("frontier-") and "policy" in table.data.columns and not covered:
            found.append((f"Query-efficiency frontier: {stem.removeprefix('frontier-')}", frontier_sentences(stem, table)))
        elif stem == "open-models" and "correct" in table.data.columns:
            found.append(("Open models: how often each is right", open_model_sentences(table)))
        elif stem == "open-models-temperature-test" and "result" in table.data.columns:
            found.append(("Open models: the temperature model tested", temperature_sentences(table)))
    return found


def page(board: Table | None, tables: Sequence[tuple[str, Table]], produced_by: str) -> str:
    """``findings.md``: the headline, then one sentence per claim of the paper, per measure of
    lagrseq's own and per study beyond the paper."""
    found = studies(tables)
    lines = ["# Findings: one sentence per claim", "", *(f"{line}  " for line in headline(board, len(found))), ""]
    lines += [f"Made by `{produced_by}` from its logs; each number is in the report's tables too.", ""]
    lines += ["## The paper's claims", ""]
    claims = paper_claims(board) if board is not None else []
    lines += [f"- {claim_sentence(r)}" for r in claims] or ["No run of these logs stands for a number the paper states."]
    own = own_measures(board) if board is not None else []
    if own:
        lines += ["", "## Measures of lagrseq's own", "", *(f"- {claim_sentence(r)}" for r in own)]
    lines += ["", "## Beyond the paper", ""]
    if not found:
        lines.append("These logs hold no study beyond the paper.")
    for name, sentences in found:
        lines += [f"### {name}", "", *(f"- {s}" for s in sentences), ""]
    return "\n".join(lines).rstrip("\n") + "\n"


_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
_BOLD = re.compile(r"\*\*([^*]+)\*\*")


def to_html(line: str) -> str:
    """One headline line as HTML: its text escaped, its ``**bold**`` and ``[links](to)`` kept."""
    import html

    text = html.escape(line, quote=False)
    text = _LINK.sub(lambda m: f'<a href="{html.escape(m.group(2))}">{m.group(1)}</a>', text)
    return _BOLD.sub(r"<strong>\1</strong>", text)


def report_tables(item_tables: Iterable[tuple[Table, str]], extra: Iterable[tuple[str, Table]]) -> list[tuple[str, Table]]:
    """(stem, table) for every table of a report: the items' (given with their Markdown path,
    ``tables/STEM.md``) and the others."""
    own = [(path.rsplit("/", 1)[-1].removesuffix(".md"), table) for table, path in item_tables]
    return own + list(extra)


OVERVIEW = "figures/overview.png"
"""The report's one-panel picture (the README shows the reference report's)."""


def overview_table(tables: Sequence[tuple[str, Table]]) -> tuple[str, Table] | None:
    """The frontier the overview shows: the cube task's where the report has it, else the first."""
    frontiers = [(s, t) for s, t in tables if s.startswith("frontier-") and {"queries_mean", "steps_to_solve_mean"} <= set(t.data.columns)]
    return next((f for f in frontiers if f[0] == "frontier-cube"), frontiers[0] if frontiers else None)


def overview_axes(stem: str, table: Table, ax: Any = None) -> Any:
    """One panel: each asking policy's queries a trial against the step of its first solved
    episode, with 95% intervals both ways (from the frontier table's data; no dollars, which for
    a free mock only restate the queries). Returns the axes."""
    from lagrseq.analysis import figures

    ax = figures.new_axes((6.4, 4.0)) if ax is None else ax
    rows = table.data.to_dict("records") if len(table.data) else []
    for k, row in enumerate(r for r in rows if _finite(r.get("queries_mean")) and _finite(r.get("steps_to_solve_mean"))):
        x, y = float(row["queries_mean"]), float(row["steps_to_solve_mean"])
        xerr = [[x - float(row.get("queries_low", x))], [float(row.get("queries_high", x)) - x]]
        yerr = [[y - float(row.get("steps_to_solve_low", y))], [float(row.get("steps_to_solve_high", y)) - y]]
        paper = _text(row.get("paper"))
        name = str(row.get("policy")) + (f" ({row.get('knobs')})" if _text(row.get("knobs")) else "")
        ax.errorbar(
            x, y, xerr=xerr, yerr=yerr, fmt="*" if paper else "o", markersize=12 if paper else 6,
            color=figures.COLORS[k % len(figures.COLORS)], capsize=2, label=name + (f" = {paper}" if paper and paper != "bound" else " (a bound)" if paper else ""),
        )
    match = _TITLE.match(table.title)
    where = f" ({match.group('preset')} preset, {match.group('source')})" if match else ""
    task = str(rows[0].get("run", "")).split("/")[0] if rows else stem.removeprefix("frontier-")
    ax.set_title(f"Asking less against solving later: {task}{where}")
    ax.set_xlabel("LLM queries per trial (mean, 95% interval)")
    ax.set_ylabel("steps to the first solve (mean, 95% interval)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7, loc="upper right", ncol=2)
    return ax
