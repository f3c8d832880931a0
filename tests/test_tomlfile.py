"""One TOML reader for configuration files, suite files and price tables: every unusable file is
one ConfigError line naming the path and the problem, never a traceback."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from lagrseq.llm.pricing import read_price_table
from lagrseq.suite import load_suite
from lagrseq.tomlfile import MAX_TOML_BYTES, read_toml

READERS: dict[str, Callable[[Path], Any]] = {
    "config": lambda path: cfg.load("cube-stacking", "lagr", "paper", config_file=path),
    "suite": load_suite,
    "price table": read_price_table,
}


def _bad_file(tmp_path: Path, kind: str) -> tuple[Path, str]:
    """A file that cannot be used as TOML, and the problem the message must name."""
    path = tmp_path / f"{kind}.toml"
    if kind == "directory":
        path.mkdir()
        return path, "is a directory"
    if kind == "missing":
        return path, "does not exist"
    if kind == "binary":
        path.write_bytes(bytes(range(256)) * 4)
        return path, "holds NUL bytes (binary data at offset 0)"
    if kind == "not-utf8":
        path.write_bytes(b'model = "caf\xe9"\n')
        return path, "is not UTF-8 text (byte 0xe9 at offset 12)"
    if kind == "invalid":
        path.write_text("[env\nhorizon = 1\n")
        return path, "is not valid TOML"
    if kind == "huge":
        path.write_text("# padding\n" * (MAX_TOML_BYTES // 10 + 1))
        return path, f"is larger than {MAX_TOML_BYTES} bytes"
    if kind == "nested":
        path.write_text("v = " + "[" * 100_000)
        return path, "nested too deeply"
    raise AssertionError(kind)


KINDS = ("directory", "missing", "binary", "not-utf8", "invalid", "huge", "nested")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("what", READERS)
def test_every_reader_gives_one_line_naming_path_and_problem(tmp_path: Path, what: str, kind: str) -> None:
    path, problem = _bad_file(tmp_path, kind)
    started = time.perf_counter()
    with pytest.raises(ConfigError) as info:
        READERS[what](path)
    assert time.perf_counter() - started < 2.0
    message = str(info.value)
    assert message.startswith(f"{what} file {path} "), message
    assert problem in message and "\n" not in message and len(message) < 300, message


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their mode")
def test_an_unreadable_file(tmp_path: Path) -> None:
    path = tmp_path / "secret.toml"
    path.write_text("[env]\n")
    path.chmod(0)
    try:
        with pytest.raises(ConfigError, match=r"config file .*secret.toml cannot be read: permission denied"):
            read_toml(path)
    finally:
        path.chmod(0o600)


def test_a_file_that_fails_on_read() -> None:
    """/proc/self/mem opens but cannot be read from offset 0 (EIO), even for root."""
    if not Path("/proc/self/mem").exists():
        pytest.skip("no /proc")
    with pytest.raises(ConfigError, match=r"^suite file /proc/self/mem cannot be read: Input/output error$"):
        read_toml("/proc/self/mem", "suite")


def test_an_endless_device_is_refused_before_it_is_read() -> None:
    started = time.perf_counter()  # every input is checked to be a regular file first
    with pytest.raises(ConfigError, match="config file /dev/zero is a character device; expected a TOML file"):
        read_toml("/dev/zero")
    assert time.perf_counter() - started < 1.0


def test_odd_paths_stay_on_one_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        read_toml(tmp_path / "two\nlines.toml")
    assert "\n" not in str(info.value) and "two\\nlines.toml" in str(info.value)
    with pytest.raises(ConfigError, match="cannot be read: embedded null byte"):
        read_toml("nul\x00.toml")


def test_a_good_file_is_read(tmp_path: Path) -> None:
    path = tmp_path / "ok.toml"
    path.write_text('[env]\nhorizon = 7\nname = "café"\n', encoding="utf-8")
    assert read_toml(path) == {"env": {"horizon": 7, "name": "café"}}
    assert read_toml(Path(os.devnull)) == {}


def test_no_module_reads_toml_but_the_reader() -> None:
    """configs, suites and price tables all go through lagrseq.tomlfile."""
    root = Path(cfg.__file__).parent
    readers = sorted(
        str(p.relative_to(root)) for p in root.rglob("*.py") if "tomllib" in p.read_text(encoding="utf-8")
    )
    assert readers == ["errors.py", "tomlfile.py"]  # errors.py only names it in its docstring
