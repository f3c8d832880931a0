"""The paper suite as data: loading, inheritance, checks, matching."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq.errors import ConfigError
from lagrseq.suite import load_suite, matches

SUITE = """
[suite]
seed = 3
provider = "mock"

[[items]]
id = "t"
title = "T"
render = "query-table"
task = "cube-stacking"
preset = "upstream"
trials = 4
episodes = 30
quick_trials = 2
set = ["env.horizon=20"]

[[items.runs]]
label = "a"
method = "lagr-seq"
set = ["llm.temperature=0.5"]
row = "0.5"
column = "SEQ"

[[items.runs]]
label = "b"
method = "baseline"
provider = "mock"
quick_episodes = 5
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "suite.toml"
    path.write_text(text)
    return path


def test_runs_inherit_item_defaults(tmp_path: Path) -> None:
    suite = load_suite(_write(tmp_path, SUITE))
    assert (suite.seed, suite.provider) == (3, "mock")
    a, b = suite.items[0].runs
    assert a.overrides == ("env.horizon=20", "llm.temperature=0.5")
    assert (a.trials, a.episodes, a.quick_trials, a.quick_episodes) == (4, 30, 2, 30)
    assert (b.quick_episodes, b.provider, a.provider) == (5, "mock", None)
    assert (a.row, a.column) == ("0.5", "SEQ")
    config = a.resolve(quick=True)
    assert (config.env.horizon, config.llm.temperature, config.run.episodes) == (20, 0.5, 30)
    assert b.resolve(quick=True).run.episodes == 5


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (('render = "query-table"', 'render = "pie"'), "render = 'pie'"),
        (('label = "a"', 'label = "a"\nbogus = 1'), "unknown key 'bogus'"),
        (("trials = 4", 'trials = "four"'), "trials = 'four'; expected an integer in \\[1, 100000\\]"),
        (('method = "lagr-seq"', 'method = "dqn"'), "method = 'dqn'"),
        (('set = ["env.horizon=20"]', 'set = ["run.episodes=20"]'), "give run.episodes"),
        # values of the right type that make no sense, and values of the wrong shape
        (("trials = 4", "trials = 0"), "trials = 0; expected an integer in \\[1, 100000\\]"),
        (("quick_trials = 2", "quick_trials = -2"), "quick_trials = -2; expected an integer in \\[1, 100000\\]"),
        (("episodes = 30", "episodes = -1"), "episodes = -1; expected an integer >= 0"),
        (("quick_episodes = 5", "quick_episodes = 5\nsamples = 0"), "samples = 0; expected an integer >= 1"),
        (("trials = 4", "trials = 99999999999999999999"), "expected an integer in \\[1, 100000\\]"),
        (("seed = 3", "seed = -1"), "seed = -1; expected an integer in \\[0, 9223372036854775807\\]"),
        (('provider = "mock"', "provider = 3"), "provider = 3; expected a provider spec"),
        (('set = ["env.horizon=20"]', 'set = "env.horizon=20"'), "set = 'env.horizon=20'; expected a list of"),
        (('label = "a"', "label = 1"), "label = 1; expected a string"),
        (('render = "query-table"', 'render = "query-table"\nwindow = 0'), "window = 0; expected an integer >= 1"),
        (('render = "query-table"', 'render = "query-table"\nx = "time"'), "x = 'time'; expected one of episode, global_step"),
        (('render = "query-table"', 'render = "query-table"\nreference = 3'), "reference = 3; expected a table"),
        (('[suite]\nseed = 3\nprovider = "mock"', "suite = 3"), "suite = 3; expected a table of keys"),
        (("[[items]]", "[extra]\n[[items]]"), "unknown section \\[extra\\]"),
    ],
)
def test_bad_suites_give_one_line(tmp_path: Path, edit: tuple[str, str], message: str) -> None:
    text = SUITE.replace(*edit, 1)
    assert text != SUITE
    with pytest.raises(ConfigError, match=message) as info:
        load_suite(_write(tmp_path, text))
    assert "\n" not in str(info.value)


ON_MISS_SUITE = """
[suite]
provider = "mock"

[[items]]
id = "t"
title = "T"
render = "query-table"
task = "cube-stacking"
preset = "upstream"
on_miss = "refuse"

[[items.runs]]
label = "on the store, inherited"
method = "lagr"
provider = "recorded:store.jsonl"

[[items.runs]]
label = "on the store, its own"
method = "lagr-seq"
provider = "recorded:store.jsonl"
on_miss = "mock"

[[items.runs]]
label = "the mock: an inherited on_miss does not apply"
method = "lagr"
provider = "mock"

[[items.runs]]
label = "the suite's default provider (reproduce --provider may make it a store)"
method = "lagr-seq"
"""


def test_on_miss_is_a_run_key_an_item_passes_to_its_store_runs(tmp_path: Path) -> None:
    inherited, own, mocked, default = load_suite(_write(tmp_path, ON_MISS_SUITE)).items[0].runs
    assert (inherited.on_miss, own.on_miss, mocked.on_miss, default.on_miss) == ("refuse", "mock", None, "refuse")
    plain = load_suite(_write(tmp_path, SUITE)).items[0].runs[0]
    assert plain.on_miss is None  # not declared: the provider's default (a miss stops the run)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (('on_miss = "mock"', 'on_miss = "ignore"'), "run 2: on_miss = 'ignore'; expected one of error, mock, live, refuse, calibrated$"),
        (('on_miss = "mock"', "on_miss = 1"), "on_miss = 1; expected one of error, mock, live, refuse, calibrated$"),
        (('on_miss = "refuse"', 'on_miss = "later"'), "run 1: on_miss = 'later'; expected one of"),
        (
            ('method = "lagr"\nprovider = "mock"', 'method = "lagr"\nprovider = "mock"\non_miss = "refuse"'),
            "run 3: on_miss = 'refuse' with provider = 'mock'; on_miss applies to recorded:STORE runs only",
        ),
    ],
)
def test_a_bad_on_miss_gives_one_line(tmp_path: Path, edit: tuple[str, str], message: str) -> None:
    text = ON_MISS_SUITE.replace(*edit, 1)
    assert text != ON_MISS_SUITE
    with pytest.raises(ConfigError, match=message) as info:
        load_suite(_write(tmp_path, text))
    assert "\n" not in str(info.value) and str(info.value).startswith("suite item 't', run ")


def test_items_and_runs_that_are_not_tables_give_one_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^items = 3; expected a list of tables"):
        load_suite(_write(tmp_path, "items = 3\n"))
    with pytest.raises(ConfigError, match=r"^items = \['a'\]; expected a list of tables"):
        load_suite(_write(tmp_path, 'items = ["a"]\n'))
    text = SUITE.split("[[items.runs]]")[0] + "runs = [1, 2]\n"
    with pytest.raises(ConfigError, match=r"items.runs of suite item 't' = \[1, 2\]; expected a list of tables"):
        load_suite(_write(tmp_path, text))


def test_select_keeps_suite_order_and_rejects_unknown_ids() -> None:
    suite = load_suite()
    picked = suite.select(["table2", "fig5a"])
    assert [i.id for i in picked.items] == ["fig5a", "table2"]
    with pytest.raises(ConfigError, match="unknown suite item 'fig9'"):
        suite.select(["fig9"])


def test_matching_ignores_run_length_and_unknown_fields() -> None:
    stored = {
        "method": "lagr",
        "llm": {"temperature": 0.0},
        "run": {"episodes": 20, "max_steps": 0},
    }
    wanted = {
        "method": "lagr",
        "llm": {"temperature": 0.0, "new_field": 1},
        "run": {"episodes": 100, "max_steps": 500},
    }
    assert matches(stored, wanted)
    assert not matches(stored, {**wanted, "llm": {"temperature": 1.0}})
    assert not matches(stored, {**wanted, "method": "lagr-seq"})


def test_packaged_suite_covers_the_papers_items() -> None:
    ids = {item.id for item in load_suite().items}
    assert {"fig4", "fig5a", "fig5b", "fig5c", "fig6a", "fig6b", "fig6c", "table2", "table3"} <= ids
    assert {
        "appendix-temperature",
        "appendix-llm-type",
        "appendix-stack-size",
        "appendix-seq",
        "appendix-extended-arrangement",
        "appendix-binary-reward",
    } <= ids


def test_suite_argument_takes_a_file_or_a_task_that_ships_a_suite(tmp_path: Path) -> None:
    from lagrseq.suite import suite_argument

    assert suite_argument(None) is None
    assert suite_argument(str(tmp_path / "mine.toml")) == tmp_path / "mine.toml"  # a file, even one still to be made
    with pytest.raises(ConfigError, match="ships no suite of its own"):
        suite_argument("cube-stacking")  # the paper's suite covers the built-in tasks
    with pytest.raises(ConfigError, match="no such suite file, and no task of that name"):
        suite_argument("no-such-suite")


def test_replay_without_a_suite_draws_the_papers_suite_only_for_logs_of_its_tasks() -> None:
    from lagrseq.suite import logged_tasks_suite

    paper = load_suite()
    chosen, notes = logged_tasks_suite({"cube-stacking"})
    assert chosen == paper and notes == ()
    # logs of a task the paper's suite does not run (a plugin's): one line, not one per item
    chosen, notes = logged_tasks_suite({"someone-elses-task"})
    assert chosen.items == () and len(notes) == 1
    assert f"the paper's suite ({len(paper.items)} items) left out" in notes[0] and "someone-elses-task" in notes[0]


def test_the_suite_format_page_names_every_key_and_renderer() -> None:
    """docs/suites.md is the format's reference: every item key, run key, renderer option and
    renderer the reader accepts is on it."""
    from lagrseq import suite

    page = (Path(__file__).resolve().parents[1] / "docs" / "suites.md").read_text(encoding="utf-8")
    names = {*suite._ITEM_KEYS, *suite._RUN_KEYS, *suite._OPTIONS, *suite.RENDERERS, *suite.KINDS, "seed", "provider"}
    assert sorted(n for n in names if f"`{n}`" not in page and f'"{n}"' not in page) == []


STOP_SUITE = """
[suite]
provider = "mock"

[[items]]
id = "f"
title = "F"
render = "frontier"
task = "cube-stacking"
preset = "paper"
trials = 30
quick_trials = 3
stop_at = "first_solve"
full_horizon_trials = 5
quick_full_horizon_trials = 1

[[items.runs]]
label = "never"
method = "baseline"

[[items.runs]]
label = "thompson"
method = "lagr-seq"
set = ["secondary.policy=\\"thompson\\""]
"""


def test_a_frontier_item_stops_its_trials_and_copies_its_runs_at_full_length(tmp_path: Path) -> None:
    """stop_at adds run.stop_at="first_solve" to every run of the item; with
    full_horizon_trials the runs are followed by one full-length copy each (K trials; quick: its
    own K, 0 none); a log matches the stopped run or the copy, never both."""
    never, thompson, never_full, thompson_full = load_suite(_write(tmp_path, STOP_SUITE)).items[0].runs
    assert thompson.overrides == ('secondary.policy="thompson"', 'run.stop_at="first_solve"')
    assert thompson_full.overrides == ('secondary.policy="thompson"',)
    assert [run.label for run in (never_full, thompson_full)] == ["never, full horizon", "thompson, full horizon"]
    assert [(run.trials, run.quick_trials, run.full_horizon) for run in (never, thompson, never_full, thompson_full)] == [
        (30, 3, False), (30, 3, False), (5, 1, True), (5, 1, True)
    ]
    stopped, full = thompson.resolved_dict(), thompson_full.resolved_dict()
    assert stopped["run"]["stop_at"] == "first_solve" and "stop_at" not in full["run"]  # left out at its default
    assert matches(stopped, stopped) and matches(full, full) and not matches(full, stopped) and not matches(stopped, full)
    default_quick = STOP_SUITE.replace("quick_full_horizon_trials = 1\n", "")
    assert load_suite(_write(tmp_path, default_quick)).items[0].runs[-1].quick_trials == 5  # the full K
    no_quick = STOP_SUITE.replace("quick_full_horizon_trials = 1", "quick_full_horizon_trials = 0")
    assert [run.length(True)[0] for run in load_suite(_write(tmp_path, no_quick)).items[0].runs] == [3, 3, 0, 0]
    stop_only = STOP_SUITE.replace("full_horizon_trials = 5\nquick_full_horizon_trials = 1\n", "")
    assert [run.label for run in load_suite(_write(tmp_path, stop_only)).items[0].runs] == ["never", "thompson"]


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (('render = "frontier"', 'render = "query-table"'), "stop_at applies to render = \"frontier\" items only: remove it$"),
        (('stop_at = "first_solve"', 'stop_at = "first_accepted"'), "stop_at = 'first_accepted'; expected \"first_solve\"$"),
        (('stop_at = "first_solve"', "stop_at = true"), "stop_at = True; expected \"first_solve\"$"),
        (('stop_at = "first_solve"\n', ""), "full_horizon_trials measures full-length trials beside trials stopped at the first solve; add stop_at"),
        (("full_horizon_trials = 5", "full_horizon_trials = -1"), "full_horizon_trials = -1; expected an integer in \\[0, 100000\\]$"),
        (("full_horizon_trials = 5", 'full_horizon_trials = "5"'), "full_horizon_trials = '5'; expected an integer in \\[0, 100000\\]$"),
        (("full_horizon_trials = 5", "full_horizon_trials = 100001"), "expected an integer in \\[0, 100000\\]$"),
        (("quick_full_horizon_trials = 1", "quick_full_horizon_trials = 1.5"), "quick_full_horizon_trials = 1.5; expected an integer"),
        (("quick_full_horizon_trials = 1", "quick_full_horizon_trials = false"), "quick_full_horizon_trials = False; expected an integer"),
        (("full_horizon_trials = 5", "full_horizon_trials = 0"), "quick_full_horizon_trials = 1 with full_horizon_trials = 0"),
        (('method = "baseline"', 'method = "baseline"\nset = ["run.stop_at=\\"first_solve\\""]'), "run 'never' sets run.stop_at and the item sets stop_at"),
        (('label = "never"', 'label = "never"\nstop_at = "first_solve"'), "run 1: unknown key 'stop_at'"),
    ],
)
def test_a_bad_stop_at_or_full_horizon_gives_one_line(tmp_path: Path, edit: tuple[str, str], message: str) -> None:
    text = STOP_SUITE.replace(*edit, 1)
    assert text != STOP_SUITE
    with pytest.raises(ConfigError, match=message) as info:
        load_suite(_write(tmp_path, text))
    assert "\n" not in str(info.value) and str(info.value).startswith("suite item 'f'")
