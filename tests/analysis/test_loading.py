"""Logs -> runs: grouping by configuration, frames equal to the logged records, bad logs skipped
with one line each."""

from __future__ import annotations

import shlex
import shutil
from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.analysis import loading
from lagrseq.errors import LogError
from lagrseq.logs.reader import read_topics
from lagrseq.running import runner
from tests.support.configs import with_episodes


def test_runs_are_grouped_by_what_was_run(runs_dir: Path, shape: tuple[int, int]) -> None:
    TRIALS, _ = shape
    logs = loading.load([runs_dir])
    assert logs.warnings == ()
    assert logs.files == 3 * TRIALS + 1
    methods = [run.key.method for run in logs.runs]
    assert methods == sorted(methods) == ["baseline", "lagr", "lagr-seq", "llm-accuracy"]
    for run in logs.runs:
        config = cfg.from_dict(run.config)
        assert run.key.digest == config.digest()
        assert run.key.provider == "mock" and run.key.preset == "upstream" and run.key.seed == 0
    probe = logs.runs[-1]
    assert probe.key.kind == "accuracy" and probe.samples == 5 and probe.key.variant == "samples-5"
    assert len(probe.queries) == 5 * 8


def test_frames_hold_exactly_the_logged_records(runs_dir: Path, shape: tuple[int, int]) -> None:
    TRIALS, EPISODES = shape
    logs = loading.load([runs_dir])
    run = next(r for r in logs.runs if r.key.method == "lagr-seq")
    assert run.trials == tuple(range(TRIALS)) and run.episodes_per_trial == EPISODES
    first = runs_dir / run.files[0]
    records = read_topics(first, ["/episode", "/query"])
    episodes = run.episodes[run.episodes["trial"] == 0]
    assert episodes["return"].tolist() == [e["return"] for e in records["/episode"]]
    queries = run.queries[run.queries["trial"] == 0]
    assert queries["queried"].tolist() == [q["queried"] for q in records["/query"]]
    assert run.transitions == TRIALS * EPISODES * 50  # upstream horizon, from the statistics
    totals = run.total_per_trial("queries")
    assert totals[0] == sum(e["queries"] for e in records["/episode"])
    assert logs.stats.chunks_decompressed < logs.stats.chunks  # transition chunks left alone


def test_bad_logs_are_skipped_with_one_line_each(
    runs_dir: Path, tmp_path: Path, shape: tuple[int, int]
) -> None:
    TRIALS, EPISODES = shape
    root = tmp_path / "runs"
    shutil.copytree(runs_dir, root)
    lagr_seq = sorted(root.rglob("lagr-seq/*/trial-000.mcap"))[0]
    # a crash leftover, a cut copy, and a trial that was interrupted (Ctrl-C leaves its .partial)
    (lagr_seq.parent / "trial-007.mcap.partial").write_bytes(lagr_seq.read_bytes()[:5000])
    config = cfg.load(
        "cube-stacking", "lagr-seq", "upstream", overrides=[f"run.episodes={EPISODES}"]
    )
    # cut from a longer trial: in log format 3 a short cube trial's transitions are one chunk,
    # so the first half of its file holds no finished episode
    longer = runner.run_one(with_episodes(config, 150), 8, 0, "mock", tmp_path / "longer" / "trial-008.mcap")
    data = longer.path.read_bytes()
    (lagr_seq.parent / "trial-008.mcap").write_bytes(data[: len(data) // 2])
    interrupted = lagr_seq.parent / "trial-009.mcap"

    def stop(_steps: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        runner.run_one(config, 9, 0, "mock", interrupted, on_episode=stop)
    logs = loading.load([root])
    assert len(logs.warnings) == 3
    assert all("\n" not in w and w.endswith("skipped") or "skipped:" in w for w in logs.warnings)
    text = " ".join(logs.warnings)
    # every log is named by its full path, and the recover command can be run as written
    assert f"{lagr_seq.parent / 'trial-007.mcap.partial'}: unfinished log" in text
    interrupted_partial = lagr_seq.parent / "trial-009.mcap.partial"
    assert not interrupted.exists() and interrupted_partial.exists()
    assert f"{interrupted_partial}: unfinished log" in text
    assert f"`lagrseq recover {shlex.quote(str(interrupted_partial))}`" in text, "its flushed episode can be kept"
    cut = lagr_seq.parent / "trial-008.mcap"
    assert f"`lagrseq recover {shlex.quote(str(cut))}` to repair it" in text
    # recover is suggested only where it can do something: the first 5000 bytes hold no episode
    assert "trial-007.mcap.partial: unfinished log" in text
    assert "`lagrseq recover` cannot repair it (no episode was flushed" in text
    # skipped logs are not in the totals, they are counted apart
    clean = loading.load([runs_dir])
    assert logs.skipped == 3 and clean.skipped == 0 and logs.files == clean.files
    assert (logs.bytes, logs.messages) == (clean.bytes, clean.messages)
    run = next(r for r in logs.runs if r.key.method == "lagr-seq")
    assert run.trials == tuple(range(TRIALS))


def test_the_same_trial_twice_is_counted_once(
    runs_dir: Path, tmp_path: Path, shape: tuple[int, int]
) -> None:
    TRIALS, _ = shape
    copy = tmp_path / "copy"
    shutil.copytree(runs_dir, copy)
    logs = loading.load([runs_dir, copy])
    assert len([w for w in logs.warnings if "also in" in w]) == 3 * TRIALS + 1
    clean = loading.load([runs_dir])
    assert logs.skipped == 3 * TRIALS + 1 and logs.files == clean.files
    assert logs.messages == clean.messages, "the skipped copies are not in the totals"
    assert all(w.startswith(str(copy.resolve())) for w in logs.warnings)
    assert all(
        len(run.trials) == (1 if run.key.kind == "accuracy" else TRIALS) for run in logs.runs
    )


def test_missing_path_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="no such MCAP file or directory"):
        loading.load([tmp_path / "nowhere"])


def test_reading_in_worker_processes_gives_the_same_runs(
    runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``replay --jobs N``: the logs read by N spawned processes make the same runs, frames,
    warnings and totals as one process (a damaged log included), in the same order."""
    runs = tmp_path / "runs"
    shutil.copytree(runs_dir, runs)
    damaged = sorted(runs.rglob("trial-001.mcap"))[0]
    damaged.write_bytes(damaged.read_bytes()[:-40])
    one = loading.load([runs], jobs=1)
    monkeypatch.setattr(loading, "PARALLEL_MIN_LOGS", 1)  # a few logs: worker processes all the same
    two = loading.load([runs], jobs=2)
    assert one.warnings == two.warnings and len(one.warnings) == 1
    assert (one.files, one.bytes, one.messages, one.skipped, one.stats) == (two.files, two.bytes, two.messages, two.skipped, two.stats)
    assert [run.key for run in one.runs] == [run.key for run in two.runs]
    for a, b in zip(one.runs, two.runs, strict=True):
        assert (a.files, a.trials, a.transitions, a.config) == (b.files, b.trials, b.transitions, b.config)
        assert a.episodes.equals(b.episodes) and a.queries.equals(b.queries)


def test_the_cycle_collector_is_paused_while_logs_are_read_and_left_as_it_was(
    runs_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Reading makes millions of acyclic objects: the cyclic collector is off meanwhile (each full
    collection would walk the frames read so far), and on again after, unless it was off before."""
    import gc

    seen: list[bool] = []
    real = loading.read_rows

    def watched(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(gc.isenabled())
        return real(*args, **kwargs)

    monkeypatch.setattr(loading, "read_rows", watched)
    assert gc.isenabled()
    clean = loading.load([runs_dir])
    assert seen and not any(seen) and gc.isenabled() and clean.runs
    gc.disable()
    try:
        loading.load([runs_dir])
        assert not gc.isenabled()
    finally:
        gc.enable()
