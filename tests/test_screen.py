"""`lagrseq screen`: the table and picture rebuilt from hand-made recorded-answer JSONL, the
Wilson interval, the spread of prompts over prefix lengths and fill fractions, hostile inputs (one
line, exit 2), the live path against the stand-in llama.cpp server of tests/llm/fake_llama, and
the report's "open models" sections from the committed recorded_llm/ files."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.llm.store import request_of
from lagrseq.running.recording import queries_for, record_config
from lagrseq.running.wiring import make_task
from lagrseq.study import screen

ROOT = Path(__file__).resolve().parents[1]
FAKE = ROOT / "tests" / "llm" / "fake_llama"
SHA = "ab" * 32


def _record(request: dict[str, Any], task: str, text: str, n: int, provenance: str | None = None, finish: str = "stop") -> str:
    return json.dumps({
        "format": "lagrseq.recorded/1",
        "task": task,
        "request": request,
        "sample": {
            "id": f"s{n}", "text": text, "origin": "live", "model": request["model"],
            "usage": {"prompt_tokens": 300, "completion_tokens": 20, "cached_tokens": 0},
            "finish_reason": finish, "latency_s": 2.0, "provenance": provenance,
        },
    })


def cube_file(tmp_path: Path, model: str = "tiny-1b", temperature: float = 0.0) -> Path:
    """Prefixes 1, 4 and 8 of the 8-cube target: prefix 4 right twice of three (two different
    wordings: at tau = 0 a word-for-word repeat would count once), prefix 1 prose, prefix 8 one
    wrong list cut at the token limit."""
    config = record_config("cube-stacking", "upstream", None, [], model, temperature)
    task = make_task(config)
    queries = {len(p): q for p, q in zip(task.prefixes(), queries_for(config, task.prefixes()))}
    target = "[" + ",".join(f"'{'abcdefghijk'[i]}'" for i in task.target) + "]"
    stamp = f"chatcmpl-1; {screen.GGUF_MARK}{SHA}; Tiny 1B, 1B, Q4_K_M, qwen2"
    lines = [
        _record(request_of(queries[4], "local"), "cube-stacking", target, 1, stamp),
        _record(request_of(queries[4], "local"), "cube-stacking", target.replace(",", ", "), 2, stamp),  # right, worded apart
        _record(request_of(queries[4], "local"), "cube-stacking", "['e','f','g','a']", 3, stamp),
        _record(request_of(queries[1], "local"), "cube-stacking", "Let me think step by step about the cubes and their sizes first", 4, stamp),
        _record(request_of(queries[8], "local"), "cube-stacking", "['a','b','c','d','e','f','g','h']", 5, stamp, "length"),
    ]
    path = tmp_path / f"{model}-cube-t{temperature:g}.jsonl"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def arrangement_file(tmp_path: Path) -> Path:
    """Two states of the arrangement (1 and 3 target cells shown): one answer the target, one a
    4 x 4 grid."""
    config = record_config("object-arrangement", "upstream", None, [], "tiny-1b", 0.0)
    task = make_task(config)
    on = np.argwhere(task.target != 0)
    states = []
    for shown in (1, 3):
        state = np.zeros_like(task.target)
        for r, c in on[:shown]:
            state[r, c] = 1
        states.append(state)
    queries = queries_for(config, states)
    right = "[" + ",\n".join("[" + ",".join(str(int(v)) for v in row) + "]" for row in task.target) + "]"
    lines = [
        _record(request_of(queries[0], "local"), "object-arrangement", right, 1),
        _record(request_of(queries[1], "local"), "object-arrangement", "[[0,1,0,0],[1,0,0,0],[0,0,0,1],[0,0,1,0]]", 2),
    ]
    path = tmp_path / "tiny-arrangement.jsonl"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def lagrseq(*args: str, env: dict[str, str] | None = None, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, timeout=timeout,
        env=env or {**os.environ, "MPLBACKEND": "Agg"}, cwd=ROOT,
    )


def test_wilson_matches_the_textbook_values() -> None:
    low, high = screen.wilson(0, 10)
    assert low == 0.0 and high == pytest.approx(0.2775, abs=1e-4)
    low, high = screen.wilson(5, 10)
    assert (low, high) == (pytest.approx(0.2366, abs=1e-4), pytest.approx(0.7634, abs=1e-4))
    assert screen.wilson(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        screen.wilson(3, 2)


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 10_000), st.data())
def test_the_wilson_interval_holds_the_estimate(n: int, data: Any) -> None:
    k = data.draw(st.integers(0, n))
    low, high = screen.wilson(k, n)
    assert 0.0 <= low <= k / n <= high <= 1.0


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 7), max_size=60), st.integers(1, 80))
def test_spread_takes_every_bin_in_turn(bins: list[int], n: int) -> None:
    patterns = list(range(len(bins)))
    chosen = screen.spread(patterns, bins, n)
    assert len(chosen) == min(n, len(bins)) and len(set(chosen)) == len(chosen)
    taken = {b: sum(1 for i in chosen if bins[i] == b) for b in set(bins)}
    available = {b: bins.count(b) for b in set(bins)}
    # a bin has fewer than another only when it has run out
    for a in taken:
        for b in taken:
            assert taken[a] >= taken[b] - 1 or taken[a] == available[a]


def test_the_table_and_picture_come_from_a_hand_made_file(tmp_path: Path) -> None:
    answers = cube_file(tmp_path)
    out = tmp_path / "screen"
    done = lagrseq("screen", "cube-stacking", "--from", str(answers), "--out", str(out))
    assert done.returncode == 0, done.stderr
    table = (out / "screen-cube-stacking.md").read_text()
    # the prompts are prefixes of one target: a complete count of that sequence, no interval
    assert "| cube-stacking | tiny-1b | 0 | Tiny 1B, 1B, Q4_K_M, qwen2 | abababababab | 2/5 = 40% (3 prefixes of one target: a count over one sequence, not a sample of prompts; no interval) | 2/4 = 50% (2 prefixes" in table
    assert "correct 2, wrong 1, partial 1, prose 1" in table
    assert "| 2.0 | 10.0 | 1 | 320 |" in table  # s/answer, tokens/s, cut at max_tokens, longest
    assert "| 4/8 cubes | 2/3 = 67% [20, 94] |" in table and "| 1/8 cubes | 0/1 = 0% [0, 80] |" in table  # bounds rounded outward
    rows = list(csv.DictReader((out / "screen-cube-stacking.csv").open()))
    four = next(r for r in rows if r["shown"] == "4")
    assert (four["answers"], four["correct"], four["fraction"], four["sha256"]) == ("3", "2", "0.5000", SHA)
    assert next(r for r in rows if r["shown"] == "all")["correct"] == "2"
    assert (out / "screen-cube-stacking.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert table in done.stdout + "\n" or "tiny-1b" in done.stdout


@pytest.mark.parametrize(("temperature", "counted"), [(0.0, (2, 1)), (1.0, (4, 3))])
def test_a_greedy_repeat_counts_once(tmp_path: Path, temperature: float, counted: tuple[int, int]) -> None:
    """At tau = 0 asking a prompt again gives the same answer (greedy decoding): three identical
    right answers and one wrong one are two observations, one right; at tau > 0 they are four
    draws. Speed counts every answer either way."""
    config = record_config("cube-stacking", "upstream", None, [], "tiny-1b", temperature)
    task = make_task(config)
    query = queries_for(config, [task.prefixes()[3]])[0]
    target = "[" + ",".join(f"'{'abcdefghijk'[i]}'" for i in task.target) + "]"
    texts = [target, target, target, "['e','f','g','a']"]
    lines = [_record(request_of(query, "local"), "cube-stacking", text, i + 1) for i, text in enumerate(texts)]
    path = tmp_path / "repeats.jsonl"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    [found] = screen.screens_from([path], [config])
    assert found.cells == {4: counted}
    assert len(found.seconds) == 4


def test_a_grid_screen_bins_by_the_target_cells_shown(tmp_path: Path) -> None:
    answers = arrangement_file(tmp_path)
    config = record_config("object-arrangement", "upstream", None, [])
    screens = screen.screens_from([answers], [config])
    assert len(screens) == 1 and screens[0].size == 8
    assert screens[0].cells == {1: (1, 1), 3: (1, 0)}
    assert screens[0].kinds == {"correct": 1, "other": 1}  # a 4 x 4 grid: the parser finds no 5 x 5 one
    assert screen.write_screen(screens, tmp_path / "out", "s")[2].stat().st_size > 1000


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--from", "NOTJSONL"], "bad line"),
        (["--from", "MISSING"], "no such file"),
        (["--from", "OTHER"], "no answers of the task"),
        (["--from", "GOOD", "--store", "S"], "--store belong to a screen that asks"),
        (["--prompts", "0"], "prompts"),
        (["--from", "GOOD", "--out", "AFILE"], "cannot write the screen"),
    ],
)
def test_hostile_inputs_are_one_line_and_exit_2(tmp_path: Path, args: list[str], fragment: str) -> None:
    (tmp_path / "bad.jsonl").write_text('{"format": "lagrseq.recorded/1", "request": 42}\n')
    afile = tmp_path / "afile"
    afile.write_text("x")
    names = {
        "NOTJSONL": str(tmp_path / "bad.jsonl"), "MISSING": str(tmp_path / "none.jsonl"),
        "OTHER": str(arrangement_file(tmp_path)), "GOOD": str(cube_file(tmp_path)), "S": str(tmp_path / "s"),
        "AFILE": str(afile),
    }
    given_args = [names.get(a, a) for a in args]
    if "--out" not in given_args:
        given_args += ["--out", str(tmp_path / "out")]
    done = lagrseq("screen", "cube-stacking", *given_args)
    assert done.returncode == 2, done.stdout + done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and fragment in done.stderr, done.stderr


def test_the_live_screen_asks_the_local_server_and_stamps_the_model(tmp_path: Path) -> None:
    """Against the stand-in llama.cpp server (same command line and HTTP as the real one): every
    prefix asked twice for 16 answers, written as JSONL whose provenance names the file's sha256."""
    model = tmp_path / "tiny-model.gguf"
    model.write_bytes(b"GGUF\x03\x00\x00\x00" + bytes(56))
    bodies = tmp_path / "bodies.jsonl"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(FAKE), str(ROOT)]), "MPLBACKEND": "Agg", "FAKE_LLAMA_BODIES": str(bodies)}
    answers = tmp_path / "a.jsonl"
    done = lagrseq(
        "screen", "cube-stacking", "--provider", f"local:{model}", "--prompts", "16", "--threads", "1",
        "--temperature", "0.5", "--answers", str(answers), "--out", str(tmp_path / "out"), "--quiet", env=env,
    )
    assert done.returncode == 0, done.stderr
    records = [json.loads(line) for line in answers.read_text().splitlines()]
    assert len(records) == 16 and {r["request"]["model"] for r in records} == {"tiny-model"}
    # llama.cpp's samplers pinned to OpenAI's meaning of temperature: the server received them on
    # every request, and every answer's key records them
    pinned = {"temperature": 0.5, "top_p": 1.0, "top_k": 0, "min_p": 0.0, "repeat_penalty": 1.0}
    received = [json.loads(line) for line in bodies.read_text().splitlines()]
    assert len(received) == 16 and all(r == pinned for r in received), received[:2]
    assert all({name: r["request"][name] for name in pinned} == pinned for r in records)
    digest = screen.model_of_provenance(records[0]["sample"]["provenance"])[0]
    import hashlib

    assert digest == hashlib.sha256(model.read_bytes()).hexdigest()
    table = (tmp_path / "out" / "screen-cube-stacking.md").read_text()
    # the stand-in always answers a..h (wrong); at tau > 0 each of the 16 is a draw of its own
    assert "0/16 = 0%" in table and "wrong 16" in table


def test_the_report_sections_come_from_recorded_answers(tmp_path: Path) -> None:
    (tmp_path / "recorded_llm").mkdir()
    cube_file(tmp_path / "recorded_llm", "screen-tiny")
    (tmp_path / "recorded_llm" / "screen-tiny-arr.jsonl").write_bytes(arrangement_file(tmp_path).read_bytes())
    sections, line = screen.report_sections(tmp_path)
    assert "2 recorded answer files, 7 answers of 2 models" in line
    stems = [stem for stem, _, _ in sections]
    assert stems == ["open-models", "open-models-cells"]
    table = sections[0][1]
    assert {row[0] for row in table.rows} == {"cube-stacking", "object-arrangement"}
    none, why = screen.report_sections(tmp_path / "empty")
    assert none == [] and "no recorded_llm/screen-*.jsonl" in why


def test_the_temperature_model_is_tested_not_fitted(tmp_path: Path) -> None:
    from lagrseq.tasks.cube import AUTHORS_T0

    config = record_config("cube-stacking", "upstream", None, [])
    t0 = screen.screens_from([cube_file(tmp_path, "m", 0.0)], [config])
    t1 = screen.screens_from([cube_file(tmp_path, "m", 1.0)], [config])
    rows = screen.temperature_rows([*t0, *t1], AUTHORS_T0.temperature)
    four = next(r for r in rows if r[2] == "4/8 cubes")
    # P(right | 4 of 8 shown, tau 1) = 2/3 x (1 - 0.3) = 47%; measured 2/3 again: inside its interval
    assert four == ("m", "1", "4/8 cubes", "47%", "2/3 = 67% [20, 94]", "yes")
    assert rows[-1][2] == "all prefixes"


def test_the_committed_screens_rebuild_without_the_extra() -> None:
    """The report's item from the files in recorded_llm/, in a process where llama_cpp cannot be
    imported (the extra absent) and no model file is read."""
    code = (
        "import sys; sys.modules['llama_cpp'] = None\n"
        "from lagrseq.study import screen\n"
        "sections, line = screen.report_sections()\n"
        "print(line); print([s for s, _, _ in sections])\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300, env={**os.environ, "MPLBACKEND": "Agg"})
    assert done.returncode == 0, done.stderr
    if "not made" in done.stdout:
        pytest.skip("no screen files committed yet")
    assert "open-models" in done.stdout


def test_replay_writes_the_sections_into_the_report(tmp_path: Path) -> None:
    from lagrseq import config as cfg
    from lagrseq.analysis.replay import replay
    from lagrseq.running import runner

    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=3"])
    runner.run_trials(config, 1, 0, "mock", runner.run_directory(tmp_path / "runs", config, "mock", 0), jobs=1)
    (tmp_path / "recorded_llm").mkdir()
    cube_file(tmp_path / "recorded_llm", "screen-tiny")
    sections, _ = screen.report_sections(tmp_path)
    report = replay([tmp_path / "runs"], tmp_path / "report", sections=sections)
    index = (report.out / "index.md").read_text()
    assert "![Open models: screen of 1 GGUF models" in index and "(figures/open-models.png)" in index
    assert "| cube-stacking | screen-tiny τ=0 | 4/8 cubes | 2/3 = 67% [20, 94] |" in index
    assert (report.out / "figures" / "open-models.png").is_file() and (report.out / "tables" / "open-models.csv").is_file()
    assert 'src="figures/open-models.png"' in (report.out / "index.html").read_text()


# ------------------------------------------------------------------------------------------
# Prompt sets that are samples, intervals clustered by prompt, exact comparisons, the
# temperature model's likelihood-ratio test
# ------------------------------------------------------------------------------------------
def test_relabelled_cube_sets_are_distinct_prompts_no_two_of_one_target() -> None:
    from lagrseq.tasks import cube

    config = record_config("cube-stacking", "upstream", None, [], "m", 0.0)
    queries, samples = screen.screen_queries(config, 56, prompt_set="relabelled", seed=3)
    assert samples == 1 and len({q.prompt for q in queries}) == 56
    tasks = [cube.task_of_prompt(q.prompt) for q in queries]
    assert len({t.target for t in tasks}) == 56 and all(t.relabel is not None for t in tasks)
    shown = [len(cube.partial_stack(q.prompt)) for q in queries]
    assert sorted(set(shown)) == list(range(1, 8)) and all(shown.count(b) == 8 for b in range(1, 8))
    # each prompt shows a prefix of its own target, under its own letters, and only that target is right
    for q, t, b in zip(queries, tasks, shown):
        assert cube.partial_stack(q.prompt) == [cube.LETTERS[i] for i in t.target[:b]]
        assert t.is_complete(t.parse(cube.format_stack(t.target)).solution)  # type: ignore[arg-type]
    # seeded: the same seed gives the same prompts, another seed others
    again, _ = screen.screen_queries(config, 56, prompt_set="relabelled", seed=3)
    other, _ = screen.screen_queries(config, 56, prompt_set="relabelled", seed=4)
    assert [q.prompt for q in again] == [q.prompt for q in queries] != [q.prompt for q in other]
    # the 11-cube target
    eleven = record_config("cube-stacking", "upstream", None, ["task.stack_size=11"], "m", 0.0)
    big, _ = screen.screen_queries(eleven, 55, prompt_set="relabelled")
    assert {cube.task_of_prompt(q.prompt).stack_size for q in big} == {11} and len({q.prompt for q in big}) == 55


def test_sampled_arrangement_states_are_distinct_partial_targets() -> None:
    config = record_config("object-arrangement", "upstream", None, ["task.target=plus"], "m", 0.0)
    task = make_task(config)
    queries, samples = screen.screen_queries(config, 60, prompt_set="sampled")
    assert samples == 1 and len({q.prompt for q in queries}) == 60
    bins = [screen.bin_of_prompt(task, q.prompt) for q in queries]
    on = int(np.count_nonzero(task.target))
    assert set(bins) == set(range(on)) and max(bins) < on  # every fill short of the whole target


@pytest.mark.parametrize(
    ("task", "sets", "fragment"),
    [
        ("object-arrangement", ["--prompt-set", "relabelled"], "object-arrangement screens take runs, sampled"),
        ("cube-stacking", ["--prompt-set", "relabelled", "--prompts", "200", "--set", "task.stack_size=5"], "5 cubes have only 119 relabellings"),
        ("cube-stacking", ["--prompt-set", "runs"], "--prompt-set runs needs --from-runs"),
    ],
)
def test_a_prompt_set_that_cannot_be_made_is_one_line_and_exit_2(tmp_path: Path, task: str, sets: list[str], fragment: str) -> None:
    model = tmp_path / "tiny-model.gguf"
    model.write_bytes(b"GGUF\x03\x00\x00\x00" + bytes(56))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(FAKE), str(ROOT)]), "MPLBACKEND": "Agg"}
    done = lagrseq("screen", task, "--provider", f"local:{model}", *sets, "--out", str(tmp_path / "out"), "--quiet", env=env)
    assert done.returncode == 2, done.stdout + done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and fragment in done.stderr, done.stderr


def _screen_of(cells: list[tuple[int, int]], prompt_set: str = "relabelled 8-cube sets", task: str = "cube-stacking") -> screen.Screen:
    s = screen.Screen(task, "m", 0.0, 8, prompt_set)
    for i, (n, k) in enumerate(cells):
        s.prompts[f"p{i}"] = (n, k)
        s.prompt_bins[f"p{i}"] = 1 + i % 7
    return s


def test_the_interval_resamples_prompts_not_answers() -> None:
    # 20 prompts of 10 answers each, half of them always right, half never: 100/200 answers right.
    # Resampling answers would give about +-7 points; the prompts are the sample: about +-22
    clustered = screen.accuracy_over_prompts(_screen_of([(10, 10)] * 10 + [(10, 0)] * 10))
    assert clustered.method.startswith("cluster bootstrap") and clustered.low is not None and clustered.high is not None
    assert clustered.high - clustered.low > 0.3
    # the exact interval at the clustered sample's effective size (20 prompts' worth, not 200
    # answers' worth) is about as wide: here every prompt is as informative as one answer
    from scipy.stats import binomtest

    effective = binomtest(10, 20).proportion_ci(0.95, method="exact")
    assert clustered.low <= effective.low + 0.03 and clustered.high >= effective.high - 0.03
    assert (clustered.correct, clustered.answers, clustered.prompts) == (100, 200, 20)
    # seeded: the same screen gives the same interval
    assert screen.accuracy_over_prompts(_screen_of([(10, 10)] * 10 + [(10, 0)] * 10)) == clustered
    # one answer per prompt and few right: at least the exact interval (the percentile bootstrap under-covers)
    few = screen.accuracy_over_prompts(_screen_of([(1, 1)] + [(1, 0)] * 47))
    exact = binomtest(1, 48).proportion_ci(0.95, method="exact")
    assert few.low is not None and few.high is not None and few.low <= exact.low and few.high >= exact.high
    # nothing right anywhere: exact over prompts
    none = screen.accuracy_over_prompts(_screen_of([(1, 0)] * 48))
    assert none.method == "exact over prompts" and none.low == 0.0 and none.high is not None and abs(none.high - binomtest(0, 48).proportion_ci(method="exact").high) < 1e-12
    # nested prefixes of one target: a count, no interval
    nested = screen.accuracy_over_prompts(_screen_of([(1, 1), (1, 0), (1, 0)], prompt_set=""))
    assert nested.low is None and "prefixes of one target" in nested.text() and "not a sample" in nested.text()


def test_fisher_compares_one_unit_per_prompt_in_both_arms() -> None:
    """Qwen's 2 of 7 prefixes against another model's 0 of 7 prefixes (never its 9 answers): Fisher
    on [[2, 5], [0, 7]] is 0.46, not the 0.175 of prompts against answers; a prompt counts right when
    at least half its counted answers are."""
    from scipy.stats import fisher_exact

    a, b = _screen_of([(1, 1)] * 2 + [(1, 0)] * 5), _screen_of([(2, 0)] * 2 + [(1, 0)] * 5)
    a.model, b.model = "good", "bad"
    (row,) = screen.fisher_rows([a, b])
    assert row[3:7] == ("good", "2/7", "bad", "0/7")
    assert float(row[7]) == pytest.approx(fisher_exact([[2, 5], [0, 7]]).pvalue, abs=5e-4) and row[7] == "0.462"
    assert row[8] == "(no prompt shows the target)"
    assert screen.prompt_units(_screen_of([(3, 2), (2, 1), (3, 1)])) == (3, 2)


def test_states_met_by_runs_get_no_binomial_interval() -> None:
    """An arrangement screen of the states the runs' trajectories met is no sample of states: no
    interval over prompts and none per cell; a screen of sampled states keeps its interval."""
    runs = _screen_of([(1, 0)] * 48, prompt_set="", task="object-arrangement")
    runs.cells = {1: (48, 0)}
    found = screen.accuracy_over_prompts(runs)
    assert found.low is None and "states met by the runs' trajectories" in found.text() and "no interval" in found.text()
    assert "wilson" not in screen.csv_text([runs]).split("\n", 2)[1]
    sampled = screen.accuracy_over_prompts(_screen_of([(1, 0)] * 56, prompt_set=screen.SAMPLED_SET, task="object-arrangement"))
    assert sampled.method == "exact over prompts" and sampled.text().startswith("0/56 = 0% [0, 7]")  # 6.38% rounded up


class _Drop:
    """A temperature model: P(right | tau) = P(right | 0) x (1 - tau / 2)."""

    def factor(self, fraction: float, temperature: float) -> float:
        return 1 - temperature / 2


def _tau_screens(base: dict[int, tuple[int, int]], hot: dict[int, tuple[int, int]]) -> list[screen.Screen]:
    zero = screen.Screen("cube-stacking", "m", 0.0, 8, cells=dict(base))
    one = screen.Screen("cube-stacking", "m", 1.0, 8, cells=dict(hot))
    return [zero, one]


def test_the_temperature_model_is_falsified_where_it_predicts_zero_and_answers_are_right() -> None:
    (test,) = screen.temperature_tests(_tau_screens({1: (1, 0), 4: (1, 1)}, {1: (10, 1), 4: (10, 5)}), _Drop(), resamples=2000)
    assert test.impossible and "1/8 cubes: predicted 0%, 1/10 right" in test.impossible[0]
    assert test.verdict().startswith("falsified") and test.possible_prefixes == 1
    # where the data are what the model predicts (50% at 4 of 8 shown), the test does not reject
    (fine,) = screen.temperature_tests(_tau_screens({1: (1, 0), 4: (1, 1)}, {1: (10, 0), 4: (10, 5)}), _Drop(), resamples=2000)
    assert not fine.impossible and fine.statistic == pytest.approx(0.0) and fine.verdict() == "not rejected at 5%"
    # far from it (0/10 where 50% is predicted), it does
    (far,) = screen.temperature_tests(_tau_screens({4: (1, 1)}, {4: (10, 0)}), _Drop(), resamples=2000)
    assert far.p_bootstrap < 0.01 and far.verdict() == "rejected at 5% (parametric bootstrap)"


def test_the_committed_temperature_answers_falsify_the_model() -> None:
    """Qwen2.5-Coder-1.5B's real tau > 0 answers: right at prefixes where the model predicts 0
    (1/10 at 3 and 6 of 8 shown at tau = 0.5; 3/10 and 1/10 at 6 and 7 at tau = 1)."""
    from lagrseq.tasks.cube import AUTHORS_T0

    config = record_config("cube-stacking", "upstream", None, [])
    files = sorted((ROOT / "recorded_llm").glob("qwen2.5-coder-1.5b-cube-t*.jsonl"))
    tests = screen.temperature_tests(screen.screens_from(files, [config]), AUTHORS_T0.temperature, resamples=2000)
    assert [t.temperature for t in tests] == [0.5, 1.0]
    assert all(t.verdict().startswith("falsified") for t in tests)
    assert any("3/10 right" in line for line in tests[1].impossible)


def test_a_relabelled_screen_asks_the_local_server_and_reads_back_as_a_sample(tmp_path: Path) -> None:
    """A relabelled screen end to end against the stand-in server (it always answers a..h, which
    is no relabelled target): 14 distinct prompts, one answer each, an exact interval over them."""
    model = tmp_path / "tiny-model.gguf"
    model.write_bytes(b"GGUF\x03\x00\x00\x00" + bytes(56))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(FAKE), str(ROOT)]), "MPLBACKEND": "Agg"}
    answers = tmp_path / "a.jsonl"
    done = lagrseq(
        "screen", "cube-stacking", "--provider", f"local:{model}", "--prompts", "14", "--threads", "1",
        "--prompt-set", "relabelled", "--answers", str(answers), "--out", str(tmp_path / "out"), "--quiet", env=env,
    )
    assert done.returncode == 0, done.stderr
    assert len({json.loads(line)["key"] for line in answers.read_text().splitlines()}) == 14
    table = (tmp_path / "out" / "screen-cube-stacking.md").read_text()
    # answers with llama.cpp's samplers pinned are labelled so, never pooled with answers of its defaults
    assert "tiny-model (relabelled 8-cube sets, samplers pinned)" in table and "0/14 = 0% [0, 24] (exact over prompts, 14 prompts)" in table
    # read back with --from: the same table, the prompts' targets read from the prompts themselves
    again = lagrseq("screen", "cube-stacking", "--from", str(answers), "--out", str(tmp_path / "again"))
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "again" / "screen-cube-stacking.md").read_text() == table


def test_a_screen_of_another_arrangement_target_is_judged_by_that_target(tmp_path: Path) -> None:
    """A grid prompt does not name its target: the report reads a file tagged ``target-plus`` with
    the plus target (its right answer is the plus, not the default diamond)."""
    config = record_config("object-arrangement", "upstream", None, ["task.target=plus"], "tiny-1b", 0.0)
    task = make_task(config)
    queries, _ = screen.screen_queries(config, 2, prompt_set="sampled")
    plus = "[" + ",\n".join("[" + ",".join(str(int(v)) for v in row) + "]" for row in task.target) + "]"
    diamond = make_task(record_config("object-arrangement", "upstream", None, [], "tiny-1b", 0.0)).target
    wrong = "[" + ",\n".join("[" + ",".join(str(int(v)) for v in row) + "]" for row in diamond) + "]"
    (tmp_path / "recorded_llm").mkdir()
    lines = [_record(request_of(queries[0], "local"), "object-arrangement", plus, 1), _record(request_of(queries[1], "local"), "object-arrangement", wrong, 2)]
    (tmp_path / "recorded_llm" / "screen-sampled-target-plus-tiny-t0.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    sections, _ = screen.report_sections(tmp_path)
    (row,) = sections[0][1].rows
    assert row[1] == "tiny-1b (sampled states, plus target)" and row[5].startswith("1/2 = 50% [")


@pytest.mark.parametrize("suffix", [".md", ".csv", ".png"])
def test_a_link_planted_at_a_screen_output_is_refused_and_nothing_is_written(tmp_path: Path, suffix: str) -> None:
    from lagrseq.errors import UsageError

    config = record_config("object-arrangement", "upstream", None, [])
    screens = screen.screens_from([arrangement_file(tmp_path)], [config])
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (out / f"s{suffix}").symlink_to(victim)
    with pytest.raises(UsageError, match="symbolic link"):
        screen.write_screen(screens, out, "s")
    assert victim.read_text() == "precious" and sorted(p.name for p in out.iterdir()) == [f"s{suffix}"]


SCREENED_MODELS = (
    "SmolLM2-135M-Instruct",
    "gemma-3-270m-q4_k_m",
    "qwen2.5-coder-0.5b-instruct-q4_k_m",
    "qwen2.5-coder-1.5b-instruct-q4_k_m",
)
"""The open models screened on the nested prefixes (recorded_llm/README.md, docs/open-models.md)."""


def test_every_screened_model_is_in_the_report_on_both_sampled_prompt_sets() -> None:
    """Each model the report screens was also asked at least 50 distinct relabelled cube prompts
    and 50 distinct sampled arrangement states, one answer each with the samplers pinned, in the
    committed files the report's item reads (its own glob); their rows carry an interval over
    prompts."""
    files = [p for p in sorted(ROOT.glob(screen.SCREEN_FILES)) if not screen.TARGET_TAG.search(p.name)]
    configs = [record_config(task, "upstream", None, []) for task in screen.SCREEN_TASKS]
    screens = screen.screens_from(files, configs)
    assert {s.model for s in screens} == set(SCREENED_MODELS)
    for task, prompt_set in (("cube-stacking", "relabelled 8-cube sets"), ("object-arrangement", "sampled states")):
        sampled = {s.model: s for s in screens if s.task == task and s.pinned and s.prompt_set == prompt_set}
        assert sorted(sampled) == sorted(SCREENED_MODELS), task
        for model, s in sampled.items():
            assert len(s.prompts) >= 50 and {n for n, _ in s.prompts.values()} == {1}, (task, model)
            (row,) = screen.overall_rows([s])
            assert "[" in row[5] and f"{len(s.prompts)} prompts)" in row[5], (task, model, row[5])
