"""The frontier protocol: refusals for store misses, matched-rate random, non-inferiority
against always, the tuning split on held-out seeds."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lagrseq import cli
from lagrseq.analysis.frontier import Point, judge, panel, summarise
from lagrseq.analysis.loading import Run
from lagrseq.frontier_protocol import matched_probability
from lagrseq.logs.reader import read_info, read_topic
from tests.llm.conftest import authors_cache
from tests.support.frontier import point as _point


def _cube_store(tmp_path: Path) -> Path:
    store = tmp_path / "store"
    path = authors_cache("cube_stacking_cache0.0.pkl")
    assert cli.main(["cache", "import", str(path), "--task", "cube-stacking", "--model", "gpt-3.5-turbo",
                     "--temperature", "0", "--store", str(store)]) == 0
    return store


def test_a_refused_miss_costs_a_query_is_logged_and_is_never_accepted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = _cube_store(tmp_path)
    common = ["run", "cube-stacking", "--method", "lagr", "--provider", f"recorded:{store}", "--on-miss", "refuse",
              "--trials", "1", "--out", str(tmp_path / "runs"), "--quiet", "--set", "run.episodes=6"]
    capsys.readouterr()
    assert cli.main([*common, "--set", "task.stack_size=5"]) == 0  # 5 cubes: no key is in the store
    printed = capsys.readouterr().out
    assert cli.main(common) == 0  # 8 cubes: every prefix is recorded
    by_size: dict[int, list[dict[str, object]]] = {}
    episodes: dict[int, list[dict[str, object]]] = {}
    for log in sorted((tmp_path / "runs").rglob("*.mcap")):
        size = read_info(log).config["task"]["stack_size"]
        by_size[size] = [q for q in read_topic(log, "/query") if q["queried"]]
        episodes[size] = read_topic(log, "/episode")
    refused = by_size[5]
    assert refused, "the always policy asks on the 5-cube task"
    for q in refused:  # logged as a miss: an empty answer, a wrong answer, never accepted
        assert q["source"] == "miss" and q["answer"] == "" and q["accepted"] is False and q["evaluation"] == 0.0
        assert q["finish_reason"] == "refused" and "refused" in str(q["parse_error"])
        assert q["query_reward"] < 0  # the binary query reward of a wrong answer
    # each refusal is a query: the episodes count them, and nothing was ever accepted
    assert sum(int(e["queries"]) for e in episodes[5]) == len(refused)  # type: ignore[call-overload]
    assert sum(int(e["accepted"]) for e in episodes[5]) == 0  # type: ignore[call-overload]
    assert f"{len(refused)} refused (--on-miss refuse: never accepted) (100.0% missed the store)" in printed
    # where the store holds the answers, nothing is refused and answers are accepted
    assert {q["source"] for q in by_size[8]} == {"recorded"} and any(q["accepted"] for q in by_size[8])


def test_refusal_is_no_answer_even_when_its_text_would_parse(tmp_path: Path) -> None:
    """The loop rejects a ``miss`` answer by its source, not by its text."""
    from lagrseq import config as cfg
    from lagrseq.llm.base import Answer, Query
    from lagrseq.loop.lagr import consult
    from lagrseq.tasks.cube import CubeStacking

    task = CubeStacking(8)
    config = cfg.load("cube-stacking", "lagr", "paper")

    class Parrot:
        name = "parrot"

        def complete(self, query: Query) -> Answer:  # the right answer, but marked as a refusal
            return Answer(text="['a','b','c','d','e','f','g','h']", source="miss", model=query.model)

        def close(self) -> None:
            return None

        def __enter__(self) -> Parrot:
            return self

        def __exit__(self, *exc: object) -> None:
            return None

    result = consult(task, Parrot(), config.llm, config.lagr.threshold, (0,))
    assert result.accepted is False and result.evaluation == 0.0 and not result.parsed.ok


# -- matched rate, non-inferiority and credit on hand-made points -------------------------------------


def test_matched_probability_is_the_runs_query_rate() -> None:
    assert matched_probability(30, 100) == 0.3
    assert matched_probability(1, 3) == 0.33  # two significant digits: the report finds the run again
    assert matched_probability(7, 7) == 1.0
    assert matched_probability(1, 10**6) == 0.001  # never below 0.001 (0 would be never)
    with pytest.raises(ValueError):
        matched_probability(0, 0)


def _around(base: list[float], ratios: list[float]) -> list[float]:
    """Each of ``base``'s times scaled by the next of ``ratios`` (cycled): a policy's per-pair times."""
    return [b * ratios[i % len(ratios)] for i, b in enumerate(base)]


ALWAYS_20 = [100.0, 104, 96, 102, 98, 101, 99, 103, 97, 100, 250, 40, 180, 75, 120, 60, 310, 90, 140, 55]
"""Always's steps to the first solve in 20 hand-made trials: the trials differ far more between
one another than any margin (the environment's draws), as the measured ones do."""
ALWAYS_400 = ALWAYS_20 * 20
"""400 pairs: enough for a bound valid for every distribution of the capped log ratio to decide."""


def test_noninferiority_tail_and_credit_on_hand_made_points() -> None:
    always = _point("always", ALWAYS_400)
    same = _point("thompson", _around(ALWAYS_400, [1.01, 0.98, 1.03, 0.99, 1.0]), queries=20, decisions=100)  # rate 0.2
    slow = _point("seq", _around(ALWAYS_400, [1.5, 1.45, 1.55]), queries=50, decisions=100)  # rate 0.5
    few = _point("thompson", ALWAYS_20[:5], queries=20, decisions=100)  # 5 trials against 400: no pairs
    random_02 = _point("random", _around(ALWAYS_400, [1.6, 1.5, 1.7]), p=0.2)  # slower than thompson
    random_05 = _point("random", _around(ALWAYS_400, [1.0, 1.02, 0.99]), p=0.5)  # faster than seq
    mocked = _point("thompson", list(same.steps_to_solve), queries=20, on_miss="mock", missed=4)
    oracle = _point("oracle", list(same.steps_to_solve), queries=5)
    points = [always, same, slow, few, random_02, random_05, mocked, oracle]
    verdicts = judge(points)
    found = verdicts[id(same)].against_always
    assert found is not None and found.verdict == "non-inferior" and found.n == 400
    longest = max(float(p.steps_to_solve.max()) for p in points)
    assert found.upper < math.log(1.1) and found.cap == longest  # the panel's horizon: its longest trial here
    assert verdicts[id(slow)].against_always.verdict == "inferior"  # type: ignore[union-attr]
    assert verdicts[id(few)].against_always.reason.startswith("pairs missing")  # type: ignore[union-attr]
    # the tail: none of the 400 pairs is more than 10% late, the exact bound 0.75% < 10%
    tail = verdicts[id(same)].tail
    assert tail is not None and tail.verdict == "non-inferior" and tail.late_pairs == 0 and tail.censored == 0
    assert tail.upper == pytest.approx(1 - 0.05 ** (1 / 400), rel=1e-6)
    assert verdicts[id(slow)].tail.verdict == "inferior"  # type: ignore[union-attr]
    # each learning policy meets random at its own rate (queries / decisions)
    assert verdicts[id(same)].matched is random_02 and verdicts[id(slow)].matched is random_05
    assert verdicts[id(same)].beats_random and not verdicts[id(slow)].beats_random
    # credit: non-inferior on the mean log ratio and on the tail, and better than random at the matched rate
    assert verdicts[id(same)].credited and not verdicts[id(slow)].credited and not verdicts[id(few)].credited
    # the oracle peeks: a bound, never credited; points on mock fallback answers get no verdict
    assert not verdicts[id(oracle)].credited and verdicts[id(oracle)].matched is None
    assert verdicts[id(mocked)].against_always is None and not verdicts[id(mocked)].credited
    assert verdicts[id(random_02)].matched is None  # random is not matched with itself
    eager = _point("thompson", list(same.steps_to_solve), queries=100, decisions=100)  # asks at every decision
    assert judge([always, eager])[id(eager)].matched is always  # random at rate 1 is always
    # the same verdicts in the table, with the margins and the horizon named
    summarise(points)
    made = panel(points)
    shown, rows = made.table, made.rows
    data = shown.data
    assert f"mean log ratio (margin 10%, horizon {longest:.0f} steps)" in " ".join(shown.columns)
    assert "pairs > 10% later (exact bound, tail margin 10%)" in " ".join(shown.columns)
    assert list(data["vs_always"]) == [
        "reference", "non-inferior", "inferior", "inconclusive", "inferior", "non-inferior",
        "no verdict: misses answered by the mock", "non-inferior",
    ]
    assert list(data["vs_always_tail"])[1:3] == ["non-inferior", "inferior"]
    assert list(data["credited"]) == [False, True, False, False, False, False, False, False]
    # the second primary outcome gets its own verdict (every hand-made trial solved one episode)
    assert list(data["vs_always_episodes_solved"])[1:4] == ["non-inferior", "non-inferior", "inconclusive"]
    assert rows[-1].label == "oracle (peeks at the answer)" and rows[-1].paper == "bound"
    assert data["noninferiority_margin"].iloc[0] == pytest.approx(math.log(1.1))
    assert rows[1].tail == "non-inferior (0 of 400 pairs late, bound 0.8% vs 10%)"
    assert rows[1].tail_margins == "5%: non-inferior; 10%: non-inferior; 20%: non-inferior"
    assert rows[1].vs_random.startswith("beats (ratio 0.")
    assert [r.credited for r in rows][:3] == ["no", "yes", "no"]
    # the Markdown columns follow the named rows: no cell can move under another header
    assert shown.rows[1][shown.columns.index("credited")] == rows[1].credited


def test_identical_pairs_get_bounds_and_the_tail_is_its_own_verdict() -> None:
    """A policy as fast as always in every pair is treated like any other sample: finite bounds,
    here narrow enough at 400 pairs. A policy 11% late in 160 of 400 pairs stays within the
    mean's margin on its point estimate (4%) but fails the tail: not credited, though it beats random."""
    always = _point("always", ALWAYS_400)
    twin = _point("thompson", ALWAYS_400, queries=20)
    late = _point("thompson", [b * (1.11 if i % 5 in (0, 2) else 1.0) for i, b in enumerate(ALWAYS_400)], queries=20)
    random_02 = _point("random", _around(ALWAYS_400, [1.6, 1.5, 1.7]), p=0.2)
    verdicts = judge([always, twin, late, random_02])
    same = verdicts[id(twin)].against_always
    assert same is not None and same.verdict == "non-inferior" and same.ties == 400 and math.isfinite(same.lower)
    on_mean, on_tail = verdicts[id(late)].against_always, verdicts[id(late)].tail
    assert on_mean is not None and on_mean.log_ratio < math.log(1.1)
    assert on_tail is not None and on_tail.late_pairs == 160 and on_tail.verdict == "inferior"
    assert verdicts[id(late)].beats_random and not verdicts[id(late)].credited


def test_a_design_or_tuning_seed_is_never_credited() -> None:
    """advance's rule and knob values were read from seeds 1, 3 and 1000004: a point of advance on any is shown with
    the role ``design`` and no credit, however good; a point tuned on its own run seed is ``tuning``."""
    from lagrseq.analysis.frontier import DESIGN, EVALUATION, TUNING, design_seeds

    assert design_seeds("advance") == (1, 3, 1_000_004)

    def on_seed(point: Point, seed: int) -> Point:
        point.run = Run(dataclasses.replace(point.run.key, seed=seed), point.run.config, (), point.run.trials, pd.DataFrame(), pd.DataFrame(), 0)
        return point

    for seed, role in ((1, DESIGN), (3, DESIGN), (1_000_004, DESIGN), (2, EVALUATION)):
        always = on_seed(_point("always", ALWAYS_400), seed)
        good = on_seed(_point("advance", _around(ALWAYS_400, [1.01, 0.98, 1.0]), queries=20), seed)
        random_02 = on_seed(_point("random", _around(ALWAYS_400, [1.6, 1.5, 1.7]), p=0.2), seed)
        verdict = judge([always, good, random_02])[id(good)]
        assert verdict.role == role and verdict.credited == (role == EVALUATION)
        summarise([always, good, random_02])
        made = panel([always, good, random_02])
        assert made.rows[1].seed_role.startswith(f"{seed}: {role}")
        assert list(made.table.data["seed_role"]) == ["evaluation", role, "evaluation"]
        assert made.table.data["design_seeds"].iloc[1] == "1 3 1000004"
        if role == DESIGN:
            assert made.rows[1].credited == "no (design seed: not evidence)"
    tuned = _point("thompson", _around(ALWAYS_400, [1.01, 0.98, 1.0]), queries=20)
    tuned.tuning = {"role": "tuned", "tuning_seed": 0, "evaluation_seed": 0}
    always = _point("always", ALWAYS_400)
    random_02 = _point("random", _around(ALWAYS_400, [1.6, 1.5, 1.7]), p=0.2)
    verdict = judge([always, tuned, random_02])[id(tuned)]
    assert verdict.role == TUNING and not verdict.credited and verdict.credit_text == "no (tuning seed: not evidence)"


def test_cells_show_no_interval_below_three_trials_and_round_outward() -> None:
    from lagrseq.analysis.frontier import outward

    always = _point("always", [100.0, 300.0])
    policy = _point("thompson", [120.0, 5000.0], queries=2)
    summarise([always, policy])
    rows = panel([always, policy]).rows
    assert rows[1].steps == "2560 (n < 3: no interval)"
    assert rows[1].vs_always.startswith("provisional ")
    assert outward(0.123, 4.561, 1) == "[0.1, 4.6]" and outward(-0.001, 0.0, 2) == "[-0.01, 0.00]"


def test_the_bounds_are_the_same_on_every_replay() -> None:
    """The bounds are a function of the pairs alone: judged twice, in another order of points,
    the same bounds to the bit."""
    always = _point("always", ALWAYS_20)
    policy = _point("thompson", _around(ALWAYS_20, [1.0, 1.0, 1.3, 1.0, 0.97]), queries=20)
    first = judge([always, policy])[id(policy)].against_always
    again = judge([policy, always])[id(policy)].against_always
    assert first is not None and again is not None and (first.lower, first.upper) == (again.lower, again.upper)


def test_paired_where_the_logs_pair_the_trials_no_verdict_where_pairs_are_missing() -> None:
    """A point whose trials do not match always's (another seed, a trial missing) gets no verdict
    (both estimands are per pair), pairs line up by trial index, and the table names the test."""
    base = [260.0, 1610, 160, 120, 320, 330, 890, 90, 220, 100, 410, 75, 530, 140, 980, 66, 300, 210, 450, 180]
    always = _point("always", base)
    close = _point("thompson", [b + d for b, d in zip(base, [0, 2, 0, 1, 0, 1, 0, 0, 0, 3] * 2, strict=True)], queries=20)
    points = [always, close]
    verdict = judge(points)[id(close)].against_always
    assert verdict is not None and verdict.n == 20 and verdict.verdict == "inconclusive"  # 20 pairs: bounds too wide
    # the same numbers under another run seed: no pairs, no verdict
    other = _point("thompson", list(close.steps_to_solve), queries=20)
    other.run = Run(dataclasses.replace(other.run.key, seed=5), other.run.config, (), other.run.trials, pd.DataFrame(), pd.DataFrame(), 0)
    missing = judge([always, other])[id(other)]
    assert missing.against_always is not None and missing.against_always.verdict == "inconclusive"
    assert missing.against_always.reason.startswith("pairs missing: seed 5 against 0")
    assert missing.tail is not None and missing.tail.verdict == "inconclusive" and missing.tail.n == 0
    # pairs line up by trial index, not by position: shuffled trials give the same verdict
    order = [3, 1, 0, 2, 9, 8, 7, 6, 5, 4, *range(10, 20)]
    shuffled = _point("thompson", [close.steps_to_solve[i] for i in order], queries=20)
    shuffled.run = Run(shuffled.run.key, shuffled.run.config, (), tuple(order), pd.DataFrame(), pd.DataFrame(), 0)
    again = judge([always, shuffled])[id(shuffled)].against_always
    assert again is not None and again.log_ratio == pytest.approx(verdict.log_ratio) and again.upper == verdict.upper
    summarise(points)
    made = panel(points)
    cell = made.rows[1].vs_always
    assert cell.startswith("inconclusive (ratio 1") and "margin 1.10, n = 20 pairs" in cell
    assert list(made.table.data["vs_always_test"]) == ["", "paired betting bound (log ratio)"]
    summarise([always, other])
    unpaired = panel([always, other])
    assert unpaired.rows[1].vs_always == "inconclusive (pairs missing: seed 5 against 0, no verdict)"
    assert list(unpaired.table.data["vs_always_test"]) == ["", "no pairs"]


# -- the tuning split and the matched-rate runs, end to end -------------------------------------------


def test_tuning_never_touches_evaluation_seeds_and_the_choice_is_in_the_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from lagrseq.config import from_dict as config_from_dict
    from lagrseq.frontier_protocol import TUNING_NOTE
    from lagrseq.running.runner import run_directory
    from lagrseq.seeding import Stream, integer_seed
    from lagrseq.study.frontier import TUNE_GRID, matched_random_config

    out = tmp_path / "fr"
    args = [
        "frontier", "cube-stacking", "--preset", "paper", "--provider", "mock:authors-t0", "--policies", "always,thompson",
        "--trials", "2", "--set", "run.episodes=4", "--out", str(out), "--quiet", "--seed", "7",
        "--tune", "--tune-trials", "2",
    ]
    assert cli.main(args) == 0
    roles: dict[str, set[tuple[int, int]]] = {"tuning": set(), "evaluation": set()}
    tuned_notes = []
    rates: dict[str, tuple[int, int]] = {}
    configs: dict[str, dict[str, object]] = {}
    for log in sorted(out.rglob("*.mcap")):
        info = read_info(log)
        note = json.loads(info.run.get(TUNING_NOTE, "{}"))
        role = "tuning" if note.get("role") == "tuning" else "evaluation"
        roles[role].add((int(info.run["seed"]), int(info.run["trial"])))
        if note.get("role") == "tuned":
            tuned_notes.append(note)
        secondary = info.config.get("secondary", {})
        if info.run["method"] == "lagr-seq" and role == "evaluation":
            rows = read_topic(log, "/query")
            name = f"{secondary['policy']}:{secondary.get('query_cost', 0)}:{secondary.get('ask_probability', 0.5)}"
            queried, decided = rates.get(name, (0, 0))
            rates[name] = (queried + sum(bool(r["queried"]) for r in rows), decided + len(rows))
            configs[name] = info.config
    # 1 control + 4 candidates x 2 tuning trials; the evaluation: the given variants, the chosen one, matched random
    assert {seed for seed, _ in roles["tuning"]} == {7 + 1_000_003} and {seed for seed, _ in roles["evaluation"]} == {7}
    assert not roles["tuning"] & roles["evaluation"]
    env_seeds = {role: {integer_seed(s, t, Stream.ENV) for s, t in pairs} for role, pairs in roles.items()}
    assert not env_seeds["tuning"] & env_seeds["evaluation"]  # no environment the tuning saw is evaluated
    # the choice is written into the evaluation logs' metadata, with the rule and every candidate
    assert tuned_notes and {n["policy"] for n in tuned_notes} == {"thompson"}
    note = tuned_notes[0]
    assert note["knob"] == "query_cost" and note["chosen"] in TUNE_GRID["thompson"][1]
    assert note["tuning_seed"] == 7 + 1_000_003 and note["evaluation_seed"] == 7 and "fewest mean queries" in note["rule"]
    assert [c["value"] for c in note["candidates"]] == list(TUNE_GRID["thompson"][1])
    # random ran at the matched rate of every thompson evaluation run (queries / decisions, from the logs)
    matched = {float(name.split(":")[2]) for name in rates if name.startswith("random:")}
    for name, (queried, decided) in rates.items():
        if name.startswith("thompson") and queried:
            assert matched_probability(queried, decided) in matched
            # reproduce's matched run (matched_random_config) is this very run directory
            match = matched_random_config(config_from_dict(configs[name]), matched_probability(queried, decided))
            assert run_directory(out, match, "mock:authors-t0", 7).is_dir()
    # the table says how each point's knobs were chosen
    (csv,) = (out / "frontier").glob("*seed7*.csv")
    data = pd.read_csv(csv, keep_default_na=False)
    assert any(str(c).startswith("tuned on seed 1000010") for c in data["knobs_chosen"])
    assert "given" in set(data["knobs_chosen"]) and "random" in set(data["policy"])
    index = json.loads((out / "frontier.json").read_text())
    assert index[-1]["tuned"]["preset/thompson"]["chosen"] == note["chosen"]
    capsys.readouterr()
    assert cli.main([*args, "--tune-seed", "7"]) == 2  # tuning on the evaluation seed is refused
    assert "evaluation seed" in capsys.readouterr().err


def test_scopes_auto_runs_both_regimes_on_the_grids_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lagrseq.errors import UsageError
    from lagrseq.study.frontier import parse_scopes

    assert parse_scopes("auto", "object-arrangement") == ["episode", "trial"]
    assert parse_scopes("auto", "cube-stacking") == [None]  # the preset's own (cube: episode)
    assert parse_scopes("trial, episode,trial", "image-completion") == ["trial", "episode"]
    for bad in ("", "forever", "episode,weekly"):
        with pytest.raises(UsageError):
            parse_scopes(bad, "cube-stacking")
    assert cli.main(["frontier", "cube-stacking", "--scopes", "forever", "--out", str(tmp_path)]) == 2
    assert "--scopes 'forever'" in capsys.readouterr().err


def test_the_tail_needs_the_pairs_the_docs_state() -> None:
    """docs/frontier.md: with no late pair the tail's exact bound falls below 10% from 29 pairs on,
    with one from 46, with two from 61."""
    from lagrseq.analysis import paired

    def first(late: int) -> int:
        for n in range(2, 200):
            policy = np.r_[np.full(late, 200.0), np.full(n - late, 100.0)]
            if paired.tail(policy, np.full(n, 100.0), 1000.0).settled == paired.NON_INFERIOR:
                return n
        return -1

    assert [first(0), first(1), first(2)] == [29, 46, 61]


def test_a_fallback_that_answered_nothing_withholds_no_verdict() -> None:
    """A run on a store whose misses would go to the mock, but that met no miss, took every answer
    from the store: it is judged like a run that refuses misses. One miss answered by the mock
    withholds the verdict."""
    always = _point("always", ALWAYS_400, on_miss="mock")
    twin = _point("thompson", ALWAYS_400, queries=20, on_miss="mock")
    mocked = _point("thompson", ALWAYS_400, queries=20, on_miss="mock", missed=1)
    verdicts = judge([always, twin, mocked])
    assert verdicts[id(always)].note == "reference"
    assert verdicts[id(twin)].against_always is not None
    assert verdicts[id(twin)].against_always.verdict == "non-inferior"
    assert verdicts[id(mocked)].against_always is None
    assert verdicts[id(mocked)].note == "no verdict: misses answered by the mock"
