"""A damaged log is found by every command that reads logs, also where the
damage is in a chunk the command never opens, and each command either goes on without it (one
warning naming its full path) or ends in one line; never another exception, a hang or an
allocation far beyond the file."""

from __future__ import annotations

import shutil
import time
import tracemalloc
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lagrseq import config as cfg
from lagrseq.analysis import loading
from lagrseq.cli import main
from lagrseq.errors import LagrseqError
from lagrseq.logs.reader import full_path, is_complete, read_info
from lagrseq.logs.recover import recover_all
from lagrseq.progress import Reporter
from lagrseq.running import runner
from lagrseq.running.recording import record_patterns
from tests.support.golden_mcap import CHUNK_DATA_LENGTHS, DATA, GOLDEN, MEMORY_BOUND, length_fields

TIME_BOUND = 2.0


def _flip_chunk_length(data: bytes, chunk: int) -> bytes:
    """Bit 62 of chunk ``chunk``'s data length (what once made ``mcap`` ask for 4 EiB)."""
    length_fields(data)
    flipped = bytearray(data)
    flipped[CHUNK_DATA_LENGTHS[chunk] + 7] ^= 0x40
    return bytes(flipped)


@pytest.mark.parametrize("chunk", range(8))
def test_a_damaged_length_in_any_chunk_is_found_by_every_reader(tmp_path: Path, chunk: int) -> None:
    """Also in a chunk of transitions, which replay and ``read_info`` never open: the log is
    not complete (a rerun runs its trial again) and replay skips it with its full path."""
    runs = tmp_path / "my runs"
    runs.mkdir()
    good = runs / "trial-000.mcap"
    shutil.copy(GOLDEN, good)
    path = runs / "trial-001.mcap"
    path.write_bytes(_flip_chunk_length(DATA, chunk))
    assert is_complete(good) and not is_complete(path)
    logs = loading.load([runs])
    assert logs.files == 1 and logs.skipped == 1
    (warning,) = logs.warnings
    assert warning.startswith(f"{full_path(path)}: damaged MCAP log (") and warning.endswith("; skipped")
    assert "\n" not in warning and "cannot repair it" in warning


def test_a_rerun_runs_a_complete_log_with_a_damaged_chunk_again(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A finished log that later lost a chunk-length bit is rerun (the same bytes come back),
    not passed off as complete while replay skips it."""
    args = ["run", "cube-stacking", "--method", "lagr-seq", "--trials", "2", "--out", str(tmp_path),
            "--set", "run.episodes=5", "--quiet", "--jobs", "1"]
    assert main(args) == 0
    logs = sorted(tmp_path.rglob("trial-*.mcap"))
    original = logs[1].read_bytes()
    logs[1].write_bytes(_flip_chunk_length(original, 0))
    capsys.readouterr()
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "1 trial complete (skipped), 0 missing and 1 unfinished" in out
    assert logs[1].read_bytes() == original


def _one_line_or_nothing(read: object) -> None:
    start = time.process_time()
    try:
        read()  # type: ignore[operator]
    except LagrseqError as exc:
        assert "\n" not in str(exc)
    assert time.process_time() - start < TIME_BOUND


CONFIG = cfg.load("cube-stacking", "lagr-seq", "upstream")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    flips=st.lists(st.tuples(st.integers(0, len(DATA) - 1), st.integers(0, 7)), min_size=1, max_size=4),
    cut=st.one_of(st.none(), st.integers(0, len(DATA))),
)
def test_random_damage_gives_each_command_a_warning_or_one_line(
    tmp_path: Path, flips: list[tuple[int, int]], cut: int | None
) -> None:
    """What replay and the frontier report (the loader), ``record --from-runs`` and ``recover``
    do with a log with flipped bits, perhaps cut short: go on with one warning line naming the
    log, or end in one line; in bounded CPU time and memory."""
    data = bytearray(DATA)
    for offset, bit in flips:
        data[offset] ^= 1 << bit
    root = tmp_path / "runs"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir()
    path = root / "trial-000.mcap"
    path.write_bytes(bytes(data[:cut]))
    warnings: list[str] = []
    tracemalloc.start()
    try:
        def load() -> None:
            logs = loading.load([root])
            warnings.extend(logs.warnings)
            assert logs.files + logs.skipped == 1

        _one_line_or_nothing(load)
        _one_line_or_nothing(lambda: record_patterns(CONFIG, [root], reporter=Reporter(warn=warnings.append)))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_BOUND
    for warning in warnings:
        assert "\n" not in warning and warning.startswith(str(full_path(path)))
    out = tmp_path / "recovered"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir()
    (outcome,) = recover_all([path], out)
    assert "\n" not in outcome.message
    if outcome.status == "recovered":
        assert outcome.result is not None and read_info(outcome.result.path).status["status"] in ("recovered", "complete")
    assert not list(root.glob("*.recovering")) and not list(out.glob("*.recovering"))


def test_record_from_runs_skips_a_log_damaged_where_it_never_reads(tmp_path: Path) -> None:
    """``record --from-runs`` reads only ``/query``; a damaged transition chunk is still found."""
    runs = tmp_path / "runs"
    runs.mkdir()
    shutil.copy(GOLDEN, runs / "trial-000.mcap")
    damaged = runs / "trial-001.mcap"
    damaged.write_bytes(_flip_chunk_length(DATA, 0))
    warnings: list[str] = []
    patterns = record_patterns(CONFIG, [runs], reporter=Reporter(warn=warnings.append))
    assert patterns
    (warning,) = warnings
    assert warning.startswith(f"{full_path(damaged)}: damaged MCAP log") and warning.endswith("; skipped")


def test_the_chunk_check_reads_no_chunk_data(tmp_path: Path) -> None:
    """The check of every chunk's fixed fields costs a few dozen bytes per chunk."""
    trials = runner.trial_path(tmp_path, 0)
    shutil.copy(GOLDEN, trials)
    from lagrseq.logs.mcap_reader import McapFile

    with McapFile(trials) as log:
        reads: list[int] = []
        original = log.read

        def counted(offset: int, length: int, what: str = "data") -> bytes:
            reads.append(length)
            return original(offset, length, what)

        log.read = counted  # type: ignore[method-assign]
        summary = log.summary()
        assert summary is not None
    chunk_reads = [n for n in reads if n < 100]
    assert len(chunk_reads) >= 2 * len(summary.chunk_indexes)
    assert sum(chunk_reads) < 64 * len(summary.chunk_indexes)


def test_record_from_runs_with_only_damaged_logs_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    damaged = tmp_path / "my runs" / "trial-000.mcap"
    damaged.parent.mkdir()
    damaged.write_bytes(DATA[:-1])
    code = main(["record", "cube-stacking", "--store", str(tmp_path / "store"), "--from-runs", str(damaged.parent),
                 "--mode", "none", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"lagrseq record: error: no /query states in {damaged.parent} (1 log skipped; first: {damaged}: damaged")
    assert f"lagrseq recover '{damaged}'" in err[0]


@pytest.mark.slow
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(flips=st.lists(st.tuples(st.integers(0, len(DATA) - 1), st.integers(0, 7)), min_size=1, max_size=3))
def test_random_damage_through_the_commands_is_a_warning_or_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flips: list[tuple[int, int]]
) -> None:
    """``frontier --replay`` (the frontier report from logs; replay reads logs the same way) and
    ``recover`` on a
    directory with one good log and one with flipped bits: exit 0 with one warning line per log
    left out, or exit 2 with one line."""
    data = bytearray(DATA)
    for offset, bit in flips:
        data[offset] ^= 1 << bit
    root = tmp_path / "my runs"
    shutil.rmtree(root, ignore_errors=True)
    (root / "a").mkdir(parents=True)
    (root / "b").mkdir()
    shutil.copy(GOLDEN, root / "a" / "trial-000.mcap")
    path = root / "b" / "trial-000.mcap"
    path.write_bytes(bytes(data))
    capsys.readouterr()
    for command in (
        ["frontier", "--replay", str(root), "--out", str(tmp_path / "frontier")],
        ["recover", str(path), "--out", str(tmp_path / "recovered.mcap")],
    ):
        shutil.rmtree(tmp_path / "frontier", ignore_errors=True)
        (tmp_path / "recovered.mcap").unlink(missing_ok=True)
        code = main(command)
        err = capsys.readouterr().err.strip().splitlines()
        assert code in (0, 2) and "Traceback" not in "\n".join(err)
        if code == 2:
            assert len(err) == 1, (command, err)
        else:
            assert all(f"warning: {full_path(path)}" in line for line in err), (command, err)


def test_frontier_replay_of_only_damaged_logs_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """As replay: nothing to draw is an error naming each log left out, not an empty report."""
    runs = tmp_path / "my runs"
    runs.mkdir()
    cut = runs / "trial 0.mcap"
    cut.write_bytes(DATA[:-1])
    code = main(["frontier", "--replay", str(runs), "--out", str(tmp_path / "frontier")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"lagrseq frontier: error: no complete lagrseq trial logs under {runs} ({cut}: damaged MCAP log")
    assert f"`lagrseq recover '{cut}'`" in err[0]
