"""Asking policies (lagrseq.loop.policies): decisions and updates on hand-worked cases, the budget's
cap, the oracle's lower bound, and the paper's SEQ through the new interface giving the very
events it gave before the interface existed."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lagrseq import config as cfg
from lagrseq.errors import UsageError
from lagrseq.logs.reader import iter_messages, read_info, read_topic
from lagrseq.loop.policies import (
    AdvancePolicy,
    Always,
    AskContext,
    Budget,
    Never,
    Oracle,
    ProgressGate,
    RandomAsk,
    SeqPolicy,
    ThompsonPolicy,
    make_policy,
    pattern_key,
)
from lagrseq.loop.seq import TabularSecondary
from lagrseq.running.runner import run_one
from lagrseq.running.wiring import check_provider, provider_options


def context(pattern=(4, 5), progress=2, rng=None, trial=0, episode=0, epsilon=0.0, peek=None) -> AskContext:
    return AskContext(
        pattern, progress, 0, 0, 0, epsilon, rng or np.random.default_rng(0), trial, episode, peek
    )


def test_never_and_always() -> None:
    c = context()
    assert [Never().decide(c), Always().decide(c)] == [0, 1]
    Never().update(c, 0, 0.0)
    Always().update(c, 1, 1.0)


def test_random_asks_with_its_probability_from_the_secondary_stream() -> None:
    # default_rng(0).random() draws 0.6369616873214543, 0.2697867137638703, 0.04097352393619469
    policy = RandomAsk(0.5)
    c = context(rng=np.random.default_rng(0))
    assert [policy.decide(c) for _ in range(3)] == [0, 1, 1]
    assert RandomAsk(0.0).decide(c) == 0 and RandomAsk(1.0).decide(c) == 1


def test_seq_policy_is_the_bandit_unchanged() -> None:
    bandit = TabularSecondary(0.1)
    policy = SeqPolicy(bandit)
    c = context(epsilon=0.0)
    assert policy.decide(c) == 0  # ties go to "do not query"
    policy.update(c, 1, 1.0)  # Q2[s, 1] = 0 + 0.1 (1 - 0) = 0.1 > Q2[s, 0] = 0
    assert bandit.table[(4, 5)].tolist() == [0.0, pytest.approx(0.1)]
    assert policy.decide(c) == 1
    policy.update(c, 1, -1.0)  # 0.1 + 0.1 (-1 - 0.1) = -0.01
    assert bandit.table[(4, 5)][1] == pytest.approx(-0.01)
    assert policy.decide(c) == 0


def test_thompson_binary_posterior_per_progress_and_rejections() -> None:
    policy = ThompsonPolicy((1.0, 1.0), "binary", reward_correct=1.0, reward_wrong=-1.0)
    c = context(pattern=(4, 5, 6), progress=3)
    assert policy.context_key(c) == (3, 0)
    c.accepted = True
    policy.update(c, 1, 1.0)
    assert policy.posterior[(3, 0)] == [2.0, 1.0]
    c.accepted = False
    policy.update(c, 1, -1.0)
    assert policy.posterior[(3, 0)] == [2.0, 2.0]
    # the rejected pattern is now its own context; another pattern at progress 3 shares (3, 0)
    assert policy.context_key(c) == (3, 1)
    assert policy.context_key(context(pattern=(4, 5, 7), progress=3)) == (3, 0)
    policy.update(c, 0, 0.0)  # not asking teaches nothing
    assert policy.posterior[(3, 0)] == [2.0, 2.0] and (3, 1) not in policy.posterior


def test_thompson_decides_on_the_sampled_net_reward() -> None:
    rng = np.random.default_rng(5)
    # reward_wrong = 0 (grids): theta > 0 always, so without a cost it always asks ...
    free = ThompsonPolicy((1.0, 1.0), "binary", 1.0, 0.0, cost=0.0)
    assert all(free.decide(context(rng=rng)) == 1 for _ in range(50))
    # ... and with a cost above the best reward it never does
    dear = ThompsonPolicy((1.0, 1.0), "binary", 1.0, 0.0, cost=1.0)
    assert all(dear.decide(context(rng=rng)) == 0 for _ in range(50))
    # the decision equals the hand-computed draw: theta ~ Beta(1, 1), ask iff 2 theta - 1 > 0.3
    policy = ThompsonPolicy((1.0, 1.0), "binary", 1.0, -1.0, cost=0.3)
    mine, theirs = np.random.default_rng(9), np.random.default_rng(9)
    for _ in range(20):
        theta = theirs.beta(1.0, 1.0)
        assert policy.decide(context(rng=mine)) == int(2 * theta - 1 - 0.3 > 0)


def test_thompson_logistic_gaussian_update() -> None:
    policy = ThompsonPolicy((1.0, 1.0), "logistic", cost=0.1)
    c = context(progress=4)
    c.accepted = False
    policy.update(c, 1, 0.9 - 0.1)  # the loop passes the reward net of the cost
    # prior mean 1/2, precision 2; one reward 0.9 with noise precision 4
    mean, precision = policy.posterior[(4, 0)]
    assert precision == 6.0 and mean == pytest.approx((0.5 * 2 + 0.9 * 4) / 6)


def test_budget_caps_queries_per_trial_and_per_episode() -> None:
    trial = Budget(Always(), 2, "trial")
    assert [trial.decide(context(trial=n)) for n in range(4)] == [1, 1, 0, 0]
    episode = Budget(Always(), 1, "episode")
    assert [episode.decide(context(trial=9, episode=n)) for n in range(3)] == [1, 0, 0]
    # once spent, the inner policy is neither asked nor updated
    inner = ThompsonPolicy((1.0, 1.0), "binary", 1.0, -1.0)
    capped = Budget(inner, 1)
    spent = context(trial=1)
    assert capped.decide(spent) == 0
    capped.update(spent, 0, 0.0)
    assert inner.posterior == {}


def test_progress_gate_asks_only_from_its_progress_on() -> None:
    gate = ProgressGate(Always(), 3)
    assert [gate.decide(context(progress=p)) for p in range(5)] == [0, 0, 0, 1, 1]
    # below the gate the inner policy draws nothing from the secondary stream: random(p=0.5) on
    # default_rng(0) draws 0.637 (no), 0.270 (yes); the gated calls at progress 1 and 2 draw none
    rng = np.random.default_rng(0)
    gated = ProgressGate(RandomAsk(0.5), 3)
    decisions = [gated.decide(context(progress=p, rng=rng)) for p in (1, 3, 2, 3)]
    assert decisions == [0, 0, 0, 1]
    # nor learns: a Thompson posterior is untouched below the gate, updated from it on
    inner = ThompsonPolicy((1.0, 1.0), "binary", 1.0, 0.0)
    learner = ProgressGate(inner, 4)
    low = context(progress=2)
    learner.update(low, 0, 0.0)
    assert inner.posterior == {}
    high = context(progress=4)
    high.accepted = True
    learner.update(high, 1, 1.0)
    assert inner.posterior == {(4, 0): [2.0, 1.0]}


def test_make_policy_gates_then_budgets() -> None:
    section = cfg.load(
        "cube-stacking", "lagr-seq", "upstream", None,
        ['secondary.policy="always"', "secondary.min_progress=2", "secondary.budget=1"],
    ).secondary
    policy = make_policy(section, lambda: pytest.fail("seq's agent is built only for policy seq"))
    assert isinstance(policy, Budget) and isinstance(policy.inner, ProgressGate)
    assert policy.inner.min_progress == 2 and isinstance(policy.inner.inner, Always)
    # progress 1: gated; progress 2: asks; then the budget of 1 is spent
    assert [policy.decide(context(progress=1)), policy.decide(context(progress=2)),
            policy.decide(context(progress=3, trial=1))] == [0, 1, 0]
    plain = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ['secondary.policy="always"']).secondary
    assert isinstance(make_policy(plain, lambda: pytest.fail("no seq")), Always)


def test_min_progress_is_validated_and_leaves_default_digests_alone() -> None:
    with pytest.raises(cfg.ConfigError, match="min_progress"):
        cfg.load("object-arrangement", "lagr-seq", "upstream", None, ["secondary.min_progress=-1"])
    base = cfg.load("object-arrangement", "lagr-seq", "upstream", None, [])
    explicit = cfg.load("object-arrangement", "lagr-seq", "upstream", None, ["secondary.min_progress=0"])
    gated = cfg.load("object-arrangement", "lagr-seq", "upstream", None, ["secondary.min_progress=4"])
    assert base.digest() == explicit.digest() != gated.digest()
    data = json.loads(base.to_json())
    del data["secondary"]["min_progress"]  # a configuration made before the field existed
    assert cfg.config_digest(data) == base.digest()


def test_oracle_asks_exactly_when_the_peeked_answer_is_accepted() -> None:
    looks: list[int] = []

    def peek(accepted: bool):
        def look():
            looks.append(1)
            return SimpleNamespace(accepted=accepted)
        return look

    yes, no = context(peek=peek(True)), context(peek=peek(False))
    assert Oracle().decide(yes) == 1 and Oracle().decide(no) == 0
    yes.peek()  # the look is made once per decision
    assert len(looks) == 2 and yes.peeked.accepted


def test_make_policy_from_the_section_with_budget() -> None:
    section = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ['secondary.policy="random"', "secondary.budget=3"]).secondary
    policy = make_policy(section, lambda: pytest.fail("seq's agent is built only for policy seq"))
    assert isinstance(policy, Budget) and isinstance(policy.inner, RandomAsk) and policy.limit == 3


def test_config_refuses_a_bad_prior_and_the_oracle_on_live_answers() -> None:
    with pytest.raises(cfg.ConfigError, match="thompson_prior"):
        cfg.load("cube-stacking", "lagr-seq", "upstream", None, ["secondary.thompson_prior=[1.0]"])
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ['secondary.policy="oracle"'])
    with pytest.raises(UsageError, match="oracle"):
        check_provider("live", config, provider_options("live", {}))


def _at(pattern=(4, 5), progress=2, episode=0) -> AskContext:
    return AskContext(pattern, progress, episode, 0, 0, 0.0, np.random.default_rng(0), 0, 0, None)


def test_advance_asks_at_each_new_best_progress_of_the_episode() -> None:
    policy = AdvancePolicy(stall_steps=1000)
    # the episode's first decision is a new best; then only rises above the best ask
    progress = [0, 1, 1, 0, 2, 2, 3, 1, 3]
    assert [policy.decide(_at(pattern=(i,), progress=p)) for i, p in enumerate(progress)] == [1, 1, 0, 0, 1, 0, 1, 0, 0]
    # a new episode starts its own best, whatever the last one reached
    assert [policy.decide(_at(pattern=(20 + i,), progress=p, episode=1)) for i, p in enumerate([1, 1, 2])] == [1, 0, 1]
    assert policy.stalled == 0


def test_advance_asks_after_stall_steps_decisions_without_a_new_best_or_a_query() -> None:
    policy = AdvancePolicy(stall_steps=3)
    got = [policy.decide(_at(pattern=(i,), progress=2)) for i in range(8)]
    # 0: new best (asks); 1, 2, 3: no new best, the third of them asks; 4-6 again; 7 waits
    assert got == [1, 0, 0, 1, 0, 0, 1, 0] and policy.stalled == 2


def test_advance_never_asks_a_rejected_pattern_again() -> None:
    policy = AdvancePolicy(stall_steps=1)
    first = _at(pattern=(7,), progress=1)
    assert policy.decide(first) == 1
    first.accepted = False
    policy.update(first, 1, -1.0)
    # the same pattern in a new episode is a new best, but its answer is known to be wrong
    assert policy.decide(_at(pattern=(7,), progress=1, episode=1)) == 0
    # nor is it asked when stalled; the next new pattern is (the stall count kept running)
    assert policy.decide(_at(pattern=(7,), progress=1, episode=1)) == 0
    assert policy.decide(_at(pattern=(8,), progress=1, episode=1)) == 1
    # an accepted answer is no rejection: its pattern is asked again at the next new best
    accepted = _at(pattern=(9,), progress=0, episode=2)
    assert policy.decide(accepted) == 1
    accepted.accepted = True
    policy.update(accepted, 1, 1.0)
    assert policy.decide(_at(pattern=(9,), progress=0, episode=3)) == 1
    assert policy.rejected == {(7,): 1}


def _rejected_twice(policy: AdvancePolicy, pattern: tuple[int, ...]) -> None:
    """Ask ``pattern`` and reject its answer; then again, at the first episode it is re-asked."""
    rng = np.random.default_rng(5)
    for episode in range(100):
        asked = AskContext(pattern, 1, episode, 0, 0, 0.0, rng, 0, 0, None)
        if policy.decide(asked):
            asked.accepted = False
            policy.update(asked, 1, -1.0)
        if policy.rejected.get(pattern_key(pattern)) == 2:
            policy.reasked = 0
            return
    pytest.fail("the rejected pattern was never asked again")


def test_advance_reasks_a_rejected_pattern_with_probability_decay_to_the_rejections() -> None:
    policy = AdvancePolicy(stall_steps=1000, reask_decay=0.5)
    _rejected_twice(policy, (7,))
    assert policy.rejected == {(7,): 2}
    rng, twin = np.random.default_rng(11), np.random.default_rng(11)
    # each new episode opens at a new best on the rejected pattern: one draw, ask below 0.5**2
    got = [policy.decide(AskContext((7,), 1, 2 + e, 0, 0, 0.0, rng, 0, 0, None)) for e in range(4000)]
    assert got == [int(u < 0.25) for u in twin.random(4000)]
    assert policy.reasked == sum(got) and abs(sum(got) / 4000 - 0.25) < 0.03
    # a pattern never rejected asks without a draw; a decision that would not ask draws nothing
    state = rng.bit_generator.state
    assert policy.decide(AskContext((8,), 1, 9000, 0, 0, 0.0, rng, 0, 0, None)) == 1
    assert policy.decide(AskContext((7,), 1, 9000, 0, 0, 0.0, rng, 0, 0, None)) == 0
    assert rng.bit_generator.state == state


def test_advance_reask_counts_rejections_and_stalls_only_when_it_asks() -> None:
    policy = AdvancePolicy(stall_steps=2, reask_decay=1.0)
    _rejected_twice(policy, (7,))
    # decay 1: a rejected pattern is asked wherever advance would ask, and rejections add up
    assert [policy.decide(_at(pattern=(7,), progress=1, episode=2)) for _ in range(5)] == [1, 0, 1, 0, 1]
    assert policy.stalled == 2 and policy.reasked == 3
    never = AdvancePolicy(stall_steps=2, reask_decay=0.0)
    first = _at(pattern=(7,), progress=1, episode=0)
    assert never.decide(first) == 1
    first.accepted = False
    never.update(first, 1, -1.0)
    # decay 0: never again, and the stall count runs on to the next pattern it may ask
    assert [never.decide(_at(pattern=(7,), progress=1, episode=2)) for _ in range(3)] == [0, 0, 0]
    assert never.decide(_at(pattern=(8,), progress=1, episode=2)) == 1 and never.stalled == 1 and never.reasked == 0


def test_reask_decay_is_range_checked_and_built_from_the_section() -> None:
    for bad in ("-0.1", "1.5", '"often"'):
        with pytest.raises(cfg.ConfigError, match="reask_decay"):
            cfg.load("cube-stacking", "lagr-seq", "paper", None, ['secondary.policy="advance"', f"secondary.reask_decay={bad}"])
    for bad_value in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="reask_decay"):
            AdvancePolicy(64, bad_value)
    section = cfg.load("cube-stacking", "lagr-seq", "paper", None, ['secondary.policy="advance"', "secondary.reask_decay=0.5"]).secondary
    policy = make_policy(section, lambda: pytest.fail("seq's agent is built only for policy seq"))
    assert isinstance(policy, AdvancePolicy) and policy.reask_decay == 0.5 and policy.stall_steps == 64
    base = cfg.load("cube-stacking", "lagr-seq", "paper", None, ['secondary.policy="advance"'])
    explicit = cfg.load("cube-stacking", "lagr-seq", "paper", None, ['secondary.policy="advance"', "secondary.reask_decay=0"])
    assert base.digest() == explicit.digest() != cfg.load(
        "cube-stacking", "lagr-seq", "paper", None, ['secondary.policy="advance"', "secondary.reask_decay=0.5"]).digest()


def test_advance_is_registered_with_validated_knobs_and_built_from_the_section() -> None:
    from lagrseq.registry import POLICIES, knob_names, tuned_knob

    spec = POLICIES.get("advance")
    assert spec.order > max(POLICIES.get(n).order for n in ("never", "always", "seq", "random", "thompson", "oracle"))
    knob = tuned_knob(spec)
    assert knob is not None and knob.name == "stall_steps" and knob.candidates and knob.help
    assert {"min_progress", "budget", "budget_scope", "query_cost"} <= set(knob_names(spec))
    for bad in ("0", "1000001", "2.5"):
        with pytest.raises(cfg.ConfigError, match="stall_steps"):
            cfg.load("object-arrangement", "lagr-seq", "upstream", None, ['secondary.policy="advance"', f"secondary.stall_steps={bad}"])
    section = cfg.load(
        "object-arrangement", "lagr-seq", "upstream", None,
        ['secondary.policy="advance"', "secondary.stall_steps=5", "secondary.budget=9"],
    ).secondary
    policy = make_policy(section, lambda: pytest.fail("seq's agent is built only for policy seq"))
    assert isinstance(policy, Budget) and isinstance(policy.inner, AdvancePolicy) and policy.inner.stall_steps == 5
    # at its default the field leaves every digest alone
    base = cfg.load("object-arrangement", "lagr-seq", "upstream", None, ['secondary.policy="advance"'])
    assert base.digest() == cfg.load("object-arrangement", "lagr-seq", "upstream", None, ['secondary.policy="advance"', "secondary.stall_steps=64"]).digest()
    with pytest.raises(ValueError, match="stall_steps"):
        AdvancePolicy(0)


def test_advance_runs_are_deterministic_and_get_every_answer_always_gets(tmp_path: Path) -> None:
    sets = ['secondary.policy="advance"', "secondary.stall_steps=1000000"]
    one = _run(tmp_path, "advance-a", sets)
    two = _run(tmp_path, "advance-b", sets)
    assert one == two
    asked = [q for q in one if q["queried"]]
    always = [q for q in _run(tmp_path, "always", [], method="lagr") if q["queried"]]
    assert 0 < len(asked) < len(always)
    # on the cube every answer always had accepted came where the stack rose to a new best of its
    # episode, so advance asks those very questions and follows always's path step for step
    assert [(q["global_step"], q["answer"]) for q in asked if q["accepted"]] == [
        (q["global_step"], q["answer"]) for q in always if q["accepted"]
    ]


# ------------------------------------------------------------------------------------------
# Runs
# ------------------------------------------------------------------------------------------
ADDED_SINCE = ("prompt", "outcome", "cached_tokens", "cut_by_step_budget")
"""Record fields added to the log after FROZEN was computed: a description of the same events."""


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    for topic, record in iter_messages(path, ["/transition", "/query", "/episode"]):
        record = {k: v for k, v in record.items() if k not in ADDED_SINCE}
        h.update(topic.encode())
        h.update(json.dumps(record, sort_keys=True).encode())
    return h.hexdigest()


# Computed with the code before asking policies existed (commit ebb29d7), trial 1 of seed 7.
FROZEN = [
    ("lagr-seq", "upstream", ["run.episodes=25"], "mock:authors-t0",
     "c277c4c2d059d0704e190456393fb18a9dc495badc69e855fcc0f6fb34a27793"),
    ("lagr-seq", "paper", ["run.episodes=20", 'secondary.query_reward="logistic"'], "mock",
     "8bd8d18f9c6657a1cf8af27620a44c8887ce11a4ad73fccd82e9f3ffe433bd39"),
    ("lagr", "upstream", ["run.episodes=15"], "mock",
     "c7766beee0f1df08151105fc9af06751636ec2c8ce4564ae09087fc536b60ec2"),
    ("baseline", "upstream", ["run.episodes=10"], "mock",
     "e4dfef4661a3baeb3036b2b3a66bd921bc2e8f2b70023ab37ef3a73d72b2dda0"),
]
# Computed with advance before it had reask_decay (commit 0d8c41a), trial 1 of seed 7: at its
# default the knob changes no event, on fixed answers and on answers sampled at temperature 1.
FROZEN_ADVANCE = [
    ("upstream", ["run.episodes=25", 'secondary.policy="advance"'], "mock:authors-t0",
     "bc1fd3118065145d4b214d9b65c91071c44340759991b1cff0897c7791db6c83"),
    ("paper", ["run.episodes=20", 'secondary.policy="advance"', "secondary.stall_steps=8", "llm.temperature=1.0"], "mock",
     "bd2925c251a154eb30bf5dc6d719c7175195cfb296c4e65968070b1e0e15c926"),
]


@pytest.mark.parametrize(("method", "preset", "sets", "provider", "digest"), FROZEN)
def test_the_paper_seq_and_the_old_methods_give_the_same_events_as_before(
    tmp_path: Path, method: str, preset: str, sets: list[str], provider: str, digest: str
) -> None:
    config = cfg.load("cube-stacking", method, preset, None, sets)
    path = tmp_path / "trial.mcap"
    run_one(config, 1, 7, provider, path)
    assert _digest(path) == digest


@pytest.mark.parametrize(("preset", "sets", "provider", "digest"), FROZEN_ADVANCE)
def test_advance_at_the_default_reask_decay_gives_the_same_events_as_before(
    tmp_path: Path, preset: str, sets: list[str], provider: str, digest: str
) -> None:
    for name, extra in (("default", []), ("zero", ["secondary.reask_decay=0"])):
        path = tmp_path / f"{name}.mcap"
        run_one(cfg.load("cube-stacking", "lagr-seq", preset, None, [*sets, *extra]), 1, 7, provider, path)
        assert _digest(path) == digest
    # re-asking changes the events (the digests above are not blind to the knob)
    path = tmp_path / "reask.mcap"
    run_one(cfg.load("cube-stacking", "lagr-seq", preset, None, [*sets, "secondary.reask_decay=1"]), 1, 7, provider, path)
    assert _digest(path) != digest


def _run(tmp_path: Path, name: str, sets: list[str], method: str = "lagr-seq", episodes: int = 30) -> list[dict]:
    config = cfg.load("cube-stacking", method, "upstream", None, [f"run.episodes={episodes}", *sets])
    path = tmp_path / f"{name}.mcap"
    run_one(config, 0, 3, "mock:authors-t0", path)
    return read_topic(path, "/query")


def test_oracle_is_the_lower_bound_and_budget_caps_a_run(tmp_path: Path) -> None:
    always = [q for q in _run(tmp_path, "always", [], method="lagr") if q["queried"]]
    oracle = [q for q in _run(tmp_path, "oracle", ['secondary.policy="oracle"']) if q["queried"]]
    # every query the oracle makes is accepted: no policy needs fewer for the same guidance
    assert oracle and all(q["accepted"] for q in oracle)
    assert len(oracle) < len(always)
    assert sum(q["accepted"] for q in always) <= len(always)
    capped = _run(tmp_path, "capped", ["secondary.budget=1", 'secondary.budget_scope="episode"'])
    per_episode: dict[int, int] = {}
    for q in capped:
        per_episode[q["episode"]] = per_episode.get(q["episode"], 0) + int(q["queried"])
    assert max(per_episode.values()) == 1
    trial = _run(tmp_path, "trial-budget", ['secondary.policy="always"', "secondary.budget=5"])
    assert sum(q["queried"] for q in trial) == 5


def test_query_cost_reaches_the_logged_reward(tmp_path: Path) -> None:
    queries = [q for q in _run(tmp_path, "cost", ['secondary.policy="thompson"', "secondary.query_cost=0.25"]) if q["queried"]]
    assert queries
    for q in queries:
        assert q["query_reward"] == pytest.approx((1.0 if q["accepted"] else -1.0) - 0.25)


def test_miss_report_counts_store_and_fallback_answers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lagrseq import cli
    from tests.llm.conftest import authors_cache

    store = tmp_path / "store"
    path = authors_cache("cube_stacking_cache0.0.pkl")
    assert cli.main(["cache", "import", str(path), "--task", "cube-stacking", "--model", "gpt-3.5-turbo",
                     "--temperature", "0", "--store", str(store)]) == 0
    common = ["run", "cube-stacking", "--method", "lagr", "--provider", f"recorded:{store}", "--on-miss", "mock",
              "--trials", "1", "--out", str(tmp_path / "runs"), "--quiet", "--set", "run.episodes=8"]
    capsys.readouterr()
    assert cli.main(common) == 0  # 8 cubes: the cache holds every prefix
    hit = capsys.readouterr().out
    assert cli.main([*common, "--set", "task.stack_size=5"]) == 0  # 5 cubes: no key is in the store
    miss = capsys.readouterr().out
    counts = {}
    for log in sorted((tmp_path / "runs").rglob("*.mcap")):
        sent = [q for q in read_topic(log, "/query") if q["queried"]]
        counts[read_info(log).config["task"]["stack_size"]] = (
            sum(q["source"] == "recorded" for q in sent), sum(q["source"] == "mock" for q in sent))
    stored, _ = counts[8]
    _, fallback = counts[5]
    assert counts[8][1] == 0 and counts[5][0] == 0 and stored > 0 and fallback > 0
    assert f"answers: {stored} from the store, none from a fallback (0.0% missed the store)" in hit
    assert f"answers: 0 from the store, {fallback} from the fallback mock (100.0% missed the store)" in miss


def test_digest_ignores_policy_fields_at_their_defaults() -> None:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream")
    data = json.loads(config.to_json())
    old = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for name in cfg.POLICY_DEFAULTS:
        del old["secondary"][name]  # a configuration logged before the fields existed
    assert cfg.config_digest(old) == cfg.config_digest(data) == config.digest()
    other = cfg.load("cube-stacking", "lagr-seq", "upstream", None, ['secondary.policy="thompson"'])
    assert other.digest() != config.digest()
    # and a log without the fields is resumable by a run that has them at their defaults
    from lagrseq.running.runner import _differences

    assert _differences(json.loads(cfg.from_dict(old).to_json()), data) == []


def test_a_frontier_point_names_its_reask_decay_only_when_set() -> None:
    from lagrseq.analysis.frontier import _knob_value, policy_of

    def point(*sets: str) -> dict:
        return json.loads(cfg.load("cube-stacking", "lagr-seq", "paper", None, ['secondary.policy="advance"', *sets]).to_json())

    assert policy_of(point()) == policy_of(point("secondary.reask_decay=0")) == ("advance", "stall 64")
    assert policy_of(point("secondary.reask_decay=0.5")) == ("advance", "stall 64 reask 0.5")
    # a curve of advance variants is ordered by the swept value
    assert _knob_value(point("secondary.reask_decay=0.25")) < _knob_value(point("secondary.reask_decay=0.75"))
