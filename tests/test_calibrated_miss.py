"""The calibrated miss answer of a recorded store (``--on-miss calibrated``), ``run.stop_at``, and
Table 3 three ways on the authors' answers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lagrseq import config as cfg
from lagrseq.analysis import provenance as prov
from lagrseq.analysis.items import match
from lagrseq.analysis.loading import load
from lagrseq.analysis.replay import with_logged_authors_runs
from lagrseq.errors import ConfigError, UsageError
from lagrseq.llm.base import Message, Query
from lagrseq.llm.calibrated import CALIBRATED_SOURCE, draw
from lagrseq.llm.store import RecordStore, Sample, endpoint_of, query_key
from lagrseq.loop.lagr import consult, query_for
from lagrseq.running import runner, wiring
from lagrseq.study import reproduce
from lagrseq.suite import MISS_ROWS, load_suite, miss_row
from tests.conftest import AUTHORS_CACHES

IMAGE = cfg.load("image-completion", "lagr", "upstream")
ENDPOINT = endpoint_of(wiring.default_options("recorded:x").live.base_url)


def _partial(rng: np.random.Generator, shown: int) -> np.ndarray:
    """A 10x10 partial image with ``shown`` pixels on, at random cells."""
    grid = np.zeros(100, dtype=np.int8)
    grid[rng.choice(100, size=shown, replace=False)] = 1
    return grid.reshape(10, 10)


def _synthetic_store(path: Path, task: object, plan: dict[int, tuple[int, int]], seed: int = 1) -> None:
    """A store of image answers: per pixel count, (answers, of them right): right answers are the
    target, wrong ones an empty grid."""
    from lagrseq.tasks import grid

    calibration = wiring.miss_calibration(IMAGE)
    rng = np.random.default_rng(seed)
    with RecordStore(path) as store:
        for shown, (answers, right) in plan.items():
            for index in range(answers):
                query = query_for(task, IMAGE.llm, _partial(rng, shown))  # type: ignore[arg-type]
                key, request = query_key(query, ENDPOINT)
                text = calibration.right(query.prompt) if index < right else grid.format_comma(np.zeros((10, 10), dtype=np.int8))
                store.add(key, request, "image-completion", [Sample(id=f"s{shown}-{index}", text=text, origin="authors-cache")])


def _calibrated(store: Path, seed: int, config: cfg.ExperimentConfig = IMAGE) -> object:
    options = wiring.provider_options(f"recorded:{store}", {"on_miss": "calibrated"})
    return wiring.make_provider(f"recorded:{store}", config, np.random.default_rng(seed), options)


# 0-2 pixels: 0 of 4 right; 3-5: 1 of 4; 6-8: 3 of 4; 9-11: 2 of 2; 12+: 0 of 2
PLAN = {1: (2, 0), 2: (2, 0), 4: (4, 1), 7: (4, 3), 10: (2, 2), 13: (2, 0)}
RATES = {"0-2 shown": 0.0, "3-5 shown": 0.25, "6-8 shown": 0.75, "9-11 shown": 1.0, "12+ shown": 0.0}


def test_the_rates_are_fitted_per_bin_of_pixels_shown_and_the_draws_follow_them(tmp_path: Path) -> None:
    task = wiring.make_task(IMAGE)
    _synthetic_store(tmp_path / "store", task, PLAN)
    calibration = wiring.miss_calibration(IMAGE)
    with RecordStore(tmp_path / "store", create=False) as store:
        fitted = wiring.fitted_rates(store, calibration)
    assert fitted.text() == (
        "0-2 shown: 0/4 (0.0%); 3-5 shown: 1/4 (25.0%); 6-8 shown: 3/4 (75.0%); 9-11 shown: 2/2 (100.0%); 12+ shown: 0/2 (0.0%)"
    )
    # distinct prompts the store lacks, 300 per bin: the share the loop accepts is this draw
    # table's rate of the bin, a draw from the bin's Beta posterior
    rng = np.random.default_rng(7)
    with _calibrated(tmp_path / "store", seed=3) as provider:  # type: ignore[attr-defined]
        drawn = provider.fallback.rates  # type: ignore[attr-defined]
        assert set(drawn) == set(RATES) and all(0 < r < 1 for r in drawn.values())
        for shown, kind in ((2, "0-2 shown"), (4, "3-5 shown"), (7, "6-8 shown"), (10, "9-11 shown"), (14, "12+ shown")):
            results = [consult(task, provider, IMAGE.llm, IMAGE.lagr.threshold, _partial(rng, shown)) for _ in range(300)]
            assert {r.answer.source for r in results} == {CALIBRATED_SOURCE}
            share = np.mean([r.accepted for r in results])
            rate = drawn[kind]
            assert abs(share - rate) <= 4 * np.sqrt(rate * (1 - rate) / 300) + 1e-9, (kind, share)


def test_each_draw_tables_rates_come_from_the_beta_posteriors() -> None:
    """Over many run seeds (draw tables) a kind's drawn rate has the Beta posterior's mean
    (accepted + 1) / (answers + 2) and variance; 21 of 212 gives mean 22/214 and the spread of
    Beta(22, 192); one seed always gives the same table."""
    from lagrseq.llm.calibrated import Fit, KindRate, posterior_rates

    fitted = Fit("image-completion", (KindRate("3-5 shown", 212, 21), KindRate("0-2 shown", 48, 0)))
    draws = np.array([[posterior_rates(fitted, seed)[k] for k in ("3-5 shown", "0-2 shown")] for seed in range(4000)])
    a, b = 22, 192
    assert draws[:, 0].mean() == pytest.approx(a / (a + b), abs=0.002)
    assert draws[:, 0].var() == pytest.approx(a * b / ((a + b) ** 2 * (a + b + 1)), rel=0.1)
    assert draws[:, 1].mean() == pytest.approx(1 / 50, abs=0.002)  # 0 of 48 is not exactly 0
    assert posterior_rates(fitted, 17) == posterior_rates(fitted, 17)


def test_the_draw_is_fixed_per_prompt_and_by_the_run_seed(tmp_path: Path) -> None:
    task = wiring.make_task(IMAGE)
    _synthetic_store(tmp_path / "store", task, PLAN)
    rng = np.random.default_rng(11)
    patterns = [_partial(rng, 6) for _ in range(60)]  # 75% accepted

    def answers(seed: int) -> list[tuple[str, bool]]:
        with _calibrated(tmp_path / "store", seed) as provider:  # type: ignore[attr-defined]
            first = [consult(task, provider, IMAGE.llm, IMAGE.lagr.threshold, p) for p in patterns]
            again = [consult(task, provider, IMAGE.llm, IMAGE.lagr.threshold, p) for p in reversed(patterns)]
        assert [(r.answer.text, r.accepted) for r in first] == [(r.answer.text, r.accepted) for r in reversed(again)]
        return [(r.answer.text, r.accepted) for r in first]

    seed_a = answers(1)
    assert answers(1) == seed_a  # the same run seed: the same draws
    assert [accepted for _, accepted in answers(2)] != [accepted for _, accepted in seed_a]  # another seed: others
    assert 0 < sum(accepted for _, accepted in seed_a) < len(patterns)
    # the draw is the prompt's key and the run seed, nothing else
    query = Query(task="image-completion", model="gpt-4", messages=(Message("user", "x"),))
    key, _ = query_key(query, ENDPOINT)
    assert draw(key, 5) == draw(key, 5) != draw(key, 6)


def test_a_recorded_answer_is_served_from_the_store_not_drawn(tmp_path: Path) -> None:
    task = wiring.make_task(IMAGE)
    _synthetic_store(tmp_path / "store", task, {4: (1, 0)})
    with RecordStore(tmp_path / "store", create=False) as store:
        (entry,) = list(store.entries())
    with _calibrated(tmp_path / "store", seed=0) as provider:  # type: ignore[attr-defined]
        query = Query(task="image-completion", model=entry.request["model"], messages=(Message("user", entry.prompt),),
                      temperature=entry.request["temperature"], max_tokens=entry.request["max_tokens"])
        answer = provider.complete(query)
    assert answer.source == "recorded" and answer.text == entry.samples[0].text


def test_bad_use_of_calibrated_is_refused_in_one_line(tmp_path: Path) -> None:
    # on a provider that is not a store
    done = subprocess.run(
        [sys.executable, "-m", "lagrseq", "run", "image-completion", "--provider", "mock", "--on-miss", "calibrated",
         "--trials", "1", "--out", str(tmp_path / "runs"), "--quiet"],
        capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip().count("\n") == 0 and "--on-miss applies to --provider recorded" in done.stderr, done.stderr
    assert not (tmp_path / "runs").exists()
    # a task without kinds to fit (cube stacking)
    task = wiring.make_task(IMAGE)
    _synthetic_store(tmp_path / "store", task, {4: (1, 0)})
    cube = cfg.load("cube-stacking", "lagr", "upstream")
    with pytest.raises(UsageError, match=r"^--on-miss calibrated needs a task whose prompts have kinds .*cube-stacking has none: use --on-miss refuse or mock$"):
        _calibrated(tmp_path / "store", 0, cube)
    # a store without answers of the task
    arrangement = cfg.load("object-arrangement", "lagr", "upstream")
    with pytest.raises(UsageError, match=r"^--on-miss calibrated: store .* holds no answers of task object-arrangement to fit"):
        _calibrated(tmp_path / "store", 0, arrangement)
    # in a suite file: on a provider that is no store, and a recorded_on_miss that would stop or pay
    base = '[suite]\nprovider = "mock"\n[[items]]\nid = "t"\ntitle = "t"\nrender = "query-table"\ntask = "image-completion"\npreset = "upstream"\n'
    (tmp_path / "a.toml").write_text(base + '[[items.runs]]\nlabel = "x"\nmethod = "lagr"\nprovider = "mock"\non_miss = "calibrated"\n')
    with pytest.raises(ConfigError, match="on_miss applies to recorded:STORE runs only"):
        load_suite(tmp_path / "a.toml")
    (tmp_path / "b.toml").write_text(base.replace('render', 'recorded = true\nrecorded_on_miss = ["live"]\nrender') + '[[items.runs]]\nlabel = "x"\nmethod = "lagr"\n')
    with pytest.raises(ConfigError, match=r"recorded_on_miss holds 'live'; expected refuse, calibrated or mock"):
        load_suite(tmp_path / "b.toml")


def test_stop_at_first_accepted_ends_the_trial_with_that_step(tmp_path: Path) -> None:
    cube = cfg.load("cube-stacking", "lagr", "upstream", overrides=["run.episodes=50"])
    stopped = cfg.load("cube-stacking", "lagr", "upstream", overrides=["run.episodes=50", "run.stop_at=first_accepted"])
    assert "stop_at" not in cube.to_dict()["run"] and cube.digest() != stopped.digest()  # the default leaves logs as they were
    full = runner.run_one(cube, 0, 0, "mock:oracle", tmp_path / "full.mcap")
    short = runner.run_one(stopped, 0, 0, "mock:oracle", tmp_path / "short.mcap")
    run_full, run_short = load([tmp_path / "full.mcap"]).runs[0], load([tmp_path / "short.mcap"]).runs[0]
    accepted = run_short.queries[run_short.queries["accepted"].fillna(False).astype(bool)]
    assert len(accepted) == 1  # one accepted answer, and nothing after it
    last = run_short.episodes.iloc[-1]
    assert int(last["accepted"]) == 1 and int(last["global_step"]) == int(accepted["global_step"].iloc[0]) + 1
    assert short.steps == int(accepted["global_step"].iloc[0]) + 1 < full.steps
    assert short.episodes < full.episodes == 50
    # up to that step the trial is the unstopped one's
    first = run_full.queries[run_full.queries["global_step"] <= int(accepted["global_step"].iloc[0])]
    columns = ["global_step", "queried", "evaluation"]
    assert first[columns].astype(str).values.tolist() == run_short.queries[columns].astype(str).values.tolist()


@pytest.fixture(scope="module")
def authors_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not AUTHORS_CACHES.exists():
        pytest.skip(f"the authors' caches are not present ({AUTHORS_CACHES})")
    out = tmp_path_factory.mktemp("authors")
    reproduce.with_authors_answers(load_suite().select(["table3"]), AUTHORS_CACHES, out, reproduce.Reporter.silent())
    return out


def test_the_authors_image_answers_fit_the_bins_the_issue_names(authors_out: Path) -> None:
    with RecordStore(authors_out / "authors-answers", create=False) as store:
        fitted = wiring.fitted_rates(store, wiring.miss_calibration(IMAGE))
    # 0 accepted at <= 2 pixels, about 10% otherwise, measured on the 780 answers
    assert fitted.text() == (
        "0-2 shown: 0/48 (0.0%); 3-5 shown: 21/212 (9.9%); 6-8 shown: 19/235 (8.1%); 9-11 shown: 20/218 (9.2%); 12+ shown: 13/67 (19.4%)"
    )


def test_table3_has_three_rows_on_the_authors_answers(authors_out: Path) -> None:
    pytest.importorskip("torch")  # Table 3 is image completion, a DQN task: planned only where torch is installed
    suite = reproduce.with_authors_answers(load_suite().select(["table3"]), AUTHORS_CACHES, authors_out, reproduce.Reporter.silent())
    runs_dir = authors_out / "runs"
    full = reproduce.plan(suite, quick=False, provider=None, runs_dir=runs_dir, seed=0)
    on_authors = [run for run in full.runs if run.provider.endswith("authors-answers")]
    assert sorted((run.config.method, run.options.on_miss) for run in on_authors) == sorted(
        (method, on_miss) for method in ("lagr", "lagr-seq") for on_miss in ("refuse", "calibrated", "mock")
    )
    assert {run.trials for run in on_authors} == {30} and len({run.path for run in on_authors}) == 6
    assert {run.config.run.stop_at for run in full.runs} == {"first_accepted"}
    # one short trial of each (200 steps), then replay finds each row's own run from the logs alone
    quick = reproduce.plan(suite, quick=True, provider=None, runs_dir=runs_dir, seed=0)
    for run in quick.runs:
        if run.provider.endswith("authors-answers"):
            short = cfg.load("image-completion", run.config.method, "upstream", overrides=["run.stop_at=first_accepted", "run.max_steps=200"])
            runner.run_trials(short, 1, run.seed, run.provider, run.path, provider_options=run.options)
    logs = load([runs_dir])
    item = with_logged_authors_runs(load_suite().select(["table3"]), logs.runs).items[0]
    matched = [m for m in match(item, logs.runs, "mock") if m.run is not None]
    rows = {(m.row, m.spec.column): m for m in matched}
    for on_miss in ("refuse", "calibrated", "mock"):
        for column in ("LaGR-SEQ", "LaGR (without SEQ)"):
            m = rows[(miss_row("GPT4", on_miss), column)]
            assert m.run is not None and m.run.key.variant == ("" if on_miss == "mock" else f"on-miss-{on_miss}")
            sources = set(m.run.queries["source"].dropna()) - {"recorded"}
            assert sources <= {"refuse": {"miss"}, "calibrated": {CALIBRATED_SOURCE}, "mock": {"mock"}}[on_miss]
            assert prov.of_run(m.run).kind == (prov.FITTED if on_miss == "calibrated" else prov.AUTHORS)
    assert set(MISS_ROWS) == {"refuse", "calibrated", "mock"}
