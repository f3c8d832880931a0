"""Suite items from runs: matching logs to the runs an item lists, and the builders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lagrseq.analysis import items, loading
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


def _grid_like_run(name: str, episodes: list[list[tuple[int, float]]]) -> Run:
    """A run shaped like a DQN grid task's: episodes of varying length, a step budget."""
    rows = []
    for trial, trial_episodes in enumerate(episodes):
        for index, (end, ret) in enumerate(trial_episodes):
            rows.append({"trial": trial, "episode": index, "return": ret, "global_step": end})
    frame = pd.DataFrame.from_records(rows, columns=list(EPISODE_COLUMNS))
    key = RunKey("image-completion", name, "upstream", "mock", 0, "deadbeef")
    return Run(
        key,
        {},
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
    assert np.isnan(at.loc[3, "mean"])  # nobody has finished an episode yet
    assert built.axes is not None and built.axes.get_xlabel() == "Environment steps"


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
    assert table.columns == ("τ", "LaGR-SEQ", "LaGR", "paper: LaGR-SEQ", "paper: LaGR")
    (row,) = table.rows
    assert row[0] == "0" and row[3] == "126 ± 2.94" and row[4] == "—"
    assert table.data["mean"].tolist()[0] == pytest.approx(np.mean(totals))
    # the same run gets the same bootstrap interval in both tables
    assert table.data.loc[0, "ci_low"] == bars.tables[0][1].data.loc[0, "ci_low"]


def test_ratio_table_pairs_trials(logs: loading.Logs) -> None:
    top = _spec(label="a", row="8", column="LaGR-SEQ")
    bottom = _spec(label="b", method="baseline", row="8", column="Q-learning")
    item = _item("ratio-table", top, bottom, numerator="LaGR-SEQ", denominator="Q-learning")
    matched = items.match(item, logs.runs, "mock")
    built = items.build_ratio_table(item, matched)
    ((_, table),) = built.tables
    a, b = matched[0].run, matched[1].run
    assert a is not None and b is not None
    ra, rb = a.total_per_trial("return"), b.total_per_trial("return")
    expected = np.mean([ra[t] / rb[t] for t in ra])
    assert table.data.loc[0, "ratio_mean"] == pytest.approx(expected)


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
