"""The report's findings page and the five lines that open its index: built from the scoreboard
and the study tables the report computes, one sentence per claim, verdicts counted as they come."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import pandas as pd

from lagrseq.analysis import findings
from lagrseq.analysis.replay import replay
from lagrseq.analysis.tables import Table


def _board(verdicts: list[str], paper_values: list[float]) -> Table:
    rows = [
        {"item": "table2", "title": "Table 2", "what": f"cell {k}", "paper": f"{v} ± 1", "paper_value": v,
         "source": "mock", "provenance": "rule-based mock", "mean": 10.0 + k, "ci_low": 9.0 + k,
         "ci_high": 11.0 + k, "trials": 10, "verdict": verdict, "verdict_reason": "why"}
        for k, (verdict, v) in enumerate(zip(verdicts, paper_values, strict=True))
    ]
    return Table("Scoreboard", (), (), pd.DataFrame(rows))


def test_the_tally_counts_verdict_labels_as_they_come_including_new_ones() -> None:
    board = _board(["reproduced", "✗ differs (margin ±3)", "a label never seen", "reproduced", "fitted"], [1, 2, 3, 4, 5])
    counts = findings.tally(findings.paper_claims(board))
    assert counts == {"reproduced": 2, "differs": 1, "a label never seen": 1, "fitted": 1}
    # known labels first, in the one mapping's order; an unknown one after them
    assert findings.tally_text(counts) == "2 reproduced, 1 differs, 1 fitted, 1 a label never seen"


def test_rows_without_a_paper_value_are_lagrseqs_own_measures_not_claims() -> None:
    board = _board(["reproduced", "no verdict"], [1.0, math.nan])
    assert [r["what"] for r in findings.paper_claims(board)] == ["cell 0"]
    assert [r["what"] for r in findings.own_measures(board)] == ["cell 1"]
    headline = findings.headline(board)
    assert len(headline) == 5 and "Of the 1 number the paper states" in headline[0] and "1 reproduced" in headline[0]


def test_a_claim_sentence_carries_n_interval_verdict_and_source() -> None:
    row = findings.paper_claims(_board(["✗ differs (margin ±3)"], [126.0]))[0]
    sentence = findings.claim_sentence(row)
    assert "126.0 ± 1" in sentence and "10.0 [9.0, 11.0]" in sentence and "n = 10" in sentence
    assert "mock" in sentence and "**differs**" in sentence


def _frontier(title: str, chosen: str) -> Table:
    rows = [
        {"policy": "always", "knobs": math.nan, "knobs_chosen": "given", "trials": 10, "queries_mean": 400.0, "queries_low": 390.0,
         "queries_high": 410.0, "steps_to_solve_mean": 80.0, "steps_to_solve_low": 50.0, "steps_to_solve_high": 120.0,
         "vs_always": "reference", "credited": False},
        {"policy": "seq", "knobs": math.nan, "knobs_chosen": chosen, "trials": 10, "queries_mean": 160.0, "queries_low": 150.0,
         "queries_high": 170.0, "steps_to_solve_mean": 85.0, "steps_to_solve_low": 55.0, "steps_to_solve_high": 130.0,
         "vs_always": "inconclusive", "vs_always_reason": "the bounds straddle the margin", "credited": False},
    ]
    return Table(title, (), (), pd.DataFrame(rows))


def test_a_frontier_sentence_names_its_seeds_role() -> None:
    given = _frontier("Query-efficiency frontier: cube-stacking (paper, mock, seed 0; answer kept for one episode)", "given")
    held_out = _frontier("Query-efficiency frontier: cube-stacking (paper, mock, seed 3; answer kept for one episode)", "tuned on seed 1 (rule)")
    tuning = _frontier("Query-efficiency frontier: cube-stacking (paper, mock, seed 1 (tuning seeds); answer kept for one episode)", "tuning candidate")
    assert "seed 0 is the evaluation seed" in findings.frontier_sentences("frontier-cube", given)[0]
    assert "seed 3 is held out" in findings.frontier_sentences("frontier-cube", held_out)[0]
    sentence = findings.frontier_sentences("frontier-cube", tuning)[0]
    assert "seed 1 is a tuning seed" in sentence
    assert "160.0 [150.0, 170.0]" in sentence and "400.0 [390.0, 410.0]" in sentence and "n = 10" in sentence
    assert "**inconclusive**" in sentence and "answers from mock" in sentence


def test_replay_writes_the_findings_page_and_opens_its_index_with_the_tally(runs_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    replay([runs_dir], out)
    page = (out / findings.PAGE).read_text(encoding="utf-8")
    with open(out / "tables" / "scoreboard.csv", encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r["paper_value"] not in ("", "nan")]
    assert rows, "the runs stand for a number the paper states"
    # every claim of the scoreboard has its sentence, and the tally adds up to them
    claims = page.split("## The paper's claims", 1)[1].split("\n## ", 1)[0]
    assert [line.split(":", 1)[0] for line in claims.splitlines() if line.startswith("- ")] == [
        f"- {r['title']}, {r['what'].split(':', 1)[0]}" for r in rows
    ]
    counts = findings.tally(rows)
    assert findings.tally_text(counts) in page
    index = (out / "index.md").read_text(encoding="utf-8")
    before_table = index.split("\n|", 1)[0]
    assert "**Did the paper reproduce?**" in before_table and findings.tally_text(counts) in before_table
    # the title, the logs' summary, then the five lines
    opening = [line for line in before_table.splitlines() if line.strip()]
    assert opening[2].startswith("**Did the paper reproduce?**") and opening[7].startswith("### Scoreboard")
    assert f"]({findings.PAGE})" in before_table
    html = (out / "index.html").read_text(encoding="utf-8")
    assert html.index('<section id="answer">') < html.index("<table")
    assert re.search(r'<a href="findings\.md">findings</a>', html)
    assert findings.PAGE in (out / ".lagrseq-report").read_text(encoding="utf-8")


def test_the_overview_is_one_panel_of_queries_against_the_first_solve_without_dollars() -> None:
    cube = _frontier("Query-efficiency frontier: cube-stacking (paper, mock, seed 0; answer kept for one episode)", "given")
    other = _frontier("Query-efficiency frontier: image-completion (upstream, mock, seed 0; answer kept for the trial)", "given")
    assert findings.overview_table([("frontier-image", other), ("frontier-cube", cube)]) == ("frontier-cube", cube)
    assert findings.overview_table([("costs-by-run", other)]) is None
    ax = findings.overview_axes("frontier-cube", cube)
    assert len(ax.figure.axes) == 1 and len(ax.containers) == 2  # one panel, one point per policy
    assert "USD" not in ax.get_xlabel() + ax.get_ylabel() and "queries" in ax.get_xlabel()
    x = [c.lines[0].get_xdata()[0] for c in ax.containers]
    assert x == [400.0, 160.0]
