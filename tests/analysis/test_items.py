"""Suite items from runs: matching logs to the runs an item lists, and the builders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lagrseq.analysis import inference, items, loading
from lagrseq.analysis.loading import EPISODE_COLUMNS, QUERY_COLUMNS, Run, RunKey
from lagrseq.suite import Item, RunSpec, load_suite


def _spec(**kw: object) -> RunSpec:
    base: dict[str, object] = {
        "label": "LaGR-SEQ ({provider})",
        "task": "cube-stacking",
        "method": "lagr-seq",
        "preset": "upstream",
        "provider": None,
    }
    base.update(kw)
    return RunSpec(**base)  # type: ignore[arg-type]


def _item(render: str, *runs: RunSpec, **options: object) -> Item:
    return Item(id="x", title="X", render=render, runs=runs, options=options)


@pytest.fixture(scope="module")
def logs(runs_dir: Path) -> loading.Logs:
    return loading.load([runs_dir])


def test_match_ignores_run_length_but_not_configuration(logs: loading.Logs) -> None:
    # The logs have 20 episodes; the suite asks for 100 (full) or 100 (quick): still a match.
    same = _spec(episodes=100, quick_episodes=100)
    hotter = _spec(overrides=("llm.temperature=0.5",))
    (found, missing) = items.match(_item("returns", same, hotter), logs.runs, "mock")
    assert found.run is not None and found.run.key.method == "lagr-seq"
    assert found.label == "LaGR-SEQ (mock)"
    assert missing.run is None and "--set llm.temperature=0.5" in missing.reason


def test_match_says_why_a_task_or_provider_is_missing(logs: loading.Logs) -> None:
    grid = _spec(task="tower-of-hanoi")
    profile = _spec(provider="mock:gpt4-tau0")
    found = items.match(
        _item("returns", grid, profile),
        logs.runs,
        "mock",
        unavailable={"mock:gpt4-tau0": "provider not available: unknown provider"},
    )
    assert [m.reason for m in found] == [
        "task tower-of-hanoi not available",
        "provider not available: unknown provider",
    ]


def test_match_respects_a_fixed_provider(logs: loading.Logs) -> None:
    (m,) = items.match(_item("returns", _spec()), logs.runs, "mock", provider="recorded:x")
    assert m.run is None and "--provider recorded:x" in m.reason


def test_returns_by_episode(logs: loading.Logs) -> None:
    matched = items.match(
        _item("returns", _spec(), _spec(label="Q", method="baseline")), logs.runs, "mock"
    )
    built = items.build_returns(_item("returns", *[m.spec for m in matched]), matched)
    data = built.figure_data
    assert data is not None and set(data["series"]) == {"LaGR-SEQ (mock)", "Q"}
    run = matched[0].run
    assert run is not None
    by_episode = run.episodes.groupby("episode")["return"].mean().to_numpy()
    series = data[data["series"] == "LaGR-SEQ (mock)"]
    assert np.allclose(series["mean"].to_numpy(), by_episode)
    assert series["episode"].tolist() == list(range(1, run.episodes_per_trial + 1))
    assert built.axes is not None and len(built.axes.get_lines()) == 2


def _grid_like_run(
    name: str, episodes: list[list[tuple[int, float]]], max_steps: int = 0, unsolved: set[tuple[int, int]] = frozenset()  # type: ignore[assignment]
) -> Run:
    """A run shaped like a DQN grid task's: episodes of varying length, a step budget
    (``max_steps``; 0: none). Every episode is solved except the (trial, episode) in ``unsolved``."""
    rows = []
    for trial, trial_episodes in enumerate(episodes):
        for index, (end, ret) in enumerate(trial_episodes):
            solved = (trial, index) not in unsolved
            rows.append({"trial": trial, "episode": index, "return": ret, "global_step": end, "solved": solved})
    frame = pd.DataFrame.from_records(rows, columns=list(EPISODE_COLUMNS))
    key = RunKey("image-completion", name, "upstream", "mock", 0, "deadbeef")
    return Run(
        key,
        {"run": {"max_steps": max_steps}} if max_steps else {},
        (),
        tuple(range(len(episodes))),
        frame,
        pd.DataFrame(columns=list(QUERY_COLUMNS)),
        0,
    )


def test_returns_by_environment_step_work_for_any_task() -> None:
    run = _grid_like_run(
        "lagr-seq", [[(100, 1.0), (400, 3.0), (600, 5.0)], [(300, 2.0), (600, 4.0)]]
    )
    spec = _spec(task="image-completion")
    item = _item("returns", spec, x="global_step", window=2)
    built = items.build_returns(item, [items.Match(spec, "LaGR-SEQ", run)])
    data = built.figure_data
    assert data is not None
    at = data.set_index("global_step")
    # step 300: trial 0 has finished 1 episode (mean 1), trial 1 one episode (2) -> 1.5
    assert at.loc[300, "mean"] == pytest.approx(1.5)
    # step 600: trial 0 mean of last two (3, 5) = 4, trial 1 mean of (2, 4) = 3 -> 3.5
    assert at.loc[600, "mean"] == pytest.approx(3.5)
    # nobody has finished an episode yet: both trials count 0 (no trial is dropped)
    assert at.loc[3, "mean"] == 0.0 and at.loc[3, "trials"] == 2
    assert built.axes is not None and built.axes.get_xlabel() == "Environment steps"


def test_every_curve_point_averages_every_trial_including_one_without_a_finished_episode() -> None:
    """Trial 2 never finishes an episode within the budget (its only episode is cut off at 600,
    unsolved): it counts 0 at every point, and every point's ``trials`` is the run's 3."""
    run = _grid_like_run(
        "lagr-seq",
        [[(100, 6.0), (400, 6.0), (600, 6.0)], [(300, 3.0), (600, 3.0)], [(600, 2.0)]],
        max_steps=600,
        unsolved={(2, 0)},
    )
    spec = _spec(task="image-completion")
    built = items.build_returns(_item("returns", spec, x="global_step", window=1), [items.Match(spec, "LaGR-SEQ", run)])
    data = built.figure_data
    assert data is not None
    assert (data["trials"] == 3).all()
    at = data.set_index("global_step")
    assert at.loc[102, "mean"] == pytest.approx((6.0 + 0.0 + 0.0) / 3)  # not 6.0: survivors only (grid: every 3 steps)
    assert at.loc[300, "mean"] == pytest.approx((6.0 + 3.0 + 0.0) / 3)
    assert at.loc[600, "mean"] == pytest.approx((6.0 + 3.0 + 0.0) / 3)  # the cut-off 2.0 is not an episode
    assert data["provenance"].unique().tolist() == ["rule-based mock"]


def test_an_episode_cut_off_by_the_step_budget_makes_no_dip_at_the_last_point() -> None:
    """The last episode of each trial is cut off by the 1000-step budget with a partial return
    (1.0 against 5.0 for whole ones): counted as a finished episode it would pull the last point
    down; a solved last episode at the budget still counts."""
    episodes = [[(200, 5.0), (400, 5.0), (600, 5.0), (800, 5.0), (1000, 1.0)] for _ in range(2)]
    cut = _grid_like_run("lagr-seq", episodes, max_steps=1000, unsolved={(0, 4), (1, 4)})
    spec = _spec(task="image-completion")
    built = items.build_returns(_item("returns", spec, x="global_step", window=3), [items.Match(spec, "LaGR-SEQ", cut)])
    assert built.figure_data is not None
    means = built.figure_data.set_index("global_step")["mean"]
    assert means.loc[1000] == pytest.approx(5.0) and means.loc[800] == pytest.approx(5.0)
    solved = _grid_like_run("lagr-seq", episodes, max_steps=1000)  # every episode solved: all count
    again = items.build_returns(_item("returns", spec, x="global_step", window=3), [items.Match(spec, "LaGR-SEQ", solved)])
    assert again.figure_data is not None
    assert again.figure_data.set_index("global_step")["mean"].loc[1000] == pytest.approx((5.0 + 5.0 + 1.0) / 3)


def test_query_bars_and_table(logs: loading.Logs) -> None:
    seq = _spec(label="LaGR-SEQ", row="0", column="LaGR-SEQ")
    lagr = _spec(label="LaGR", method="lagr", row="0", column="LaGR")
    matched = items.match(_item("query-bars", seq, lagr), logs.runs, "mock")
    bars = items.build_query_bars(_item("query-bars", seq, lagr), matched)
    ((_, table),) = bars.tables
    run = matched[0].run
    assert run is not None
    totals = list(run.total_per_trial("queries").values())
    assert table.data.loc[0, "mean"] == pytest.approx(np.mean(totals))
    assert table.data.loc[0, "se"] == pytest.approx(np.std(totals, ddof=1) / np.sqrt(len(totals)))

    item = _item("query-table", seq, lagr, row_header="τ", reference={"0|LaGR-SEQ": "126 ± 2.94"})
    built = items.build_query_table(item, matched)
    ((_, table),) = built.tables
    assert table.columns == ("τ", "made by", "LaGR-SEQ", "LaGR", "paper: LaGR-SEQ", "paper: LaGR")
    (row,) = table.rows
    assert row[0] == "0" and row[1] == "rule-based mock" and row[4] == "126 ± 2.94" and row[5] == "—"
    assert all(f"(n={len(totals)})" in cell for cell in row[2:4])  # every cell shows n
    assert table.data["mean"].tolist()[0] == pytest.approx(np.mean(totals))
    # the same run gets the same interval in both tables: the modified Cox interval from the logs
    # (a count's interval never reaches below 0), not a bootstrap
    assert table.data.loc[0, "ci_low"] == bars.tables[0][1].data.loc[0, "ci_low"]
    t = inference.positive_mean_interval(totals)
    assert (table.data.loc[0, "ci_low"], table.data.loc[0, "ci_high"]) == pytest.approx((t.low, t.high))
    assert 0 < t.low < np.mean(totals) < t.high


def test_ratio_table_pairs_trials(logs: loading.Logs) -> None:
    """The main ratio is the item's numerator (here LaGR, as the paper's stack-size caption
    defines it) over Q-learning, read back from the logged runs; every other column's ratio
    (LaGR-SEQ) stands beside it, labelled, over the same Q-learning trials."""
    seq = _spec(label="s", row="8", column="LaGR-SEQ")
    lagr = _spec(label="a", method="lagr", row="8", column="LaGR")
    bottom = _spec(label="b", method="baseline", row="8", column="Q-learning")
    item = _item("ratio-table", seq, lagr, bottom, numerator="LaGR", denominator="Q-learning")
    matched = items.match(item, logs.runs, "mock")
    built = items.build_ratio_table(item, matched)
    ((_, table),) = built.tables
    s, a, b = matched[0].run, matched[1].run, matched[2].run
    assert s is not None and a is not None and b is not None
    assert (s.key.method, a.key.method, b.key.method) == ("lagr-seq", "lagr", "baseline")
    rs, ra, rb = s.total_per_trial("return"), a.total_per_trial("return"), b.total_per_trial("return")
    assert table.columns[2] == "performance ratio LaGR / Q-learning (mean ± s.e.)"
    assert table.columns[3] == "LaGR-SEQ / Q-learning (mean ± s.e.)"
    data = table.data.set_index("ratio")
    assert bool(data.loc["LaGR / Q-learning", "main"]) and not bool(data.loc["LaGR-SEQ / Q-learning", "main"])
    assert data.loc["LaGR / Q-learning", "ratio_mean"] == pytest.approx(np.mean([ra[t] / rb[t] for t in ra]))
    assert data.loc["LaGR-SEQ / Q-learning", "ratio_mean"] == pytest.approx(np.mean([rs[t] / rb[t] for t in rs]))
    (row,) = table.rows
    assert row[1] == "rule-based mock" and f"(n={len(ra)})" in row[2]


def test_accuracy_counts_exact_answers_per_prefix(logs: loading.Logs) -> None:
    spec = _spec(
        label="{provider}, τ=1", kind="accuracy", method="lagr", overrides=("llm.temperature=1.0",)
    )
    matched = items.match(_item("accuracy", spec), logs.runs, "mock")
    built = items.build_accuracy(_item("accuracy", spec), matched)
    data = built.figure_data
    assert data is not None
    assert data["prefix_length"].tolist() == list(range(1, 9))
    assert data["answers"].tolist() == [5] * 8
    run = matched[0].run
    assert run is not None
    queries = run.queries
    for _, row in data.iterrows():
        answers = queries[queries["prefix_length"] == row["prefix_length"]]
        assert row["correct"] == int(answers["accepted"].sum())
    assert data["fraction"].tolist() == [k / 8 for k in range(1, 9)]


def test_every_packaged_item_has_a_builder() -> None:
    suite = load_suite()
    assert {item.render for item in suite.items} <= set(items.BUILDERS)


def test_config_table_reads_each_runs_configuration(logs: loading.Logs) -> None:
    seq = _spec(label="SEQ")
    base = _spec(label="Q", method="baseline")
    matched = items.match(_item("config-table", seq, base), logs.runs, "mock")
    built = items.build_config_table(_item("config-table", seq, base), matched)
    ((_, table),) = built.tables
    rows = {row[0]: row[1:] for row in table.rows}
    assert rows["env.horizon"] == ("50", "50")
    assert rows["method *"] == ('"lagr-seq"', '"baseline"')
    assert rows["run.episodes"] == ("20", "20")
    data = table.data.set_index("field")
    assert bool(data.loc["method", "differs"]) and not bool(data.loc["env.horizon", "differs"])


def _recorded_run(first_sources: list[str], max_steps: int) -> Run:
    """A run on the authors' answers: trial k's first accepted answer came from
    ``first_sources[k]`` (``recorded`` or the fallback ``mock``), after one refused recorded one."""
    episodes = pd.DataFrame.from_records(
        [{"trial": k, "episode": 0, "return": 1.0, "queries": 2, "global_step": max_steps, "solved": False} for k in range(len(first_sources))],
        columns=list(EPISODE_COLUMNS),
    )
    queries = []
    for k, source in enumerate(first_sources):
        queries.append({"trial": k, "episode": 0, "step": 1, "global_step": 1, "queried": True, "accepted": False, "source": "recorded"})
        queries.append({"trial": k, "episode": 0, "step": 5, "global_step": 5, "queried": True, "accepted": True, "source": source})
        queries.append({"trial": k, "episode": 0, "step": 9, "global_step": 9, "queried": True, "accepted": True, "source": "recorded"})
    key = RunKey("image-completion", "lagr-seq", "upstream", "recorded:/out/authors-answers", 0, "cafe")
    frame = pd.DataFrame.from_records(queries, columns=list(QUERY_COLUMNS))
    return Run(key, {"run": {"max_steps": max_steps}}, (), tuple(range(len(first_sources))), episodes, frame, 0)


def test_a_row_on_the_authors_answers_counts_fallback_decided_trials_and_says_when_it_is_short() -> None:
    run = _recorded_run(["mock", "recorded", "mock", "recorded", "recorded"], max_steps=2000)
    assert items.fallback_decided(run) == (2, 5)
    spec = _spec(task="image-completion", provider="recorded:/out/authors-answers", trials=10, quick_trials=5, quick_max_steps=2000)
    (m,) = items.match(_item("returns", spec), [run], "mock")
    assert m.run is run
    assert "first accepted answer from the fallback in 2/5 trials" in m.note
    assert "misses: 2 of 15 answers (13.3%), answered by the mock fallback, which can be right" in m.note
    # the quick length is named against the paper's (the preset's 10,001 steps, 10 trials)
    assert m.note.startswith("shorter than the full suite: 5 trials × 2000 steps (full: 10 trials × 10001 steps)")
    assert m.note in m.label


def test_a_last_episode_that_reached_its_horizon_at_the_budget_is_a_finished_one() -> None:
    """Budget 200, horizon 50: trial 0's fourth episode ran its full 50 steps and ends at 200
    unsolved on its own (kept); trial 1's last episode was cut after 20 steps (left out)."""
    rows = []
    for trial, episodes in enumerate([[(50, 50, 1.0), (100, 50, 1.0), (150, 50, 1.0), (200, 50, 3.0)], [(90, 90, 2.0), (180, 50, 2.0), (200, 20, 0.0)]]):
        for index, (end, length, ret) in enumerate(episodes):
            rows.append({"trial": trial, "episode": index, "return": ret, "global_step": end, "length": length, "solved": False})
    frame = pd.DataFrame.from_records(rows, columns=list(EPISODE_COLUMNS))
    key = RunKey("object-arrangement", "baseline", "upstream", "mock", 0, "feed")
    run = Run(key, {"run": {"max_steps": 200}, "env": {"horizon": 50}}, (), (0, 1), frame, pd.DataFrame(columns=list(QUERY_COLUMNS)), 0)
    spec = _spec(task="object-arrangement", method="baseline")
    built = items.build_returns(_item("returns", spec, x="global_step", window=1), [items.Match(spec, "DQN", run)])
    assert built.figure_data is not None
    at = built.figure_data.set_index("global_step")
    assert at.loc[200, "mean"] == pytest.approx((3.0 + 2.0) / 2) and at.loc[200, "trials"] == 2
    # without a configured horizon, the longest unsolved episode that was not a trial's last (90) stands for it
    no_horizon = Run(key, {"run": {"max_steps": 200}}, (), (0, 1), frame, pd.DataFrame(columns=list(QUERY_COLUMNS)), 0)
    assert items._episode_horizon(no_horizon) == 90
