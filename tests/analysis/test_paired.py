"""Paired bounds of the mean log ratio that hold for every distribution of the capped times."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.analysis import paired

CAP = 3000.0
MARGIN = math.log(1.1)


def _rank(verdict: str) -> int:
    return paired.ORDER[verdict.removeprefix(f"{paired.PROVISIONAL} ")]


def _slower(factor: float, n: int = 30) -> paired.SlowdownVerdict:
    always = np.full(n, 100.0)
    return paired.slowdown(always * factor, always, CAP)


def test_thirty_ties_get_finite_bounds_and_no_verdict_of_either_kind() -> None:
    found = _slower(1.0)
    assert math.isfinite(found.lower) and math.isfinite(found.upper)
    assert found.lower < 0.0 < found.upper and found.ties == 30
    assert found.verdict == paired.INCONCLUSIVE  # 30 pairs cannot bound a mean on [-log cap, log cap]


@pytest.mark.parametrize("factor", [1.0, 1.05, 2.0, 7.0])
def test_all_equal_samples_of_any_value_are_treated_alike(factor: float) -> None:
    """No rule for "no spread": every all-equal sample gets finite bounds around its value, the
    same width whatever the value (up to the range's asymmetry)."""
    found = _slower(factor)
    assert math.isfinite(found.lower) and math.isfinite(found.upper)
    assert found.lower < found.log_ratio < found.upper
    assert found.log_ratio == pytest.approx(math.log(factor), abs=1e-12)


def test_ties_105_200_and_one_step_slower_pairs_are_monotone_in_the_slowdown() -> None:
    always = np.full(30, 100.0)
    samples = [always.copy()]
    for k in range(1, 9):  # 1-8 of 30 pairs one step slower
        policy = always.copy()
        policy[:k] += 1.0
        samples.append(policy)
    samples += [always * 1.05, always * 2.0]
    verdicts = [paired.slowdown(s, always, CAP) for s in samples]
    for v in verdicts:
        assert math.isfinite(v.lower) and math.isfinite(v.upper)
    uppers = [v.upper for v in verdicts]
    lowers = [v.lower for v in verdicts]
    assert uppers == sorted(uppers) and lowers == sorted(lowers)
    ranks = [_rank(v.verdict) for v in verdicts]
    assert ranks == sorted(ranks)


def test_enough_pairs_decide_both_ways() -> None:
    assert _slower(1.0, 400).verdict == paired.NON_INFERIOR
    assert _slower(2.0, 300).verdict == paired.INFERIOR
    assert _slower(1.05, 3000).verdict == paired.NON_INFERIOR  # 5% slower lies inside a 10% margin


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.floats(1.0, CAP), min_size=1, max_size=60),
    st.lists(st.floats(1.0, CAP), min_size=60, max_size=60),
    st.integers(0, 59),
    st.floats(0.0, 50.0),
)
def test_a_slower_pair_never_strengthens_the_verdict(policy: list[float], always: list[float], which: int, extra: float) -> None:
    a = np.array(policy)
    b = np.array(always[: len(policy)])
    slower = a.copy()
    slower[which % len(a)] = min(slower[which % len(a)] + extra, CAP)
    before, after = paired.slowdown(a, b, CAP), paired.slowdown(slower, b, CAP)
    assert after.upper >= before.upper and after.lower >= before.lower
    assert _rank(after.verdict) >= _rank(before.verdict)
    t_before, t_after = paired.tail(a, b, CAP), paired.tail(slower, b, CAP)
    assert _rank(t_after.verdict) >= _rank(t_before.verdict)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-8.0, 8.0), min_size=1, max_size=50))
def test_the_bounds_bracket_the_sample_mean_and_stay_in_range(values: list[float]) -> None:
    x = np.array(values)
    upper = paired.upper_bounds(x[None, :], 8.0)[0]
    lower = -paired.upper_bounds(-x[None, :], 8.0)[0]
    assert -8.0 <= lower <= x.mean() + 1e-9 and x.mean() - 1e-9 <= upper <= 8.0


def test_the_bound_keeps_its_level_on_the_worst_two_point_law() -> None:
    """The hardest laws for a bounded mean put their mass at the range's ends and one inner point:
    a share q of pairs at +log cap (the policy never solved, always at step 1), the rest tied; the
    mean sits at the margin. The upper bound must lie below it in at most 5% of samples."""
    span = math.log(CAP)
    rng = np.random.default_rng(7)
    for n in (10, 30, 100):
        q = MARGIN / span
        x = np.where(rng.random((4000, n)) < q, span, 0.0)
        below = float(np.mean(paired.upper_bounds(x, span) < MARGIN))
        assert below <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / 4000)


def test_a_trial_that_never_solved_counts_at_its_cap_and_censored_pairs_are_counted_apart() -> None:
    always = np.full(10, 100.0) + np.arange(10)
    policy = always.copy()
    policy[0] = math.inf
    assert paired.slowdown(policy, always, 2000.0).n == 9  # a non-finite time drops its pair
    policy[0] = 5000.0  # counted at the cap
    capped = paired.slowdown(policy, always, 2000.0)
    assert capped.n == 10 and capped.log_ratio == pytest.approx(math.log(2000.0 / 100.0) / 10)
    both = paired.slowdown(np.full(10, 2000.0), np.full(10, 2500.0), 2000.0)
    assert both.censored == 10 and both.ties == 10 and both.log_ratio == 0.0
    with pytest.raises(ValueError, match="step cap"):
        paired.slowdown(policy, always, math.inf)


def test_below_min_pairs_every_verdict_is_provisional() -> None:
    always = np.full(paired.MIN_PAIRS - 1, 100.0)
    assert _slower(1.0, paired.MIN_PAIRS - 1).verdict == f"{paired.PROVISIONAL} {paired.INCONCLUSIVE}"
    assert paired.tail(always, always, CAP).verdict.startswith(paired.PROVISIONAL)
    assert paired.equivalence(always, always, CAP).verdict.startswith(paired.PROVISIONAL)
    assert not _slower(1.0, paired.MIN_PAIRS).verdict.startswith(paired.PROVISIONAL)


def test_the_tail_share_has_exact_bounds_at_three_margins() -> None:
    always = np.full(30, 100.0)
    none_late = paired.tail(always * 1.05, always, CAP)
    assert none_late.late_pairs == 0 and none_late.upper == pytest.approx(1 - 0.05 ** (1 / 30), rel=1e-6)
    assert none_late.verdict == paired.NON_INFERIOR  # 9.5% < 10%
    assert [m for m, _ in none_late.at_margins] == [0.05, 0.10, 0.20]
    assert [v for _, v in none_late.at_margins] == [paired.INCONCLUSIVE, paired.NON_INFERIOR, paired.NON_INFERIOR]
    late = always.copy()
    late[:15] = 500.0
    assert paired.tail(late, always, CAP).verdict == paired.INFERIOR


def test_censored_pairs_decide_the_tail_only_where_both_countings_agree() -> None:
    always = np.full(30, 100.0)
    policy = always.copy()
    always[:3] = policy[:3] = CAP  # neither solved by the cap in 3 pairs
    found = paired.tail(policy, always, CAP)
    assert found.censored == 3 and found.late_pairs == 0
    assert found.upper < 0.10 < found.upper_if_late  # on time: non-inferior; as late: not
    assert found.verdict == paired.INCONCLUSIVE
    assert found.upper_if_late == pytest.approx(0.2386, abs=1e-4)  # 3 of 30 counted late: 23.9%, above 20% too
    assert dict(found.at_margins)[0.20] == paired.INCONCLUSIVE


def test_the_coverage_benchmark_prints_the_worst_false_non_inferior_rate_over_its_family() -> None:
    import re
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "benchmarks/coverage.py", "--paired", "--experiments", "200", "--n", "5,30"],
        cwd=root, capture_output=True, text=True, timeout=300, env={"PYTHONPATH": str(root), "PATH": ""},
    )
    assert done.returncode == 0, done.stderr
    rows = re.findall(r"^\s+(\d+)\s+([\d.]+)%\s+([\d.]+)%\s+([\d.]+)%", done.stdout, re.M)
    assert [int(n) for n, *_ in rows] == [5, 30]
    assert all(float(worst) <= 5.0 + 3 * 100 * math.sqrt(0.05 * 0.95 / 200) for _, worst, _, _ in rows)
    assert "70 laws" in done.stdout and "(provisional: below MIN_PAIRS)" in done.stdout.splitlines()[2]
