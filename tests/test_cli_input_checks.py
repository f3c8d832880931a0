"""Commands and options refuse bad input: every bad value,
name, path and combination ends in one line on stderr and exit status 2 before anything runs, and
nothing already written is touched."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq import config as cfg
from lagrseq.errors import ConfigError, UsageError
from lagrseq.study import frontier
from tests.support.cli import cli, files_under, refused

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--set", "run.episodes=2", "--quiet"]
RECORDED = ROOT / "recorded_llm" / "smollm2-135m-cube-t0.jsonl"


# ----------------------------------------------------------------------------- --name (Also:)
BAD_NAMES = ["../../x", "/abs", "a/b", "..", ".", "a\\b", "a\nb", "a\tb", "a\rb", " ", " lead", "trail ", "a\x7fb", "a\x00b", "n" * 201]


@pytest.mark.parametrize("name", BAD_NAMES, ids=[repr(n)[:20] for n in BAD_NAMES])
def test_a_name_that_is_not_one_plain_component_is_refused_before_anything_is_written(tmp_path: Path, name: str) -> None:
    error = refused("run", "cube-stacking", "--method", "baseline", "--trials", "1", "--out", str(tmp_path / "runs"), "--name", name, *SMALL)
    assert "--name" in error and "give" in error
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").rglob("*.mcap*"))
    assert sorted(p.name for p in tmp_path.iterdir()) in ([], ["runs"])


@settings(max_examples=150, deadline=None)
@given(st.text(min_size=0, max_size=80))
def test_check_name_accepts_only_plain_names_and_refuses_the_rest_with_usage_errors(name: str) -> None:
    from lagrseq.running.runner import check_name

    try:
        assert check_name(name) == name
    except UsageError as exc:
        assert "\n" not in str(exc)
        return
    assert name.strip() == name and name not in ("", ".", "..")
    assert not any(ch in name for ch in "/\\") and all(ord(ch) >= 32 and ord(ch) != 127 for ch in name)


# ----------------------------------------------------------------------------- --name reuse
def test_a_reused_name_under_another_configuration_is_refused_for_each_difference(tmp_path: Path) -> None:
    base = ["run", "cube-stacking", "--method", "lagr-seq", "--trials", "2", "--out", str(tmp_path), "--name", "mine", *SMALL]
    assert cli(*base)[0] == 0
    before = files_under(tmp_path)
    for extra, shown in [
        (["--set", "run.episodes=3"], "run.episodes: 2 -> 3"),
        (["--set", 'secondary.policy="thompson"'], 'secondary.policy: "seq" -> "thompson"'),
        (["--set", "secondary.query_cost=0.5"], "secondary.query_cost: 0.0 -> 0.5"),
        (["--provider", "mock:authors-t0"], 'provider: "mock" -> "mock:authors-t0"'),
        (["--preset", "paper"], "env.horizon: 50 -> 100"),
        (["--set", "run.episodes=3", "--executor", "dask", "--jobs", "1"], "run.episodes: 2 -> 3"),  # refused before a cluster starts
    ]:
        error = refused(*base, *extra)
        assert "made by another run" in error and shown in error, error
    assert files_under(tmp_path) == before, "nothing already written is touched"
    status, out, _ = cli(*base)
    assert status == 0 and "2 already complete, skipped" in out


def test_an_unfinished_log_of_another_configuration_is_not_overwritten_by_a_reused_name(tmp_path: Path) -> None:
    """A crash leaves trial-000.mcap.partial (recoverable episodes); a rerun under the same
    --name with another configuration must refuse rather than overwrite it. The same
    configuration reruns the trial, as resume does."""
    base = ["run", "cube-stacking", "--method", "lagr-seq", "--trials", "1", "--out", str(tmp_path), "--name", "mine", "--quiet"]
    assert cli(*base, "--set", "run.episodes=20")[0] == 0
    log = next(tmp_path.rglob("trial-000.mcap"))
    data = log.read_bytes()
    partial = log.with_name(log.name + ".partial")
    partial.write_bytes(data[: len(data) * 2 // 3])  # cut short by a crash, its first episodes flushed
    log.unlink()
    before = files_under(tmp_path)
    error = refused(*base, "--set", "run.episodes=3")
    assert str(partial) in error and "run.episodes: 20 -> 3" in error and "unfinished" in error
    assert files_under(tmp_path) == before
    assert cli(*base, "--set", "run.episodes=20")[0] == 0
    assert not partial.exists() and log.read_bytes() == data


# ----------------------------------------------------------------------------- policies, values and lengths
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--policies", "thompson:query_cost=0.5:query_cost=0.7"], "sets query_cost twice"),
        (["--policies", "random:ask_probability=0.1:budget=3:ask_probability=1"], "sets ask_probability twice"),
        (["--policies", "thompson:budget=nan"], "secondary.budget"),
        (["--policies", "random:p=2"], "FIELD one of"),
        (["--policies", "random:ask_probability=2"], "secondary.ask_probability = 2.0; expected a finite number in [0, 1]"),
        (["--policies", "seq:foo=1"], "FIELD one of"),
        (["--policies", ""], "--policies is empty"),
        (["--policies", ",,"], "--policies is empty"),
        (["--policies", "thompson:query_cost=inf"], "secondary.query_cost = inf"),
        (["--policies", "thompson:min_progress=-3"], "secondary.min_progress = -3"),
        (["--sweep", "thompson:query_cost=0.5,nan"], "secondary.query_cost = nan"),
        (["--sweep", "thompson:query_cost=0.5:query_cost=1,2"], "sets query_cost twice"),
        (["--miss-threshold", "2"], "argument --miss-threshold: expected a finite number in [0, 1]"),
        (["--miss-threshold", "nan"], "argument --miss-threshold"),
        (["--max-cost-usd", "nan"], "argument --max-cost-usd"),
        (["--trials", "0"], "argument --trials"),
        (["--seed", str(2**70)], "argument --seed"),
    ],
)
def test_frontier_refuses_bad_policies_and_values_before_any_trial(tmp_path: Path, args: list[str], message: str) -> None:
    error = refused("frontier", "cube-stacking", "--out", str(tmp_path / "fr"), "--jobs", "1", *SMALL, *args)
    assert message in error, error
    assert not list(tmp_path.rglob("*.mcap*"))


def test_frontier_replay_refuses_a_task_and_bad_policies_it_would_ignore(tmp_path: Path) -> None:
    golden = str(ROOT / "fixtures" / "golden")
    assert "give no TASK" in refused("frontier", "cube-stacking", "--replay", golden, "--out", str(tmp_path))
    assert "policy 'bogus'" in refused("frontier", "--replay", golden, "--out", str(tmp_path), "--policies", "bogus")
    assert not list(tmp_path.iterdir())


KNOB_VALUES = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "-1", "0", "0.5", "1", "2", "1e999", str(2**70), "[1, 2]", "[0, 1]", '"trial"', '"x"', "true", ""]),
    st.text(alphabet="0123456789.-e:=,[]ax", max_size=8),
)


@settings(max_examples=80, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from([*frontier.NAMES, "bogus", ""]), st.lists(st.tuples(st.sampled_from([*frontier.KNOBS, "p", "policy"]), KNOB_VALUES), max_size=3)),
        max_size=4,
    )
)
def test_any_policies_string_gives_valid_configurations_or_one_usage_error(items: list[tuple[str, list[tuple[str, str]]]]) -> None:
    text = ",".join(":".join([name, *(f"{k}={v}" for k, v in knobs)]) for name, knobs in items)
    try:
        variants = frontier.parse_policies(text)
        for variant in variants:
            cfg.load("cube-stacking", variant.method, "upstream", None, variant.overrides())
    except (UsageError, ConfigError) as exc:
        assert "\n" not in str(exc)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--episodes", "-1"], "argument --episodes"),
        (["--episodes", "nan"], "argument --episodes"),
        (["--max-steps", "-2"], "argument --max-steps"),
        (["--max-steps", "1e3"], "argument --max-steps"),
        (["--trials", "0"], "argument --trials"),
        (["--jobs", "0"], "argument --jobs"),
        (["--seed", "-1"], "argument --seed"),
    ],
)
def test_audit_refuses_bad_lengths(tmp_path: Path, args: list[str], message: str) -> None:
    assert message in refused("audit", "cube-stacking", "--out", str(tmp_path / "a"), "--quiet", *args)
    assert not (tmp_path / "a").exists()


# ----------------------------------------------------------------------------- reproduce
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--items", ""], "--items is empty"),
        (["--items", ",,"], "--items is empty"),
        (["--items", "nosuch"], "unknown suite item 'nosuch'"),
        (["--items", "table2,nosuch"], "unknown suite item 'nosuch'"),
        (["--items", "table2", "--formats", "gif"], "argument --formats"),
        (["--items", "fig6a", "--provider", "recorded:{tmp}/missing-store"], "no recorded store at"),
        (["--items", "fig6a", "--provider", "live"], "OPENAI_API_KEY is not set"),
        (["--items", "table2", "--scheduler", "tcp://127.0.0.1:8786"], "--scheduler applies to --executor dask only"),
        (["--items", "table2", "--retries", "-1"], "argument --retries"),
        (["--items", "table2", "--authors-caches", "{tmp}/missing"], "--authors-caches"),
        (["--items", "table2", "--price-table", "{tmp}"], "is a directory"),
    ],
)
def test_reproduce_validates_every_option_before_any_trial(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], message: str) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    out = tmp_path / "out"
    status, stdout, err = cli("reproduce", "--quick", "--out", str(out), *[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert status == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert "expected about" not in stdout, "refused before planning the time of any trial"
    assert not list(tmp_path.rglob("*.mcap*"))


# ----------------------------------------------------------------------------- input files
def _bad_files(tmp_path: Path) -> dict[str, Path]:
    binary = tmp_path / "binary.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    nested = tmp_path / "nested.toml"
    nested.write_text("a = " + "[" * 50_000 + "]" * 50_000 + "\n")
    tables = tmp_path / "tables.toml"
    tables.write_text("a = " + "{x = " * 3000 + "1" + "}" * 3000 + "\n")
    digits = tmp_path / "digits.toml"
    digits.write_text("[env]\nhorizon = " + "9" * 5000 + "\n")
    return {"directory": tmp_path, "binary": binary, "digits": digits, "nested": nested, "inline tables": tables, "missing": tmp_path / "none.toml"}


@pytest.mark.parametrize("option", ["--price-table", "--config"])
@pytest.mark.parametrize("command", ["run", "record", "frontier"])
def test_a_bad_toml_file_is_one_line_whatever_the_provider(tmp_path: Path, command: str, option: str) -> None:
    """A price table is read even when the provider (mock) would never use it."""
    head = {
        "run": ["run", "cube-stacking", "--trials", "1", "--out", str(tmp_path / "o"), *SMALL],
        "record": ["record", "cube-stacking", "--store", str(tmp_path / "s"), "--mode", "none"],
        "frontier": ["frontier", "cube-stacking", "--trials", "1", "--jobs", "1", "--out", str(tmp_path / "o"), *SMALL],
    }[command]
    for what, path in _bad_files(tmp_path).items():
        error = refused(*head, option, str(path))
        assert str(path) in error, (what, error)
    assert not (tmp_path / "o").exists() and not (tmp_path / "s").exists()


# ----------------------------------------------------------------------------- output paths
@pytest.mark.parametrize("where", ["file", "below-file", "proc"])
def test_cache_export_and_frontier_and_audit_outputs_that_cannot_be_written_are_one_line(tmp_path: Path, where: str) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("keep me")
    target = {"file": a_file, "below-file": a_file / "below", "proc": Path("/proc/lagrseq-x")}[where]
    store = tmp_path / "store"
    assert cli("cache", "import", str(RECORDED), "--store", str(store))[0] == 0
    if where != "file":  # exporting over a file replaces it: that is what --out FILE means
        assert str(target) in refused("cache", "export", "--store", str(store), "--out", str(target))
    assert str(target) in refused("frontier", "cube-stacking", "--trials", "1", "--jobs", "1", "--out", str(target), *SMALL)
    assert str(target) in refused("frontier", "--replay", str(ROOT / "fixtures" / "golden"), "--out", str(target))
    assert str(target) in refused("audit", "cube-stacking", "--trials", "1", "--episodes", "1", "--out", str(target), "--quiet")
    directory = tmp_path / "dir"
    directory.mkdir()
    assert str(directory) in refused("cache", "export", "--store", str(store), "--out", str(directory))
    assert a_file.read_text() == "keep me"


# ----------------------------------------------------------------------------- sizes and --set text
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "cube-stacking", "--trials", "1000000000"], "argument --trials: expected an integer in [1, 100000]"),
        (["run", "cube-stacking", "--jobs", "100000"], "argument --jobs: expected an integer in [1, 1024]"),
        (["frontier", "cube-stacking", "--trials", str(10**9)], "argument --trials"),
        (["audit", "cube-stacking", "--jobs", "5000"], "argument --jobs"),
        (["reproduce", "--jobs", "5000"], "argument --jobs"),
        (["record", "cube-stacking", "--store", "{tmp}/s", "--samples", "100000"], "argument --samples: expected an integer in [1, 10000]"),
        (["config", "cube-stacking", "--set", "env.horizon=" + "9" * 5000], "--set env.horizon: the value cannot be read: it holds an integer of more than 4300 digits"),
        (["config", "cube-stacking", "--set", "a" * 5000], "(5002 characters): expected section.field=value"),
        (["config", "cube-stacking", "--set", "env." + "b" * 5000 + "=1"], "unknown field env."),
    ],
)
def test_sizes_that_make_no_sense_and_huge_set_texts_are_one_short_line(tmp_path: Path, args: list[str], message: str) -> None:
    error = refused(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert message in error and len(error) < 400, error
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("option", ["--suite", "--price-table"])
def test_replay_and_reproduce_refuse_every_bad_toml_file_in_one_line(tmp_path: Path, option: str) -> None:
    golden = str(ROOT / "fixtures" / "golden")
    for what, path in _bad_files(tmp_path).items():
        assert str(path) in refused("replay", golden, "--out", str(tmp_path / "rep"), option, str(path)), what
        assert str(path) in refused("reproduce", "--quick", "--items", "table2", "--out", str(tmp_path / "rp"), option, str(path)), what
    assert not (tmp_path / "rep").exists() and not list(tmp_path.rglob("*.mcap*"))


# ----------------------------------------------------------------------------- combinations
@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--model", "gpt-4", "--temperature", "1"], "--model and --temperature"),
        (["--task", "cube-stacking"], "--task"),
        (["--max-tokens", "64"], "--max-tokens"),
        (["--base-url", "http://127.0.0.1:8080/v1"], "--base-url"),
        (["--set", "task.stack_size=11"], "--set"),
    ],
)
def test_pickle_only_options_with_a_jsonl_import_are_refused_before_the_store_is_made(tmp_path: Path, extra: list[str], named: str) -> None:
    error = refused("cache", "import", str(RECORDED), "--store", str(tmp_path / "s"), *extra)
    assert error.startswith(f"lagrseq cache: error: {named} describe") and "--format pkl" in error
    assert not (tmp_path / "s").exists()


def test_states_from_without_from_runs_is_refused(tmp_path: Path) -> None:
    assert "give --from-runs" in refused("record", "cube-stacking", "--store", str(tmp_path / "s"), "--states-from", "/transition", "--mode", "none")


def test_authors_caches_that_are_a_file_or_a_folder_of_garbage_are_one_line_and_run_nothing(tmp_path: Path) -> None:
    import pickle

    garbage = tmp_path / "garbage"
    (garbage / "sub").mkdir(parents=True)
    (garbage / "cache0.0.pkl").write_bytes(b"\x80\x04" + os.urandom(64))
    (garbage / "x.pkl").write_bytes(pickle.dumps([("k", os.getcwd)]))  # references a function: never loaded
    (garbage / "sub" / "loop").symlink_to(garbage)
    os.mkfifo(garbage / "fifo.pkl")  # opening it would block for ever
    (garbage / "zero.pkl").symlink_to("/dev/zero")
    a_file = tmp_path / "file.pkl"
    a_file.write_bytes(b"not a pickle")
    for caches in (a_file, garbage, tmp_path / "missing"):
        error = refused("reproduce", "--quick", "--items", "table2", "--out", str(tmp_path / "out"), "--quiet", "--authors-caches", str(caches))
        assert f"--authors-caches {caches}" in error
    assert not list(tmp_path.rglob("*.mcap*"))


# ----------------------------------------------------------------------------- --render
def test_render_is_checked_before_any_trial(tmp_path: Path) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("keep me")
    head = ["run", "--trials", "1", "--out", str(tmp_path / "r"), *SMALL]
    assert "arm-arrangement only" in refused(head[0], "cube-stacking", *head[1:], "--render", str(tmp_path / "frames"))
    for bad in (a_file, a_file / "below", Path("/proc/lagrseq-x")):
        assert f"--render {bad}" in refused(head[0], "arm-arrangement", *head[1:], "--render", str(bad))
    assert a_file.read_text() == "keep me" and not list(tmp_path.rglob("*.mcap*"))


# ----------------------------------------------------------------------------- --base-url
@pytest.mark.parametrize("url", ["http://[bad", "http://[::1", "ftp://127.0.0.1/v1", "127.0.0.1:8080", "http://127.0.0.1:99999/v1", "http://", "http://a b/v1"])
@pytest.mark.parametrize("command", ["run", "frontier"])
def test_a_bad_base_url_is_one_line_before_any_trial(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, url: str, command: str) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-not-a-key")
    extra = ["--policies", "always", "--jobs", "1"] if command == "frontier" else []
    error = refused(command, "cube-stacking", "--provider", "live", "--base-url", url, "--trials", "1", "--out", str(tmp_path / "o"), *SMALL, *extra)
    assert "URL" in error or "base URL" in error, error
    assert not list(tmp_path.rglob("*.mcap*"))
