"""Crash safety: a writer killed with SIGKILL leaves a log that `lagrseq recover` repairs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

import lagrseq
from lagrseq import config as cfg
from lagrseq.errors import LogError
from lagrseq.logs.reader import read_info, read_topics
from lagrseq.logs.recover import default_output, recover
from lagrseq.running import runner
from tests.support.configs import with_episodes

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


def _finished_log(tmp_path: Path, episodes: int = 150) -> Path:
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
    runner.run_one(with_episodes(config, len(episodes)), 0, 0, "mock", reference)
    expected = read_topics(reference, ["/episode", "/query"])
    assert episodes == expected["/episode"]
    assert topics["/query"] == expected["/query"]


@pytest.mark.parametrize("fraction", [0.2, 0.5, 0.77, 0.999])
def test_truncation_anywhere_keeps_the_flushed_episodes(tmp_path: Path, fraction: float) -> None:
    complete = _finished_log(tmp_path, episodes=300)  # chunks of many episodes: a first one before 20%
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
    with complete.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    # the middle of the middle transitions chunk: damage inside the data, not a cut-off
    chunks = sorted((i for i in summary.chunk_indexes if i.compression == "zstd"), key=lambda i: i.chunk_start_offset)
    chunk = chunks[len(chunks) // 2]
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
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
    complete = _finished_log(tmp_path, episodes=150)  # a chunk written before the middle
    partial = complete.with_name(complete.name + ".partial")
    partial.write_bytes(complete.read_bytes()[: complete.stat().st_size // 2])
    with pytest.raises(LogError, match="exists already"):
        recover(partial)
    elsewhere = recover(partial, tmp_path / "elsewhere.mcap")
    assert read_info(elsewhere.path).status["status"] == "recovered"


def test_in_place_repair_keeps_the_original(tmp_path: Path) -> None:
    complete = _finished_log(tmp_path, episodes=150)  # a chunk written before the middle
    cut = tmp_path / "cut.mcap"
    original = complete.read_bytes()[: complete.stat().st_size // 2]
    cut.write_bytes(original)
    result = recover(cut)
    assert result.path == cut and result.backup == tmp_path / "cut.mcap.truncated"
    assert result.backup.read_bytes() == original
    assert read_info(cut).status["status"] == "recovered"


# ------------------------------------------------------------------------------------------
# Files that are not only cut short; several files; where the result goes; a full disk
# ------------------------------------------------------------------------------------------
GOLDEN = ROOT / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"


def test_a_cut_log_with_garbage_after_it_keeps_its_flushed_episodes(tmp_path: Path) -> None:
    data = GOLDEN.read_bytes()
    for tail in (b"\x00" * 700, b"\x05" + b"\xff" * 40, b"garbage " * 30):
        partial = tmp_path / "trial-000.mcap.partial"
        partial.write_bytes(data[:13000] + tail)
        result = recover(partial)
        kept = read_topics(result.path, ["/episode"])["/episode"]
        assert 0 < len(kept) < 4 and result.episodes == len(kept)
        assert kept == read_topics(GOLDEN, ["/episode"])["/episode"][: len(kept)]
        assert read_info(result.path).status["status"] == "recovered"
        result.path.unlink()


def test_recover_all_goes_on_past_a_bad_file(tmp_path: Path) -> None:
    from lagrseq.logs.recover import recover_all

    data = GOLDEN.read_bytes()
    junk = tmp_path / "a.mcap.partial"
    junk.write_bytes(b"not an mcap file at all")
    short = tmp_path / "b.mcap"
    short.write_bytes(data[:-1])
    intact = tmp_path / "c.mcap"
    intact.write_bytes(data)
    outcomes = recover_all([junk, short, intact])
    assert [o.status for o in outcomes] == ["failed", "recovered", "intact"]
    assert [o.ok for o in outcomes] == [False, True, True]
    assert all("\n" not in o.message and str(o.source) in o.message for o in outcomes)
    assert "not an MCAP file" in outcomes[0].message
    assert outcomes[1].result is not None and read_info(short).complete
    assert intact.read_bytes() == data and junk.read_bytes() == b"not an mcap file at all"


def test_out_may_be_an_existing_directory(tmp_path: Path) -> None:
    from lagrseq.errors import UsageError
    from lagrseq.logs.recover import recover_all

    data = GOLDEN.read_bytes()
    partial = tmp_path / "trial-003.mcap.partial"
    partial.write_bytes(data[:13000])
    cut = tmp_path / "trial-004.mcap"
    cut.write_bytes(data[:-5])
    out = tmp_path / "out"
    out.mkdir()
    outcomes = recover_all([partial, cut], out)
    assert [o.status for o in outcomes] == ["recovered", "recovered"]
    assert read_info(out / "trial-003.mcap").status["status"] == "recovered"
    assert read_info(out / "trial-004.mcap").complete
    assert cut.read_bytes() == data[:-5], "with --out the source is left alone"
    with pytest.raises(LogError, match=r"trial-003.mcap exists already; recover never overwrites a log: give --out a new file name or another directory"):
        recover(partial, out)
    with pytest.raises(UsageError, match="not an existing directory"):
        recover_all([partial, cut], tmp_path / "one.mcap")


def test_a_full_disk_leaves_the_original_and_no_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno

    data = GOLDEN.read_bytes()[:-1]
    cut = tmp_path / "trial-000.mcap"
    cut.write_bytes(data)
    real_write = os.write
    calls = []

    def full_disk(fd: int, chunk: bytes) -> int:
        calls.append(len(chunk))
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, bytes(chunk)[:100])  # a short write, then the disk is full

    monkeypatch.setattr(os, "write", full_disk)
    with pytest.raises(LogError) as info:
        recover(cut)
    monkeypatch.undo()
    message = str(info.value)
    assert "\n" not in message and "No space left on device" in message
    assert "trial-000.mcap.recovering" in message and f"{cut} was left as it was" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trial-000.mcap"]
    assert cut.read_bytes() == data

    # the rename that swaps the files in fails: the original is put back
    real_replace = os.replace

    def no_rename(src: str | Path, dst: str | Path) -> None:
        if str(src).endswith(".recovering"):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(dst))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", no_rename)
    with pytest.raises(LogError, match="Read-only file system"):
        recover(cut)
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trial-000.mcap"]
    assert cut.read_bytes() == data


def test_an_unwritable_out_is_one_line(tmp_path: Path) -> None:
    partial = tmp_path / "trial-000.mcap.partial"
    partial.write_bytes(GOLDEN.read_bytes()[:13000])
    below_a_file = tmp_path / "trial-000.mcap.partial" / "x.mcap"
    with pytest.raises(LogError, match=r"x.mcap.recovering: cannot write the recovered log \(Not a directory\)"):
        recover(partial, below_a_file)
    assert partial.read_bytes() == GOLDEN.read_bytes()[:13000]


def test_an_unwritable_out_never_suggests_passing_out(tmp_path: Path) -> None:
    partial = tmp_path / "trial-000.mcap.partial"
    partial.write_bytes(GOLDEN.read_bytes()[:13000])
    with pytest.raises(LogError) as given:
        recover(partial, tmp_path / "trial-000.mcap.partial" / "x.mcap")
    assert "pass --out" not in str(given.value) and "give --out a writable place" in str(given.value)


def test_the_recover_command_reports_every_bad_file_and_repairs_the_others(tmp_path: Path) -> None:
    """One line on stderr per file it cannot repair (a directory, junk, a log damaged inside), each
    repairable one repaired in place (one byte short, bytes appended), exit status 2, and no
    ``.recovering`` file left anywhere."""
    data = GOLDEN.read_bytes()
    folder = tmp_path / "my logs"
    folder.mkdir()
    junk = folder / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + b"\xff" * 50)
    short = folder / "short.mcap"
    short.write_bytes(data[:-1])
    tail = folder / "tail.mcap"
    tail.write_bytes(data + b"\x07garbage that replay rejects")
    flipped = bytearray(data)
    flipped[4000] ^= 0xFF  # inside a chunk of a finished file: corruption, not a cut-off
    inside = folder / "inside.mcap"
    inside.write_bytes(bytes(flipped))
    sub = folder / "sub.mcap"
    sub.mkdir()
    result = _cli("recover", str(junk), str(short), str(sub), str(tail), str(inside))
    assert result.returncode == 2
    errors = result.stderr.strip().splitlines()
    assert len(errors) == 3 and "Traceback" not in result.stderr
    assert errors[0].startswith(f"lagrseq recover: error: {junk}: not an MCAP file")
    assert errors[1] == f"lagrseq recover: error: {sub}: a directory, not a log: give the .mcap or .mcap.partial files in it"
    assert errors[2].startswith(f"lagrseq recover: error: {inside}: corrupt at byte") and "cannot repair it" in errors[2]
    said = result.stdout.strip().splitlines()
    assert len(said) == 2 and said[0].startswith(f"recovered {short} -> {short}") and said[1].startswith(f"recovered {tail}")
    assert read_info(short).complete and read_info(tail).complete
    assert inside.read_bytes() == bytes(flipped)
    assert not list(tmp_path.rglob("*.recovering"))


def test_a_partial_file_still_being_written_is_refused(tmp_path: Path) -> None:
    """A running trial holds its ``.partial`` locked; recovering it then would race the writer's
    own rename, so recover says to wait, and writes nothing."""
    from lagrseq.logs.sink import McapSink

    path = tmp_path / "trial-000.mcap"
    sink = McapSink(path, {"config": "{}"})
    try:
        sink.flush()
        with pytest.raises(LogError, match=r"trial-000.mcap.partial is being written by a running lagrseq trial; wait"):
            recover(sink.partial)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["trial-000.mcap.partial"]
    finally:
        sink.abandon()


def test_recover_never_writes_through_a_planted_link(tmp_path: Path) -> None:
    """A symbolic link planted at the output, at the default output or at the temporary file
    ``NAME.mcap.recovering`` (a shared folder) is refused in one line with exit status 2: the
    file it points to is unchanged, and a dangling link's target is not created."""
    data = GOLDEN.read_bytes()[:13000]
    victim = tmp_path / "victim.txt"
    victim.write_text("someone's file\n")
    logs = tmp_path / "logs"
    logs.mkdir()
    partial = logs / "trial-000.mcap.partial"
    partial.write_bytes(data)
    cases = {
        "--out, a link to a file": (["--out", str(tmp_path / "out.mcap")], tmp_path / "out.mcap", victim),
        "--out, a dangling link": (["--out", str(tmp_path / "new.mcap")], tmp_path / "new.mcap", tmp_path / "made.txt"),
        "the default output": ([], logs / "trial-000.mcap", victim),
        "the temporary file": ([], logs / "trial-000.mcap.recovering", victim),
    }
    for case, (args, link, points_to) in cases.items():
        link.symlink_to(points_to)
        done = _cli("recover", str(partial), *args)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, (case, done.stderr, done.stdout)
        assert "is a symbolic link; lagrseq never writes through a link" in lines[0], (case, lines)
        assert victim.read_text() == "someone's file\n", case
        assert not (tmp_path / "made.txt").exists(), case
        assert link.is_symlink() and partial.read_bytes() == data, case
        link.unlink()
    assert sorted(p.name for p in logs.iterdir()) == ["trial-000.mcap.partial"]
    done = _cli("recover", str(partial))  # with the links gone it recovers
    assert done.returncode == 0, done.stderr
    assert read_info(logs / "trial-000.mcap").status["status"] == "recovered"
