"""What a suite run on a recorded store does with a query the store lacks (``on_miss``), the miss
share the report shows beside every number made on a store, and a suite started outside the
clone finding the recorded answers it needs."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.analysis.loading import load
from lagrseq.analysis.replay import replay
from lagrseq.errors import ConfigError
from lagrseq.running import wiring
from lagrseq.study import reproduce
from lagrseq.suite import load_suite

ROOT = Path(__file__).resolve().parents[1]
SMOLLM2 = "recorded_llm/smollm2-135m-cube-t0.jsonl"
"""SmolLM2-135M's answers to the 8 prefixes of the cube target (20 each): never right."""
SMOLLM2_SET = '["llm.temperature=0.0", "llm.model=SmolLM2-135M-Instruct"]'


def test_every_recorded_store_run_of_the_packaged_suite_declares_on_miss_and_the_plan_applies_it(tmp_path: Path) -> None:
    suite = load_suite()
    recorded = [
        (item.id, spec) for item in suite.items for spec in item.runs
        if spec.provider is not None and wiring.provider_kind(spec.provider).replays
    ]
    assert {item for item, _ in recorded} >= {"fig4", "table2", "table3"}
    undeclared = [f"{item}: {spec.label}" for item, spec in recorded if spec.on_miss is None]
    assert not undeclared, undeclared
    # SmolLM2 on images is never right: a refused miss is its faithful stand-in (Table 3)
    assert {spec.on_miss for item, spec in recorded if item == "table3"} == {"refuse"}
    for quick in (True, False):
        plan = reproduce.plan(suite, quick=quick, provider=None, runs_dir=tmp_path, seed=0)
        on_stores = [run for run in plan.runs if wiring.provider_kind(run.provider).replays]
        assert {run.kind for run in on_stores} == {"trial", "accuracy"}  # Table 2's cube runs, Fig. 4's probes
        for run in on_stores:
            wanted = {spec.on_miss for item, spec in recorded if item in run.items and spec.provider == run.provider}
            assert run.options is not None and {run.options.on_miss} == wanted, run.path
    # runs off a store keep their provider's defaults; the authors' answers still fall back to the mock
    plan = reproduce.plan(suite, quick=True, provider=None, runs_dir=tmp_path, seed=0)
    assert all(run.options is None for run in plan.runs if not wiring.provider_kind(run.provider).replays)
    authors = f"recorded:{tmp_path / 'authors-answers'}"
    spec = next(spec for item in suite.items for spec in item.runs if spec.on_miss is None)
    assert reproduce.run_options(spec, authors).on_miss == "mock"
    # a recorded-GPT row that says what answers the misses (Table 3's three rows) is run so
    assert reproduce.run_options(replace(spec, on_miss="calibrated"), authors).on_miss == "calibrated"


def test_two_items_sharing_a_run_must_agree_on_what_a_miss_does(tmp_path: Path) -> None:
    item = """
[[items]]
id = "{id}"
title = "{id}"
render = "query-table"
task = "cube-stacking"
preset = "upstream"

[[items.runs]]
label = "LaGR"
method = "lagr"
provider = "recorded:{store}"
on_miss = "{on_miss}"
set = {set}
"""
    text = '[suite]\nprovider = "mock"\n' + "".join(
        item.format(id=name, store=ROOT / SMOLLM2, on_miss=on_miss, set=SMOLLM2_SET) for name, on_miss in (("a", "refuse"), ("b", "mock"))
    )
    (tmp_path / "suite.toml").write_text(text)
    with pytest.raises(ConfigError, match=r"^suite item 'b': run 'LaGR' is the same run as item 'a''s .*on_miss = mock vs on_miss = refuse.*give both the same on_miss$"):
        reproduce.plan(load_suite(tmp_path / "suite.toml"), quick=True, provider=None, runs_dir=tmp_path / "runs", seed=0)


def _part_of_the_store(path: Path, keep: int) -> None:
    """SmolLM2's cube answers for the first ``keep`` of its 8 prompts only."""
    lines = (ROOT / SMOLLM2).read_text(encoding="utf-8").splitlines(keepends=True)
    keys: list[str] = []
    for line in lines:
        key = json.loads(line)["key"]
        if key not in keys:
            keys.append(key)
    path.write_text("".join(line for line in lines if json.loads(line)["key"] in keys[:keep]), encoding="utf-8")


TABLE_SUITE = """
[suite]
provider = "mock"

[[items]]
id = "queries"
title = "Queries"
render = "query-table"
row_header = "store"
task = "cube-stacking"
preset = "upstream"
trials = 3
episodes = 20
reference = {{ "part|LaGR" = "100 ± 10" }}

[[items.runs]]
label = "LaGR, part of SmolLM2's answers"
row = "part"
column = "LaGR"
method = "lagr"
provider = "recorded:{store}"
on_miss = "refuse"
set = {set}
"""


def test_a_table_made_on_a_store_that_lacks_prompts_shows_the_refused_misses(tmp_path: Path) -> None:
    store = tmp_path / "part.jsonl"
    _part_of_the_store(store, keep=4)
    (tmp_path / "suite.toml").write_text(TABLE_SUITE.format(store=store, set=SMOLLM2_SET))
    suite = load_suite(tmp_path / "suite.toml")
    plan = reproduce.plan(suite, quick=False, provider=None, runs_dir=tmp_path / "runs", seed=0)
    (run,) = plan.runs
    assert run.options.on_miss == "refuse"
    reproduce.execute(plan, jobs=1)  # error (the default) would stop at the first prompt the store lacks

    queries = load([tmp_path / "runs"]).runs[0].queries
    asked = queries[queries["queried"].astype(bool)]
    refused = int((asked["source"] == "miss").sum())
    assert 0 < refused < len(asked) and not asked[asked["source"] == "miss"]["accepted"].astype(bool).any()
    share = f"{100 * refused / len(asked):.1f}%"
    shown = f"misses: {refused} of {len(asked)} answers ({share}), refused (counted as wrong answers)"

    first = replay([tmp_path / "runs"], tmp_path / "report", suite=suite)
    table = (first.out / "tables" / "queries.md").read_text(encoding="utf-8")
    assert shown in table  # beside the number, in its cell
    scoreboard = (first.out / "scoreboard.md").read_text(encoding="utf-8")
    assert shown in scoreboard and f"(refused misses: {refused} of {len(asked)})" in scoreboard  # and in its provenance
    index = (first.out / "index.md").read_text(encoding="utf-8")
    assert f"LaGR, part of SmolLM2's answers [{shown}]" in index
    row = next(r for r in _csv(first.out / "tables" / "scoreboard.csv") if r["item"] == "queries")
    assert (int(row["answers"]), int(row["misses"]), row["misses_answered_by"]) == (len(asked), refused, "refused")
    assert float(row["miss_share"]) == pytest.approx(refused / len(asked), rel=1e-5)
    assert shown in row["provenance_why"]
    # a frontier point on the store says the same, in the same words
    from lagrseq.analysis import frontier

    points = frontier.points_of(load([tmp_path / "runs"]).runs, None)
    board = frontier.table(points)
    cell = board.rows[0][board.columns.index("store misses (refused, or answered by a fallback)")]
    assert cell == f"misses: {refused} of {len(asked)} answers ({share}), refused"
    # replay stays byte for byte: the same logs give the same tables
    again = replay([tmp_path / "runs"], tmp_path / "again", suite=suite)
    for name in ("tables/queries.md", "tables/queries.csv", "tables/scoreboard.csv", "scoreboard.md", "index.md"):
        assert (first.out / name).read_bytes() == (again.out / name).read_bytes(), name


def _csv(path: Path) -> list[dict[str, str]]:
    import csv
    import io

    return list(csv.DictReader(io.StringIO(path.read_text(encoding="utf-8"))))


ELSEWHERE_SUITE = f"""
[suite]
provider = "mock"

[[items]]
id = "open-llm"
title = "SmolLM2's recorded answers, from another directory"
render = "query-table"
row_header = "τ"
task = "cube-stacking"
preset = "upstream"
trials = 1
episodes = 5
on_miss = "refuse"

[[items.runs]]
label = "LaGR, SmolLM2-135M (recorded)"
row = "0"
column = "LaGR"
method = "lagr"
provider = "recorded:{SMOLLM2}"
set = {SMOLLM2_SET}

[[items.runs]]
label = "LaGR, mock"
row = "0"
column = "LaGR (mock)"
method = "lagr"
provider = "mock"
"""


def test_a_suite_started_in_another_directory_finds_the_recorded_answers_and_writes_no_absolute_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The packaged suite's ``recorded:recorded_llm/...`` paths, with the current directory outside
    the clone: read from the source checkout (editable install), written as given."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "suite.toml").write_text(ELSEWHERE_SUITE)
    monkeypatch.chdir(elsewhere)
    assert not (elsewhere / SMOLLM2).exists()
    said: list[str] = []
    report = reproduce.reproduce(
        reproduce.Request(Path("suite.toml"), None, True, None, Path("out"), 1), reproduce.Reporter(said.append, quiet=True)
    ).report
    runs = load([elsewhere / "out" / "runs"]).runs
    recorded = next(run for run in runs if run.key.provider.startswith("recorded:"))
    assert recorded.key.provider == f"recorded:{SMOLLM2}"  # as written, not where it was found
    table = (report.out / "tables" / "open-llm.md").read_text(encoding="utf-8")
    assert "not run" not in table and "misses: 0 of " in table
    for path in sorted((elsewhere / "out" / "reports").rglob("*")):
        if path.is_file() and path.suffix in (".md", ".html", ".csv", ".svg", ".json", ".txt"):
            text = path.read_text(encoding="utf-8", errors="replace")
            for absolute in (str(tmp_path), str(ROOT)):
                assert absolute not in text, (path.name, absolute)
    assert not any("not run" in line for line in said), said


def test_a_recorded_file_found_nowhere_is_one_line_naming_the_item_and_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A non-editable install (no recorded_llm/ beside the package) started outside a clone."""
    (tmp_path / "suite.toml").write_text(ELSEWHERE_SUITE)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(wiring, "source_checkout", lambda: tmp_path / "site-packages")
    plan = reproduce.plan(load_suite(tmp_path / "suite.toml"), quick=True, provider=None, runs_dir=tmp_path / "runs", seed=0)
    line = plan.set_aside["open-llm"]
    assert "\n" not in line and line.startswith("1 of 2 runs not run: ")
    assert line == (
        f"1 of 2 runs not run: recorded answers not found here or in a lagrseq source checkout: {SMOLLM2} (a non-editable "
        "install ships no recorded_llm/: run from a clone of the repository, or copy its recorded_llm/ folder into this directory)"
    )
    assert [run.provider for run in plan.runs] == ["mock"]  # the item's other run still runs


def test_the_open_model_screens_are_found_from_another_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from lagrseq import paths
    from lagrseq.study import screen

    if not list(ROOT.glob(screen.SCREEN_FILES)):
        pytest.skip("no screen files committed")
    monkeypatch.chdir(tmp_path)
    sections, line = screen.report_sections()
    assert sections and line.startswith("open models: ") and "not made" not in line
    monkeypatch.setattr(paths, "source_checkout", lambda: tmp_path / "site-packages")
    none, why = screen.report_sections()
    assert none == [] and "\n" not in why
    assert why.startswith("open models: not made: no recorded_llm/screen-*.jsonl here or in a lagrseq source checkout")
    assert str(tmp_path) not in why


def test_an_accuracy_probe_refuses_a_prefix_its_store_lacks(tmp_path: Path) -> None:
    """Fixed prefixes, not a learner's path: a miss is a prefix nobody recorded, and on_miss
    answers it there as in a trial (a refusal counts as a wrong answer)."""
    from lagrseq.study import probe

    store = tmp_path / "part.jsonl"
    _part_of_the_store(store, keep=6)
    spec = f"recorded:{store}"
    config = cfg.load("cube-stacking", "lagr", "upstream", None, ["llm.temperature=0.0", "llm.model=SmolLM2-135M-Instruct"])
    options = wiring.provider_options(spec, {"on_miss": "refuse"})
    probe.run_accuracy_probe(config, 2, 0, spec, tmp_path / "probe.mcap", provider_options=options)
    (run,) = load([tmp_path]).runs
    sources = run.queries["source"].tolist()
    assert len(sources) == 16 and sources.count("miss") == 4 and sources.count("recorded") == 12
    from lagrseq.logs.reader import read_info

    assert json.loads(read_info(tmp_path / "probe.mcap").run["provider_options"])["on_miss"] == "refuse"
