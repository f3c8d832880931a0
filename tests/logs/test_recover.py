"""Crash safety: a writer killed with SIGKILL leaves a log that `lagrseq recover` repairs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import lagrseq
from lagrseq import config as cfg
from lagrseq import runner
from lagrseq.errors import LogError
from lagrseq.logs.reader import read_info, read_topics
from lagrseq.logs.recover import default_output, recover

ROOT = Path(lagrseq.__file__).resolve().parents[1]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lagrseq", *args],
        env=_env(),
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
    )


def _finished_log(tmp_path: Path, episodes: int = 30) -> Path:
    config = cfg.load(
        "cube-stacking", "lagr-seq", "upstream", overrides=[f"run.episodes={episodes}"]
    )
    path = tmp_path / "complete" / "trial-000.mcap"
    runner.run_one(config, 0, 0, "mock", path)
    return path


def test_sigkill_mid_run_is_recovered_with_every_flushed_episode(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    writer = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lagrseq",
            "run",
            "cube-stacking",
            "--method",
            "lagr-seq",
            "--trials",
            "1",
            "--set",
            "run.episodes=1000000",
            "--out",
            str(out),
            "--quiet",
        ],
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        partial: Path | None = None
        while time.monotonic() < deadline:
            found = list(out.rglob("*.mcap.partial"))
            if found and found[0].stat().st_size > 300_000:
                partial = found[0]
                break
            time.sleep(0.05)
        assert partial is not None, "the writer never got going"
    finally:
        writer.send_signal(signal.SIGKILL)
        writer.wait(timeout=30)
    assert writer.returncode == -signal.SIGKILL
    with pytest.raises(LogError, match="recover"):
        read_info(partial)

    result = _cli("recover", str(partial))
    assert result.returncode == 0, result.stderr
    recovered = default_output(partial)
    assert recovered.name == "trial-000.mcap"
    info = read_info(recovered)
    assert info.status["status"] == "recovered"
    topics = read_topics(recovered, ["/episode", "/query", "/transition"])
    episodes = topics["/episode"]
    assert len(episodes) > 10
    assert [e["episode"] for e in episodes] == list(range(len(episodes)))
    # Every transition kept belongs to a flushed episode, and all of each such episode is there.
    assert len(topics["/transition"]) == sum(e["length"] for e in episodes)
    assert max(t["episode"] for t in topics["/transition"]) == episodes[-1]["episode"]

    # Same seed, same config: the recovered episodes are exactly the first episodes of a run.
    config = cfg.from_dict(info.config)
    reference = tmp_path / "reference.mcap"
    runner.run_one(runner.with_episodes(config, len(episodes)), 0, 0, "mock", reference)
    expected = read_topics(reference, ["/episode", "/query"])
    assert episodes == expected["/episode"]
    assert topics["/query"] == expected["/query"]


@pytest.mark.parametrize("fraction", [0.13, 0.5, 0.77, 0.999])
def test_truncation_anywhere_keeps_the_flushed_episodes(tmp_path: Path, fraction: float) -> None:
    complete = _finished_log(tmp_path)
    data = complete.read_bytes()
    partial = tmp_path / "trial-000.mcap.partial"
    partial.write_bytes(data[: int(len(data) * fraction)])
    result = recover(partial)
    assert result.path == tmp_path / "trial-000.mcap"
    kept = read_topics(result.path, ["/episode"])["/episode"]
    full = read_topics(complete, ["/episode"])["/episode"]
    assert 0 < len(kept) <= len(full)
    if fraction < 0.9:
        assert len(kept) < len(full)
    assert kept == full[: len(kept)]
    assert result.episodes == len(kept)


def test_flipped_bytes_mid_file_give_one_clear_line(tmp_path: Path) -> None:
    complete = _finished_log(tmp_path)
    data = bytearray(complete.read_bytes())
    middle = len(data) // 2
    for i in range(middle, middle + 64):
        data[i] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    with pytest.raises(LogError, match="corrupt at byte .* cannot repair"):
        recover(damaged)
    result = _cli("recover", str(damaged))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "corrupt" in lines[0] and "Traceback" not in result.stderr
    assert damaged.read_bytes() == bytes(data), "a refused recovery must not touch the file"


def test_complete_log_and_non_mcap_are_refused(tmp_path: Path) -> None:
    complete = _finished_log(tmp_path, episodes=3)
    with pytest.raises(LogError, match="nothing to recover"):
        recover(complete)
    junk = tmp_path / "junk.mcap.partial"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(LogError, match="not an MCAP file"):
        recover(junk)


def test_recover_never_overwrites_an_existing_log(tmp_path: Path) -> None:
    complete = _finished_log(tmp_path, episodes=10)
    partial = complete.with_name(complete.name + ".partial")
    partial.write_bytes(complete.read_bytes()[: complete.stat().st_size // 2])
    with pytest.raises(LogError, match="exists already"):
        recover(partial)
    elsewhere = recover(partial, tmp_path / "elsewhere.mcap")
    assert read_info(elsewhere.path).status["status"] == "recovered"


def test_in_place_repair_keeps_the_original(tmp_path: Path) -> None:
    complete = _finished_log(tmp_path, episodes=10)
    cut = tmp_path / "cut.mcap"
    original = complete.read_bytes()[: complete.stat().st_size // 2]
    cut.write_bytes(original)
    result = recover(cut)
    assert result.path == cut and result.backup == tmp_path / "cut.mcap.truncated"
    assert result.backup.read_bytes() == original
    assert read_info(cut).status["status"] == "recovered"
