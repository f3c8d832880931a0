"""The LaGR-SEQ loop: determinism, query counts per method, guidance, P < 1."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.logs.reader import iter_messages, read_topic
from lagrseq.running.runner import run_one, run_trials


def small(method: str, preset: str = "upstream", *overrides: str) -> cfg.ExperimentConfig:
    return cfg.load("cube-stacking", method, preset, overrides=["run.episodes=30", *overrides])


def events(path: Path) -> list[tuple[str, dict]]:
    return list(iter_messages(path))


@pytest.mark.parametrize("method", ["baseline", "lagr", "lagr-seq"])
def test_same_seed_gives_identical_events(tmp_path: Path, method: str) -> None:
    config = small(method)
    a = run_one(config, 2, 7, "mock", tmp_path / "a.mcap")
    b = run_one(config, 2, 7, "mock", tmp_path / "b.mcap")
    assert events(a.path) == events(b.path)
    c = run_one(config, 3, 7, "mock", tmp_path / "c.mcap")
    assert events(c.path) != events(a.path)


def test_trial_streams_do_not_depend_on_the_number_of_trials(tmp_path: Path) -> None:
    config = small("lagr-seq")
    run_trials(config, 3, 0, "mock", tmp_path / "three")
    run_trials(config, 1, 0, "mock", tmp_path / "one")
    assert events(tmp_path / "three" / "trial-000.mcap") == events(tmp_path / "one" / "trial-000.mcap")


def test_seq_asks_less_than_lagr_and_baseline_never(tmp_path: Path) -> None:
    totals = {}
    for method in ("baseline", "lagr", "lagr-seq"):
        results = run_trials(cfg.load("cube-stacking", method, "upstream"), 3, 0, "mock", tmp_path / method)
        totals[method] = sum(r.queries for r in results) / 3
        queries = [q for r in results for q in read_topic(r.path, "/query") if q["queried"]]
        assert len(queries) == sum(r.queries for r in results)
    assert totals["baseline"] == 0
    assert totals["lagr-seq"] < 0.6 * totals["lagr"]


def test_upstream_cube_queries_once_per_new_stack_height(tmp_path: Path) -> None:
    result = run_one(small("lagr"), 0, 0, "mock", tmp_path / "t.mcap")
    for episode in range(30):
        heights = [
            len(q["state"]) for q in read_topic(result.path, "/query") if q["episode"] == episode
        ]
        assert heights == sorted(set(heights)) and all(h >= 1 for h in heights)
        # the mock is right from a stack of 4, so LaGR stops asking there
        assert not heights or heights[-1] <= 4


def test_guidance_starts_the_step_after_an_accepted_answer(tmp_path: Path) -> None:
    result = run_one(small("lagr"), 0, 1, "mock", tmp_path / "t.mcap")
    transitions = read_topic(result.path, "/transition")
    accepted = [q for q in read_topic(result.path, "/query") if q["accepted"]]
    assert accepted
    by_step = {t["global_step"]: t for t in transitions}
    for query in accepted:
        assert not by_step[query["global_step"]]["guided"]
        assert by_step[query["global_step"] + 1]["guided"] or by_step[query["global_step"]]["truncated"]


def test_query_records_carry_the_contract_fields(tmp_path: Path) -> None:
    result = run_one(small("lagr-seq"), 0, 0, "mock", tmp_path / "t.mcap")
    queries = read_topic(result.path, "/query")
    sent = [q for q in queries if q["queried"]]
    skipped = [q for q in queries if not q["queried"]]
    assert sent and skipped
    assert all(q["decision"] == 0 and q["answer"] is None for q in skipped)
    for q in sent:
        assert q["source"] == "mock" and q["provider"] == "mock" and q["prompt_tokens"] > 0
        assert len(q["prompt_sha256"]) == 64
        assert q["query_reward"] == (1.0 if q["accepted"] else -1.0)


def test_follow_probability_below_one_mixes_in_primary_actions(tmp_path: Path) -> None:
    full = run_one(small("lagr", "paper"), 0, 0, "mock", tmp_path / "p1.mcap")
    half = run_one(small("lagr", "paper", "lagr.follow_probability=0.5"), 0, 0, "mock", tmp_path / "p5.mcap")

    def guided_share(path: Path) -> float:
        episodes = read_topic(path, "/episode")
        steps_after = sum(e["length"] for e in episodes if e["accepted"] or e["guided_steps"])
        return sum(e["guided_steps"] for e in episodes) / max(steps_after, 1)

    assert guided_share(half.path) < guided_share(full.path)


def test_logistic_query_reward(tmp_path: Path) -> None:
    config = small("lagr-seq", "paper", 'secondary.query_reward="logistic"')
    result = run_one(config, 0, 0, "mock", tmp_path / "t.mcap")
    sent = [q for q in read_topic(result.path, "/query") if q["queried"]]
    assert sent
    for q in sent:
        expected = 1 / (1 + pytest.importorskip("math").exp(-20 * (q["evaluation"] - 0.9)))
        assert q["query_reward"] == pytest.approx(expected)


def test_paper_preset_learns_to_complete_the_stack(tmp_path: Path) -> None:
    result = run_one(cfg.load("cube-stacking", "lagr-seq", "paper"), 0, 0, "mock", tmp_path / "t.mcap")
    episodes = read_topic(result.path, "/episode")
    assert all(e["solved"] for e in episodes[-10:])
    assert episodes[-1]["length"] == 8  # the complete stack in 8 steps, then the episode ends


def test_max_steps_bounds_the_trial(tmp_path: Path) -> None:
    result = run_one(small("baseline", "upstream", "run.max_steps=120"), 0, 0, "mock", tmp_path / "t.mcap")
    assert result.steps == 120
    assert [e["length"] for e in read_topic(result.path, "/episode")] == [50, 50, 20]


def test_stop_at_first_solve_ends_the_trial_with_its_first_solved_episode(tmp_path: Path) -> None:
    """``run.stop_at = "first_solve"``: the trial is the full trial's events up to the end of its
    first solved episode, to the record (the same streams, only cut), and the default never stops
    early (the configuration's digest without the field is the one it always had)."""
    full = small("lagr", "paper")
    stopped = small("lagr", "paper", 'run.stop_at="first_solve"')
    before = json.loads(full.to_json())  # a configuration written before the field existed
    before["run"].pop("stop_at", None)  # absent at its default (a log made before the field reads the same)
    assert full.run.stop_at == "" and cfg.config_digest(before) == full.digest()
    assert stopped.digest() != full.digest()
    a = run_one(full, 0, 3, "mock", tmp_path / "full.mcap")
    b = run_one(stopped, 0, 3, "mock", tmp_path / "stopped.mcap")
    episodes = read_topic(b.path, "/episode")
    assert [e["solved"] for e in episodes] == [False] * (len(episodes) - 1) + [True]
    assert b.episodes == len(episodes) < a.episodes == 30
    first = next(e for e in read_topic(a.path, "/episode") if e["solved"])
    assert b.steps == first["global_step"] and b.queries == sum(int(e["queries"]) for e in episodes)
    cut = [(topic, message) for topic, message in events(a.path) if int(message.get("episode", 0)) < len(episodes)]
    assert events(b.path) == cut
    with pytest.raises(cfg.ConfigError, match="stop_at"):
        small("lagr", "paper", 'run.stop_at="never"')


def test_a_sink_with_only_write_and_close_gets_every_record_in_the_logs_order(tmp_path: Path) -> None:
    """The loop hands its sink every record as it comes, through ``write`` alone (the sink
    buffers an episode itself), and closes it: a sink of nothing else runs a trial and gets the
    transitions, decisions and episodes the MCAP log of the same trial holds."""
    from lagrseq.logs.events import EpisodeEvent, NotAsked, QueryEvent, Transition
    from lagrseq.loop.experiment import run_trial
    from lagrseq.running.wiring import trial_parts

    class Recording:
        def __init__(self) -> None:
            self.events: list[object] = []
            self.closed = False

        def write(self, event: object) -> None:
            self.events.append(event)

        def close(self) -> None:
            self.closed = True

        def __enter__(self) -> Recording:
            return self

        def __exit__(self, *exc: object) -> None:
            self.close()

    config = small("lagr-seq")
    sink = Recording()
    result = run_trial(trial_parts(config, 0, 0, "mock", lambda: sink), tmp_path / "unused.mcap")  # type: ignore[arg-type]
    logged = run_one(config, 0, 0, "mock", tmp_path / "t.mcap")
    assert sink.closed and not (tmp_path / "unused.mcap").exists()
    steps = [(e.global_step, e.action, e.reward) for e in sink.events if type(e) is Transition]
    assert steps == [(t["global_step"], t["action"], t["reward"]) for t in read_topic(logged.path, "/transition")]
    assert len(steps) == result.steps == logged.steps
    decisions = [(e.global_step, 0 if type(e) is NotAsked else e.decision)  # type: ignore[attr-defined]
                 for e in sink.events if type(e) in (NotAsked, QueryEvent)]
    assert decisions == [(q["global_step"], q["decision"]) for q in read_topic(logged.path, "/query")]
    assert {d for _, d in decisions} == {0, 1}
    episodes = [e.length for e in sink.events if type(e) is EpisodeEvent]
    assert episodes == [e["length"] for e in read_topic(logged.path, "/episode")] and len(episodes) == 30
