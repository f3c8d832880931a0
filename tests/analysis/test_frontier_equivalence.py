"""The frontier's equivalence column against random at the matched rate, and the learning SEQ's
label."""

from __future__ import annotations

import json

import numpy as np

from lagrseq import config as cfg
from lagrseq.analysis.frontier import EQUIVALENCE_COLUMN, judge, policy_of, summarise, table
from tests.support.frontier import point as _point


def test_the_table_says_whether_a_point_is_equivalent_to_random_at_its_rate() -> None:
    rng = np.random.default_rng(0)
    n = 600
    base = rng.uniform(40, 400, n)
    always = _point("always", list(base))
    # thompson at rate 0.2 and random at 0.2 finish within 1-2% of each other in every pair: equivalent
    thompson = _point("thompson", list(base * np.exp(rng.normal(0.0, 0.01, n))), queries=20, decisions=100)
    random_02 = _point("random", list(base * np.exp(rng.normal(0.0, 0.01, n))), p=0.2)
    # seq at rate 0.5 takes half random's time in every pair: faster, so not equivalent
    seq = _point("seq", list(base * 0.5 * np.exp(rng.normal(0.0, 0.01, n))), queries=50, decisions=100)
    random_05 = _point("random", list(base), p=0.5)
    points = [always, thompson, seq, random_02, random_05]
    verdicts = judge(points)
    assert verdicts[id(thompson)].matched is random_02 and verdicts[id(seq)].matched is random_05
    summarise(points)
    shown = table(points)
    cells = [row[shown.columns.index(EQUIVALENCE_COLUMN)] for row in shown.rows]
    assert cells[0] == "n/a" and cells[3] == cells[4] == "n/a"  # always and random are not matched
    assert cells[1].startswith("equivalent (ratio 1.0") and f"n = {n} pairs" in cells[1]
    assert cells[2].startswith("not equivalent; faster (ratio 0.50")
    data = shown.data
    assert list(data["vs_matched_random_equivalence"]) == ["", "equivalent", "not equivalent", "", ""]
    assert list(data["vs_matched_random_faster"]) == [False, False, True, False, False]
    assert abs(data["vs_matched_random_log_ratio"].iloc[2] - np.log(0.5)) < 0.02
    # 30 pairs each identical to its random twin: finite bounds, too wide to claim equality
    few = [_point(p.policy, list(p.steps_to_solve[:30]), queries=20, decisions=100, p=0.2 if p.policy == "random" else None)
           for p in (always, random_02)]
    twin = _point("thompson", list(few[1].steps_to_solve), queries=20, decisions=100)
    summarise([few[0], twin, few[1]])
    cell = table([few[0], twin, few[1]]).rows[1][-1]
    assert cell.startswith("inconclusive (ratio 1.00, 90% [")


def _json(task: str, preset: str, sets: list[str]) -> dict:
    return json.loads(cfg.load(task, "lagr-seq", preset, None, sets).to_json())


def test_a_seq_whose_schedule_is_not_its_presets_is_labelled_as_learning() -> None:
    decay = ['secondary.epsilon_schedule="exponential"', "secondary.epsilon_decay=0.998", 'secondary.epsilon_unit="step"',
             "secondary.epsilon_min=0.1"]
    assert policy_of(_json("object-arrangement", "upstream", decay)) == ("seq", "epsilon exponential 0.998/step, min 0.1")
    # the upstream SEQ (epsilon fixed at 1) and the paper presets' own schedules keep the paper's name
    assert policy_of(_json("object-arrangement", "upstream", [])) == ("seq", "")
    assert policy_of(_json("object-arrangement", "paper", decay)) == ("seq", "")
    assert policy_of(_json("cube-stacking", "paper", [])) == ("seq", "")
    assert policy_of(_json("cube-stacking", "paper", ['secondary.policy="advance"', "secondary.stall_steps=16"])) == ("advance", "stall 16")
