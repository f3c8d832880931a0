"""What a new user reads first: every --help text, the progress bars and messages of a run, and
``lagrseq info`` (with and without each extra)."""

from __future__ import annotations

import argparse
import fcntl
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from lagrseq import __version__, info
from lagrseq.cli import build_parser
from lagrseq.running.wiring import mock_profiles

ROOT = Path(__file__).resolve().parents[1]


def _parsers(parser: argparse.ArgumentParser, name: str = "lagrseq") -> list[tuple[str, argparse.ArgumentParser]]:
    """The parser and every subcommand's parser, depth first."""
    out = [(name, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, child in action.choices.items():
                out += _parsers(child, f"{name} {sub}")
    return out


def _help(parser: argparse.ArgumentParser) -> str:
    os.environ["COLUMNS"] = "100"  # a fixed width, so wrapping does not depend on the terminal
    return parser.format_help()


PARSERS = _parsers(build_parser())


def test_every_command_is_covered() -> None:
    names = {name for name, _ in PARSERS}
    assert {"lagrseq run", "lagrseq reproduce", "lagrseq frontier", "lagrseq audit", "lagrseq info", "lagrseq cache import"} <= names


@pytest.mark.parametrize("name, parser", PARSERS, ids=[n for n, _ in PARSERS])
def test_help_texts_print_no_format_escapes(name: str, parser: argparse.ArgumentParser) -> None:
    text = _help(parser)
    # argparse formats help= strings with %, not descriptions and epilogs: a "%%" written for
    # one of them reached the screen as "95%%"
    assert "%%" not in text, name
    assert not re.search(r"%\([a-z_]+\)[sd]", text), name
    assert "Traceback" not in text


def test_frontier_help_points_to_its_protocol_and_audit_help_says_95_percent() -> None:
    helps = dict(PARSERS)
    for name, interval in (("lagrseq frontier", "docs/frontier.md"), ("lagrseq audit", "95% t-intervals")):
        text = " ".join(_help(helps[name]).split())
        assert interval in text and "%%" not in text, name


def test_run_help_names_every_mock_profile() -> None:
    text = " ".join(_help(dict(PARSERS)["lagrseq run"]).split())
    for profile in mock_profiles():
        assert f"{profile}:" in text, profile
    assert "authors-gpt4: (image completion, object arrangement)" in text


def _screen_lines(command: list[str]) -> list[str]:
    """What ``lagrseq COMMAND --help`` prints on a terminal 100 columns wide, a line per row."""
    done = subprocess.run([sys.executable, "-m", "lagrseq", *command, "--help"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "100"}, timeout=120)
    assert done.returncode == 0 and not done.stderr, done.stderr
    return done.stdout.rstrip("\n").split("\n")


def test_frontier_help_fits_one_screen() -> None:
    lines = _screen_lines(["frontier"])
    assert len(lines) <= 50, "\n".join(lines)
    assert all(len(line) <= 100 for line in lines), [line for line in lines if len(line) > 100]
    assert lines[0] == "usage: lagrseq frontier [options] [TASK]"
    assert any(line.startswith("provider options (") and "docs/providers.md" in line for line in lines)


TWO_LINES = {"--provider", "TASK", "COMMAND", "ACTION"}
"""The options whose help may take a second line: ``--provider`` lists every kind's form, a
task argument every task (a command or action is followed by the list of them)."""


@pytest.mark.parametrize("name, parser", PARSERS, ids=[n for n, _ in PARSERS])
def test_every_option_is_one_line_of_help(name: str, parser: argparse.ArgumentParser) -> None:
    lines = _help(parser).rstrip("\n").split("\n")
    assert all(len(line) <= 100 for line in lines), (name, [line for line in lines if len(line) > 100])
    # the options only: up to the examples, and a plugin provider kind's own flags (their group:
    # "options of --provider KIND") are its author's
    ends = ("options of --provider", "example:", "examples:")
    ours = lines[: next((k for k, line in enumerate(lines) if line.startswith(ends)), len(lines))]
    wrapped = [
        line.split()[0] for line, after in zip(ours, ours[1:], strict=False)
        if re.match(r"  [-A-Z]", line) and re.match(r" {4,}\S", after) and line.split()[0] not in TWO_LINES
    ]
    assert wrapped == [], name


def test_a_long_usage_is_cut_to_options_and_what_is_required() -> None:
    helps = dict(PARSERS)
    assert _help(helps["lagrseq record"]).startswith("usage: lagrseq record [options] --store STORE TASK\n")
    assert _help(helps["lagrseq cache export"]).startswith("usage: lagrseq cache export [-h] --store STORE --out FILE.jsonl\n")


def test_reproduce_writes_to_an_untracked_folder_by_default() -> None:
    parser = dict(PARSERS)["lagrseq reproduce"]
    args = build_parser().parse_args(["reproduce", "--quick"])
    assert args.out == Path("lagrseq-out")
    assert "lagrseq-out" in _help(parser)
    ignored = (ROOT / ".gitignore").read_text().splitlines()
    assert "/lagrseq-out/" in ignored and ".venv" in ignored  # .venv: tox 4's file as well as the folder


# ------------------------------------------------------------------------------------------
# Progress bars and the lines printed beside them
# ------------------------------------------------------------------------------------------
def _in_pty(code: str, columns: int, rows: int) -> str:
    """Run ``code`` in a fresh interpreter whose stdout and stderr are a terminal of the given
    size (0 x 0: a terminal that reports no size); return what it printed."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    process = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.DEVNULL, stdout=slave, stderr=slave,
        env={**os.environ, "PYTHONPATH": str(ROOT)}, close_fds=True,
    )
    os.close(slave)
    chunks = []
    while True:
        ready, _, _ = select.select([master], [], [], 60)
        if not ready:
            break
        try:
            chunk = os.read(master, 4096)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(master)
    assert process.wait(timeout=60) == 0
    return b"".join(chunks).decode("utf-8", "replace")


BAR = (
    "from lagrseq.progress import bar, say\n"
    "import time\n"
    "with bar(4, 'ep', 'cube') as b:\n"
    "    for k in range(4):\n"
    "        if k == 2:\n"
    "            say('resuming: 2 trials complete (skipped)')\n"
    "        b.update(1)\n"
    "        time.sleep(0.12)\n"
)


def test_a_terminal_of_unknown_size_gets_an_80_column_bar_not_blank_lines() -> None:
    text = _in_pty(BAR, 0, 0)
    segments = [s for s in re.split(r"[\r\n]+", text)]
    shown = [s for s in segments if "4/4" in s]
    assert shown, text  # the bar is drawn (with 0 columns tqdm drew nothing but line ends)
    assert all(len(s) <= 80 for s in shown)
    assert text.count("\n") <= 3, text  # the message, the finished bar: no empty line per refresh


def test_a_message_during_a_bar_gets_a_line_of_its_own() -> None:
    for columns in (0, 120):
        text = _in_pty(BAR, columns, 40)
        segments = [s.strip() for s in re.split(r"[\r\n]+", text)]
        assert "resuming: 2 trials complete (skipped)" in segments, text  # never glued onto the bar


def test_a_rerun_says_resuming_on_its_own_line(tmp_path: Path) -> None:
    args = ["run", "cube-stacking", "--out", str(tmp_path), "--set", "run.episodes=3", "--seed", "0"]
    code = "import sys\nfrom lagrseq.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    first = subprocess.run([sys.executable, "-c", code, *args, "--trials", "1"], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert first.returncode == 0, first.stderr
    again = _in_pty(code.replace("sys.argv[1:]", repr([*args, "--trials", "2"])), 100, 40)
    lines = [s.strip() for s in re.split(r"[\r\n]+", again)]
    assert any(line.startswith("resuming: 1 trial complete (skipped)") for line in lines), again


# ------------------------------------------------------------------------------------------
# lagrseq info
# ------------------------------------------------------------------------------------------
def test_info_runs_here_and_names_version_python_extras_device_and_outputs(tmp_path: Path) -> None:
    # the real command in whatever this environment has installed: the core tox environments
    # have no extra but test, py311-full has dqn and arm, the dask env has dask
    done = subprocess.run([sys.executable, "-m", "lagrseq", "info"], capture_output=True, text=True, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert done.returncode == 0 and not done.stderr, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith(f"lagrseq {__version__} (")
    assert lines[1].startswith(f"python {sys.version.split()[0]} ")
    device = next(line for line in lines if line.startswith("torch device: "))
    if info.installed("torch") is None:
        assert "torch not installed (the dqn extra)" in device
    else:
        assert device.startswith(f"torch device: torch {info.installed('torch')}: ")
    assert f"output of reproduce: {tmp_path.resolve() / 'lagrseq-out'} (runs/ and reports/ inside)" in {
        line.replace(str(tmp_path), str(tmp_path.resolve())).split(";")[0] for line in lines
    }
    for extra, packages in info.extras().items():
        line = next(line for line in lines if line.startswith(f"extra {extra}: "))
        for package in packages:
            assert f"{package} {info.installed(package) or 'not installed'}" in line


@pytest.mark.parametrize("missing", ["dqn", "arm", "dask", "local-llm", "docs"])
def test_info_with_an_extra_missing(missing: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    extras = info.extras()
    if not extras:
        pytest.skip("lagrseq is not installed here (no metadata to read its extras from)")
    gone = set(extras.get(missing, []))
    real = info.installed
    monkeypatch.setattr(info, "installed", lambda package: None if package in gone else real(package))
    lines = info.lines(tmp_path, device=info.torch_device)
    if missing in extras:
        assert f"extra {missing}: not installed (" in "\n".join(lines)
    if missing == "dqn":
        assert "torch device: torch not installed (the dqn extra): the grid tasks' DQN is not available" in lines


def test_info_with_every_extra_present(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    extras = info.extras()
    if not extras:
        pytest.skip("lagrseq is not installed here (no metadata to read its extras from)")
    monkeypatch.setattr(info, "installed", lambda package: "9.9")
    lines = info.lines(tmp_path, device=lambda: "torch 9.9: no GPU visible (cpu only)")
    for extra, packages in extras.items():
        assert f"extra {extra}: installed ({', '.join(f'{p} 9.9' for p in packages)})" in lines


def test_info_from_a_source_tree_without_metadata(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(info, "extras", lambda distribution="lagrseq": {})
    lines = info.lines(tmp_path, device=lambda: "x")
    assert any(line.startswith("extras: unknown (lagrseq is not installed") for line in lines)
