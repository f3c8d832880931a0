"""The authors' recorded GPT answers as a source of the suite (``reproduce --authors-caches``)."""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from lagrseq.errors import UsageError
from lagrseq.progress import Reporter
from lagrseq.study import authors
from lagrseq.suite import AUTHORS_STORE_NAME, is_authors_provider, load_suite, with_recorded
from tests.conftest import AUTHORS_CACHES
from tests.support.summaries import summarize

NAMES = {
    "cube_stacking_cache0.0.pkl": ("cube-stacking", 8),
    "cube_stacking_cache0.pkl": ("cube-stacking", 11),
    "image_completion_gpt4.pkl": ("image-completion", 0),
    "object_arrangement_gpt4.pkl": ("object-arrangement", 0),
}


def _caches() -> Path:
    if not all((AUTHORS_CACHES / name).is_file() for name in NAMES):
        pytest.skip(f"the authors' caches are not at {AUTHORS_CACHES} (the shared/ folder beside the repository)")
    return AUTHORS_CACHES


def test_caches_are_identified_by_content_not_name(tmp_path: Path) -> None:
    source = _caches()
    # A clone-like layout with the authors' own names, plus things that are not caches.
    layout = {
        "cube_stacking_cache0.0.pkl": "Cube_stacking/cache0.0",
        "cube_stacking_cache0.pkl": "Cube_stacking/cache0",
        "image_completion_gpt4.pkl": "Image_completion/imagecache_init0",
        "object_arrangement_gpt4.pkl": "Object_arrangement(simulated)/cache_robotgpt4",
    }
    for name, target in layout.items():
        (tmp_path / target).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source / name, tmp_path / target)
    shutil.copyfile(source / "image_completion_gpt4.pkl", tmp_path / "Image_completion" / "copy")  # same bytes: once
    (tmp_path / "README.md").write_text("not a pickle")
    (tmp_path / "other.pkl").write_bytes(pickle.dumps({"a": 1}))  # a pickle of something else
    (tmp_path / "grid.pkl").write_bytes(pickle.dumps([np.zeros((3, 3)), np.zeros((3, 3))]))
    (tmp_path / ".git").mkdir()
    shutil.copyfile(source / "cube_stacking_cache0.0.pkl", tmp_path / ".git" / "blob")  # .git is skipped
    found = authors.find_caches(tmp_path)
    assert sorted(c.covers for c in found) == sorted(NAMES.values())
    by_name = {c.path.name: c.covers for c in found}
    assert by_name["cache0.0"] == ("cube-stacking", 8) and by_name["cache0"] == ("cube-stacking", 11)
    assert by_name["cache_robotgpt4"] == ("object-arrangement", 0)


def test_a_pickle_that_could_run_code_is_refused_and_named(tmp_path: Path) -> None:
    _caches()
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps([print, "x"]))
    warnings: list[str] = []
    with pytest.raises(UsageError, match="no authors' cache found"):
        authors.find_caches(tmp_path, Reporter(warnings.append))
    assert len(warnings) == 1 and warnings[0].startswith("warning: ") and "refusing to load builtins.print" in warnings[0]
    with pytest.raises(UsageError, match="no such file or folder"):
        authors.find_caches(tmp_path / "missing")


def test_every_marked_item_gets_a_recorded_line_where_the_caches_cover_it() -> None:
    suite = load_suite()
    provider = f"recorded:/somewhere/{AUTHORS_STORE_NAME}"
    assert is_authors_provider(provider) and not is_authors_provider("recorded:store/")
    covered = with_recorded(suite, provider, set(NAMES.values()))
    added = {
        item.id: [r for r in item.runs if r.provider == provider]
        for item in covered.items
    }
    marked = {i.id for i in suite.items if i.recorded}
    assert {"fig4", "fig5a", "fig5b", "fig5c", "fig6a", "fig6b", "fig6c", "table2", "table3",
            "appendix-stack-size", "appendix-binary-reward", "appendix-extended-arrangement",
            "frontier-cube", "frontier-arrangement", "frontier-image"} == marked
    # the frontiers: every asking policy again on the recorded answers, in both regimes (never joins each panel as it is),
    # stopped at the first solve and as a full-length copy of 5 trials (the item's full_horizon_trials)
    image = added["frontier-image"]
    assert {r.method for r in image} == {"lagr", "lagr-seq"} and len(image) == 28
    assert sorted((r.full_horizon, r.trials) for r in image) == [(False, 30)] * 14 + [(True, 10)] * 14
    assert all(added[i] for i in marked) and not any(added[i.id] for i in suite.items if not i.recorded)
    # Fig. 4: one tau = 0 line (the default run and the authors-t0 profile run are the same query)
    assert [r.label for r in added["fig4"]] == ["authors' GPT answers, τ=0"]
    # Table 2: the tau = 0 row only; Table 3: the paper's GPT4 row three ways (what answered the
    # store's misses), 30 trials each, stopping at the first accepted answer
    assert {r.row for r in added["table2"]} == {"0 (authors' GPT answers)"}
    assert {(r.row, r.on_miss) for r in added["table3"]} == {
        ("GPT4 (misses refused)", "refuse"), ("GPT4 (misses: calibrated draw, fitted)", "calibrated"),
        ("GPT4 (misses: rule-based mock)", "mock"),
    }
    assert {r.trials for r in added["table3"]} == {30} and len(added["table3"]) == 6
    assert all("run.stop_at=first_accepted" in r.overrides for r in added["table3"])
    # the stack-size table: rows of 8 and 11 cubes (no cache for 5), each with its Q-learning run
    rows = next(i for i in covered.items if i.id == "appendix-stack-size").runs
    recorded_rows = {r.row for r in rows if r.row and "authors" in r.row}
    assert recorded_rows == {"8 (authors' GPT answers)", "11 (authors' GPT answers)"}
    # LaGR (the paper's ratio) and LaGR-SEQ (beside it) on the answers, over the same Q-learning
    assert {r.method for r in rows if r.row == "8 (authors' GPT answers)"} == {"lagr", "lagr-seq", "baseline"}
    # no baseline is ever run on the recorded answers, and only caches present add lines
    assert all(r.method != "baseline" for runs in added.values() for r in runs)
    only_cubes = with_recorded(suite, provider, {("cube-stacking", 8)})
    assert not [r for i in only_cubes.items if i.id == "table3" for r in i.runs if r.provider == provider]


SMALL_SUITE = """
[suite]
seed = 0
provider = "mock"

[[items]]
id = "t2"
title = "queries"
render = "query-table"
recorded = true
row_header = "tau"
task = "cube-stacking"
preset = "upstream"
trials = 2
episodes = 10
reference = { "0|LaGR-SEQ" = "126 ± 2.94", "0|LaGR" = "284 ± 0.94" }

[[items.runs]]
label = "LaGR-SEQ"
row = "0"
column = "LaGR-SEQ"
method = "lagr-seq"

[[items.runs]]
label = "LaGR"
row = "0"
column = "LaGR"
method = "lagr"
"""


def test_reproduce_with_the_authors_caches_adds_rows_that_replay_rebuilds_from_logs(tmp_path: Path) -> None:
    from lagrseq.analysis.replay import replay
    from lagrseq.study.reproduce import Reporter, Request, reproduce

    caches = _caches()
    suite_path = tmp_path / "suite.toml"
    suite_path.write_text(SMALL_SUITE)
    said: list[str] = []
    out = tmp_path / "out"
    reproduce(Request(suite_path, None, False, None, out, 1, authors_caches=caches), Reporter(said.append, quiet=True))
    assert sum("authors' answers:" in line for line in said) == 4
    assert (out / AUTHORS_STORE_NAME).is_dir()
    table = (out / "reports" / "tables" / "t2.md").read_text()
    recorded = [line for line in table.splitlines() if line.startswith("| 0 (authors' GPT answers)")]
    # each cell says how many of its answers the store lacked: the small run's prompts are all in the caches
    assert len(recorded) == 1 and recorded[0].count("; misses: 0 of ") == 2
    # replay alone, with the plain suite, finds the recorded runs in the logs and makes the same table
    again = replay([out / "runs"], tmp_path / "again", suite=load_suite(suite_path))
    assert (again.out / "tables" / "t2.md").read_text() == table
    assert "--authors-caches" not in (again.out / "index.md").read_text()
    # the scoreboard: each paper value beside every source (the mock and the authors' answers),
    # with the reduction SEQ brings; rebuilt by replay from the logs alone
    board = (out / "reports" / "scoreboard.md").read_text()
    assert board == (again.out / "scoreboard.md").read_text()
    rows = [line for line in board.splitlines() if line.startswith("| queries")]
    assert len(rows) == 6 and sum("authors' GPT answers" in r for r in rows) == 3
    # every row: what made it and one verdict: the mock rule-based, the authors' answers
    # theirs; 2 trials are never "reproduced"
    assert all(sum(v in r for v in ("| reproduced", "| ✗ differs", "| inconclusive", "| fitted", "| no verdict")) == 1 for r in rows)
    assert not any("| reproduced" in r for r in rows) and all("(n=2" in r for r in rows)
    assert sum("| authors' answers |" in r for r in rows) == 3 and sum("| rule-based mock |" in r for r in rows) == 3
    html = (out / "reports" / "index.html").read_text()
    assert html.index('id="scoreboard"') < html.index("<ul>")
    # without the option the item says in one line how to add the recorded row
    plain = reproduce(Request(suite_path, None, False, None, tmp_path / "plain", 1), Reporter(said.append, quiet=True)).report
    assert "lagrseq reproduce --authors-caches DIR" in (plain.out / "index.md").read_text()


@pytest.mark.slow
@pytest.mark.parametrize(("task", "trials", "steps"), [("object-arrangement", 5, 200), ("image-completion", 3, 2000)])
def test_the_grid_profile_runs_like_the_recorded_answers(tmp_path: Path, task: str, trials: int, steps: int) -> None:
    """mock:authors-gpt4 against the authors' GPT-4 answers (misses answered by the mock), upstream
    preset, queries per trial with and without SEQ: the two runs' 95% bootstrap intervals overlap."""
    pytest.importorskip("torch")
    from lagrseq import config as cfg
    from lagrseq.analysis import stats
    from lagrseq.running import runner
    from lagrseq.running.wiring import provider_options

    caches = _caches()
    found = [c for c in authors.find_caches(caches) if c.task == task]
    authors.import_caches(found, tmp_path)
    recorded = authors.provider_spec(tmp_path)
    for method in ("lagr", "lagr-seq"):
        config = cfg.load(task, method, "upstream", None, [f"run.max_steps={steps}"])
        summaries = []
        for provider in ("mock:authors-gpt4", recorded):
            options = provider_options(provider, {"on_miss": "mock"}) if provider == recorded else None
            queries = [
                runner.run_one(config, t, 0, provider, tmp_path / "x.mcap", log=False, provider_options=options).queries
                for t in range(trials)
            ]
            summaries.append(summarize(np.array(queries, dtype=float), stats.generator(f"{task}/{method}/{provider}")))
        profile, authors_run = summaries
        assert profile.ci_low <= authors_run.ci_high and authors_run.ci_low <= profile.ci_high, (method, profile, authors_run)
