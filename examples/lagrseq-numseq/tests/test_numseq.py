"""The example plugin, installed (``pip install -e examples/lagrseq-numseq``): its parts alone,
then through lagrseq's own command line in fresh interpreters (lagrseq finds it by entry point)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from lagrseq_numseq.env import NumberSequenceEnv
from lagrseq_numseq.policy import Backoff
from lagrseq_numseq.task import NumberSequence, extrapolate

from lagrseq.config import load
from lagrseq.registry import POLICIES, TASKS

TASK = NumberSequence(start=2, step=3, length=6, values=20)


def lagrseq(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "lagrseq", *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_the_mock_continues_a_prefix_and_its_answer_parses_to_the_target() -> None:
    rng = np.random.default_rng(0)
    answer = extrapolate(TASK.prompt((2, 5)), 0.0, rng)
    assert answer == "[2, 5, 8, 11, 14, 17]"
    parsed = TASK.parse(answer)
    assert parsed.ok and TASK.evaluate(parsed.solution) == 1.0
    assert TASK.evaluate(TASK.parse(extrapolate(TASK.prompt(()), 0.0, rng)).solution) == 0.0  # 0, 1, 2 ...: no position right


@given(st.text(max_size=200))
def test_the_parser_never_raises(text: str) -> None:
    parsed = TASK.parse(text)
    assert parsed.ok == (parsed.solution is not None)


def test_the_env_appends_only_the_right_number_and_pays_the_bonus_at_the_end() -> None:
    env = NumberSequenceEnv(TASK, horizon=20, bonus=1.0)
    _, info = env.reset(seed=0)
    assert info["pattern"] == ()
    _, reward, terminated, _, info = env.step(7)
    assert (reward, terminated, info["pattern"]) == (0.0, False, ())
    for number in TASK.target:
        assert TASK.guidance(info["pattern"], TASK.target) == number
        _, reward, terminated, _, info = env.step(number)
    assert terminated and info["pattern"] == TASK.target and reward == pytest.approx(1 / 6 + 1.0)
    with pytest.raises(ValueError, match="outside Discrete"):
        env.step(20)


def test_backoff_halves_after_a_rejected_answer_and_resets_every_episode() -> None:
    class Context:
        def __init__(self, episode: int) -> None:
            self.episode, self.rng, self.accepted = episode, np.random.default_rng(0), False

    policy = Backoff(0.8)
    policy.decide(Context(0))
    policy.update(Context(0), 1, -1.0)
    policy.update(Context(0), 1, -1.0)
    assert policy.probability == pytest.approx(0.2)
    policy.decide(Context(1))
    assert policy.probability == pytest.approx(0.8)
    slower = Backoff(0.8, factor=0.75)
    slower.decide(Context(0))
    slower.update(Context(0), 1, -1.0)
    assert slower.probability == pytest.approx(0.6)


def test_lagrseq_finds_the_task_and_the_policy_by_entry_point() -> None:
    assert "number-sequence" in TASKS.names() and "backoff" in POLICIES.names()
    config = load("number-sequence", "lagr-seq", "paper", overrides=['secondary.policy="backoff"', "task.length=4"])
    assert config.task.length == 4 and config.secondary.policy == "backoff"
    assert config.secondary.knob("backoff_factor") == 0.5  # its own knob, at its default
    tuned = load("number-sequence", "lagr-seq", "paper", overrides=['secondary.policy="backoff"', "secondary.backoff_factor=0.25"])
    assert tuned.secondary.knob("backoff_factor") == 0.25 and tuned.to_dict()["secondary"]["knobs"] == {"backoff_factor": 0.25}


def test_backoffs_own_knob_through_set_and_the_frontier(tmp_path: Path) -> None:
    """backoff_factor is set with --set and with the frontier's backoff:backoff_factor=V, logged
    in the configuration; a value out of range or of the wrong type is one line, exit 2."""
    from lagrseq.logs.reader import read_info

    small = ["--trials", "2", "--jobs", "1", "--quiet"]
    run = lagrseq("run", "number-sequence", "--method", "lagr-seq", "--set", 'secondary.policy="backoff"', "--set", "secondary.backoff_factor=0.25",
                  *small, "--out", str(tmp_path / "runs"), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    logs = sorted((tmp_path / "runs").rglob("trial-*.mcap"))
    assert len(logs) == 2
    assert all(json.loads(read_info(log).run["config"])["secondary"]["knobs"] == {"backoff_factor": 0.25} for log in logs)
    frontier = lagrseq("frontier", "number-sequence", "--policies", "always,backoff:backoff_factor=0.25", *small, "--no-matched-random",
                       "--out", str(tmp_path / "fr"), cwd=tmp_path)
    assert frontier.returncode == 0, frontier.stderr
    assert "backoff (backoff_factor 0.25)" in frontier.stdout, frontier.stdout
    for bad, message in [("secondary.backoff_factor=2", "out of range"), ('secondary.backoff_factor="half"', "wrong type")]:
        refused = lagrseq("run", "number-sequence", "--set", 'secondary.policy="backoff"', "--set", bad, *small, "--out", str(tmp_path / "bad"), cwd=tmp_path)
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and message in refused.stderr, refused.stderr


def test_plugins_run_frontier_and_replay_through_the_command_line(tmp_path: Path) -> None:
    listed = lagrseq("plugins", cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert "number-sequence     lagrseq-numseq 0.1.0" in listed.stdout
    assert "backoff   lagrseq-numseq 0.1.0" in listed.stdout
    run = lagrseq("run", "number-sequence", "--method", "lagr-seq", "--provider", "mock", "--trials", "2", "--jobs", "1", "--quiet", "--out", str(tmp_path / "runs"), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert len(list((tmp_path / "runs").rglob("trial-*.mcap"))) == 2
    frontier = lagrseq("frontier", "number-sequence", "--policies", "always,backoff", "--trials", "2", "--jobs", "1", "--quiet", "--out", str(tmp_path / "fr"), cwd=tmp_path)
    assert frontier.returncode == 0, frontier.stderr
    assert "backoff" in frontier.stdout and "always" in frontier.stdout
    for logs in ("runs", "fr"):
        replayed = lagrseq("replay", str(tmp_path / logs), "--out", str(tmp_path / f"report-{logs}"), cwd=tmp_path)
        assert replayed.returncode == 0, replayed.stderr
    again = lagrseq("frontier", "--replay", str(tmp_path / "fr"), "--out", str(tmp_path / "again"), cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    variants = json.loads((tmp_path / "fr" / "frontier.json").read_text())
    # the protocol adds random at backoff's matched query rate beside the policies asked for
    assert [(v["policy"], v["method"]) for v in variants][:2] == [("always", "lagr"), ("backoff", "lagr-seq")]
    assert all(v["policy"].startswith("random:ask_probability=") for v in variants[2:] if "policy" in v)
    assert list((tmp_path / "again").glob("*.png"))


def test_the_tasks_own_suite_is_run_by_name_and_drawn_by_replay_without_a_suite_flag(tmp_path: Path) -> None:
    """The task ships ``suite.toml`` (``TaskSpec.suite``): ``reproduce --suite number-sequence``
    runs it, and ``replay`` of its logs draws its figures with no ``--suite``, the paper's items
    left out in one line instead of 23 "not run" lines."""
    made = lagrseq("reproduce", "--suite", "number-sequence", "--quick", "--jobs", "1", "--quiet", "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    assert "2 of 2 suite items made" in made.stdout, made.stdout
    replayed = lagrseq("replay", str(tmp_path / "out" / "runs"), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert replayed.returncode == 0, replayed.stderr
    assert "2 of 2 suite items made from 6 logs" in replayed.stdout, replayed.stdout
    assert "not run" not in replayed.stdout, replayed.stdout
    left_out = [line for line in replayed.stdout.splitlines() if "paper's suite" in line]
    assert len(left_out) == 1 and "left out: no log is of its tasks" in left_out[0], replayed.stdout
    for item in ("numseq-returns", "numseq-queries"):
        assert (tmp_path / "report" / "figures" / f"{item}.png").stat().st_size > 0
        assert (tmp_path / "report" / "figures" / f"{item}.csv").read_text().count("\n") > 1
    assert "Number sequence: return per episode" in (tmp_path / "report" / "index.md").read_text()
    # a task that ships no suite, or a name that is neither file nor task: one line, exit 2
    for bad, message in [("cube-stacking", "ships no suite of its own"), ("no-such-thing", "no such suite file")]:
        refused = lagrseq("replay", str(tmp_path / "out" / "runs"), "--suite", bad, "--out", str(tmp_path / "bad"), cwd=tmp_path)
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and message in refused.stderr, refused.stderr


def test_the_env_counts_refused_numbers_in_its_own_episode_field() -> None:
    env = NumberSequenceEnv(TASK, horizon=20, bonus=1.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(7)
    _, _, _, _, info = env.step(2)
    _, _, _, _, info = env.step(3)
    assert info["log_episode"] == {"wrong_numbers": 2}
    _, info = env.reset()
    assert "log_episode" not in info
    assert TASKS.get("number-sequence").episode_fields == {"wrong_numbers": "integer"}


def test_wrong_numbers_is_logged_under_the_tasks_schema_and_replayed_into_the_runs_csv(tmp_path: Path) -> None:
    """The MCAP (read with the plain mcap library, as Foxglove reads it) holds wrong_numbers in
    every /episode record and its schema; replay's runs table and CSV have its mean per episode."""
    import csv

    from mcap.reader import make_reader

    run = lagrseq("run", "number-sequence", "--method", "lagr-seq", "--trials", "2", "--jobs", "1", "--quiet", "--out", str(tmp_path / "runs"), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    per_trial = []
    for log in sorted((tmp_path / "runs").rglob("trial-*.mcap")):
        with log.open("rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            assert summary is not None
            (channel,) = [c for c in summary.channels.values() if c.topic == "/episode"]
            schema = json.loads(summary.schemas[channel.schema_id].data)
            assert schema["properties"]["wrong_numbers"]["type"] == ["integer", "null"]
            episodes = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/episode"])]
        assert episodes and all(type(e["wrong_numbers"]) is int and e["wrong_numbers"] <= e["length"] for e in episodes)
        per_trial.append(sum(e["wrong_numbers"] for e in episodes) / len(episodes))
    replayed = lagrseq("replay", str(tmp_path / "runs"), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert replayed.returncode == 0, replayed.stderr
    with (tmp_path / "report" / "tables" / "runs.csv").open() as file:
        (row,) = list(csv.DictReader(file))
    assert float(row["wrong_numbers_per_episode_mean"]) == pytest.approx(sum(per_trial) / len(per_trial), rel=1e-4)
    assert "wrong_numbers per episode" in (tmp_path / "report" / "tables" / "runs.md").read_text()


def test_another_tasks_profile_and_another_policys_knob_are_refused_in_one_line(tmp_path: Path) -> None:
    """A mock profile belongs to its task and a knob to its policy: each refused before anything
    is made (no --out folder), one line, exit 2."""
    small = ["--trials", "1", "--jobs", "1", "--quiet"]
    for args, message in [
        (["run", "number-sequence", "--provider", "mock:authors-t0"], "mock profile 'authors-t0' is not one of task number-sequence's"),
        (["frontier", "number-sequence", "--policies", "always,backoff:query_reward=logistic"], "query_reward is a knob of seq, thompson, not of backoff"),
        (["frontier", "number-sequence", "--policies", "always,backoff:backoff_factor=2"], "secondary.backoff_factor = 2 is out of range"),
    ]:
        out = tmp_path / "out"
        refused = lagrseq(*args, *small, "--out", str(out), cwd=tmp_path)
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and message in refused.stderr, refused.stderr
        assert not out.exists()
    shown = lagrseq("config", "number-sequence", "--set", 'secondary.policy="backoff"', cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert "\nbackoff_factor = 0.5  # what the asking probability is multiplied by after a rejected answer (0.5: halved); a knob of policy backoff, not set (default 0.5)\n" in shown.stdout
    listed = lagrseq("plugins", cwd=tmp_path)
    assert "      knob backoff_factor = 0.5: what the asking probability is multiplied by" in listed.stdout
