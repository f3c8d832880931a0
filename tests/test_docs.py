"""The README and the docs site: a short README whose two quick-start commands are the ones CI
runs, a site whose navigation names only pages that exist, and one list of the docs packages."""

from __future__ import annotations

import configparser
import re
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"

pytestmark = pytest.mark.skipif(not README.is_file() or not DOCS.is_dir(), reason="no source tree (installed package)")


def _blocks(text: str) -> list[str]:
    """The fenced code blocks of a Markdown text."""
    return [b.strip() for b in re.findall(r"^```[a-z]*\n(.*?)^```", text, re.S | re.M)]


def _quick_start() -> list[str]:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return _blocks(section)


def test_the_readme_is_short_and_its_first_command_comes_early() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 120
    first = next(k for k, line in enumerate(lines) if line.startswith("python3 -m venv"))
    assert first < 40


def test_the_quick_start_installs_and_reproduces_in_a_venv_then_gives_the_test_command() -> None:
    install, tests = _quick_start()
    steps = install.splitlines()
    # a virtual environment first: a PEP 668 system Python refuses pip install outside one
    assert steps[0] == "python3 -m venv .venv"
    assert all(step.startswith(".venv/bin/") for step in steps[1:])
    assert any("pip install -e '.[dqn]' -c constraints.txt" in step for step in steps)
    assert steps[-1].endswith("lagrseq reproduce --quick")
    assert "\n" not in tests and tests.startswith("python3 -m venv ") and "pip install 'tox" in tests
    assert "python3 -m pip" not in install + tests  # never pip into the system Python
    assert not any(re.search(r"\b(tox|pytest)\b", step) for step in steps)  # the first tox line is the test command


def test_ci_runs_the_readme_test_command() -> None:
    _, tests = _quick_start()
    script = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    assert tests in script
    assert script[-1] == tests  # the last thing CI does


def test_what_the_quick_start_writes_is_ignored() -> None:
    ignored = (ROOT / ".gitignore").read_text(encoding="utf-8").splitlines()
    # .venv (folder, and tox 4's file of that name), .tox/ (and the bootstrap venv in it), the
    # reproduce output, the built site
    for pattern in (".venv", ".tox/", "/lagrseq-out/", "/site/"):
        assert pattern in ignored, pattern


def test_the_readme_examples_write_only_ignored_places(tmp_path: Path) -> None:
    """Every output folder of the README's example commands (--out, --store, the run's runs/) is
    ignored by git, so running the examples leaves `git status` clean."""
    import shutil
    import subprocess

    git = shutil.which("git")
    if git is None or not (ROOT / ".git").exists():
        pytest.skip("needs git and a clone")
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    outputs = set(re.findall(r"--(?:out|store) (\S+)", text)) | {"runs/cube-stacking/x.mcap"}
    outputs = {o.removeprefix("recorded:") for o in outputs}
    assert {"lagrseq-out/report", "lagrseq-out/store/"} <= outputs
    for path in outputs:
        probe = path.rstrip("/") + "/x"
        result = subprocess.run([git, "-C", str(ROOT), "check-ignore", "-q", "--no-index", probe], capture_output=True)
        assert result.returncode == 0, f"{path} (an example's output) is not ignored by .gitignore"


def test_the_docs_site_lands_where_the_readme_says() -> None:
    import configparser

    tox = configparser.ConfigParser(interpolation=None)
    tox.read(ROOT / "tox.ini", encoding="utf-8")
    assert "--site-dir {tox_root}{/}site" in tox.get("testenv:docs", "commands")
    assert "site_dir: site" in (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    assert "the site lands in `site/`" in (ROOT / "README.md").read_text(encoding="utf-8")


def test_the_test_command_leaves_no_venv_file_in_the_install_commands_way() -> None:
    """tox >= 4.6x writes a PEP 832 redirect *file* named .venv after a run, and then the install
    command's `python3 -m venv .venv` fails ("Unable to create directory"): tox.ini turns it off."""
    import configparser

    tox = configparser.ConfigParser()
    tox.read(ROOT / "tox.ini", encoding="utf-8")
    assert tox.getboolean("tox", "venv_redirect") is False


def _nav_pages(nav: object) -> list[str]:
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [page for entry in nav for page in _nav_pages(entry)]
    if isinstance(nav, dict):
        return [page for value in nav.values() for page in _nav_pages(value)]
    return []


def _nav() -> list[str]:
    # mkdocs.yml without a YAML parser (PyYAML is not a test dependency): the nav entries are
    # "- Title: page.md" lines
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8").split("\nnav:\n", 1)[1]
    return re.findall(r":\s*([\w./-]+\.md)\s*$", text, re.M)


def test_the_nav_lists_every_page_and_only_pages_that_exist() -> None:
    pages = _nav()
    for page in pages:
        assert (DOCS / page).is_file(), page
    required = {
        "index.md", "quickstart.md", "install.md", "tasks.md", "providers.md", "presets.md", "reproduce.md",
        "policies.md", "dask.md", "arm.md", "logs.md", "reference/index.md",
        "extending.md", "architecture.md", "verdicts.md", "audit.md", "security.md", "benchmarks.md", "frontier.md",
        "tutorials/read-the-report.md", "tutorials/run-one-experiment.md",
        "tutorials/local-model.md", "reference/cli.md", "open-models.md", "suites.md",
    }
    assert required <= set(pages)
    own = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md") if "reference-report/tables" not in p.as_posix()}
    assert own <= set(pages), own - set(pages)


def test_the_readme_links_resolve() -> None:
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README.read_text(encoding="utf-8")):
        if "://" not in target:
            assert (ROOT / target).exists(), target


def test_the_docs_extra_is_what_tox_builds_the_site_with() -> None:
    extra = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]["docs"]
    tox = configparser.ConfigParser(interpolation=None)
    tox.read(ROOT / "tox.ini", encoding="utf-8")
    deps = [line.strip() for line in tox["testenv:docs"]["deps"].splitlines() if line.strip()]
    assert deps == extra
    assert "mkdocs build --strict" in tox["testenv:docs"]["commands"]
    assert "docs" in [e.strip() for e in tox["tox"]["env_list"].split(",")]


@pytest.mark.parametrize(
    "page, phrases",
    [
        # topics of the README of before, each on its page now
        ("tasks.md", ["--name NAME", "--jobs N", "lagrseq/CubeStacking-v0", "One environment, two defaults"]),
        ("logs.md", ["/transition", "/query", "/episode", "Foxglove"]),
        ("reproduce.md", ["--authors-caches", "lagrseq recover", "Ctrl-C", "lagrseq replay", "reports/reference"]),
        ("dask.md", ["--executor dask", "SLURMCluster", "budget-ledger.sqlite"]),
        ("arm.md", ["pybullet", "robot.proto", "ur_rtde", "lagrseq robot serve"]),
        ("providers.md", ["recorded:STORE", "--provider local", "Limits on what comes back", "mock:authors-gpt4", "How the mock profiles were calibrated"]),
        ("policies.md", ["secondary.policy", "lagrseq frontier", "thompson"]),
        ("presets.md", ["env.horizon", "lagrseq audit cube-stacking", "lagr.solution_scope", "Image completion and object arrangement"]),
        ("install.md", ["download.pytorch.org/whl/cpu", "torch==2.13.0", "local-llm"]),
        ("reference/index.md", ["lagrseq/loop/experiment.py", "tests/test_layers.py"]),
    ],
)
def test_each_topic_has_its_page(page: str, phrases: list[str]) -> None:
    text = (DOCS / page).read_text(encoding="utf-8")
    for phrase in phrases:
        assert phrase in text, (page, phrase)


def test_llama_cpp_is_built_portably_where_the_project_builds_it() -> None:
    """A -march=native llama.cpp dies of SIGILL on another CPU; the local-llm tox env and
    the install docs build it with GGML_NATIVE off and without pip's cache of a native wheel."""
    tox = configparser.ConfigParser(interpolation=None)
    tox.read(ROOT / "tox.ini", encoding="utf-8")
    env = tox.get("testenv:local-llm", "set_env")
    assert "CMAKE_ARGS = -DGGML_NATIVE=OFF" in env and "PIP_NO_CACHE_DIR = 1" in env
    install = (ROOT / "docs" / "install.md").read_text(encoding="utf-8")
    assert 'CMAKE_ARGS="-DGGML_NATIVE=OFF" .venv/bin/python -m pip install --no-cache-dir' in install
    from lagrseq.llm import local

    assert "-DGGML_NATIVE=OFF" in local.REBUILD_COMMAND and "--no-cache-dir" in local.REBUILD_COMMAND


def test_the_cli_reference_names_every_command() -> None:
    from lagrseq.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    page = (DOCS / "reference" / "cli.md").read_text(encoding="utf-8")
    for name in commands:
        assert f"`lagrseq {name}" in page, name


def _tutorial_commands() -> list[str]:
    lines = []
    for page in [DOCS / "quickstart.md", *sorted((DOCS / "tutorials").glob("*.md"))]:
        for block in _blocks(page.read_text(encoding="utf-8")):
            lines += [line.strip() for line in block.splitlines() if line.strip().startswith(".venv/bin/lagrseq ")]
    return lines


def test_every_tutorial_command_parses() -> None:
    """The tutorials' lagrseq commands are accepted by the command line as written (the quick
    start, one experiment and the recorded answers run end to end in the test below)."""
    import shlex

    from lagrseq.cli import build_parser

    commands = _tutorial_commands()
    assert len(commands) >= 8
    for command in commands:
        argv = shlex.split(command)[1:]
        build_parser(argv[0]).parse_args(argv)


def test_the_first_experiment_tutorial_runs_as_written(tmp_path: Path) -> None:
    import shlex
    import subprocess

    (tmp_path / "recorded_llm").symlink_to(ROOT / "recorded_llm")
    page = (DOCS / "tutorials" / "run-one-experiment.md").read_text(encoding="utf-8")
    page += (DOCS / "tutorials" / "local-model.md").read_text(encoding="utf-8").split("## 2.", 1)[0]
    commands = [c for c in _tutorial_commands() if c in page and " config " not in c]
    assert len(commands) == 5
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    said = {}
    for command in commands:
        argv = [sys.executable, "-m", "lagrseq", *shlex.split(command)[1:], *(["--quiet"] if " run " in command else [])]
        result = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=600, env=env)
        assert result.returncode == 0, (command, result.stderr[-2000:])
        said[command] = result.stdout + result.stderr
    assert (tmp_path / "lagrseq-out" / "first-report" / "index.html").is_file()
    recorded = next(text for command, text in said.items() if "recorded:" in command)
    assert "from the store" in recorded and "3 trial logs" in recorded


def test_every_commands_help_ends_with_a_page_that_exists() -> None:
    from lagrseq.cli import build_parser

    parser = build_parser()
    for name, command in next(a for a in parser._actions if a.dest == "command").choices.items():
        if name == "frontier":  # its help is the protocol's own page link, written with the command
            continue
        last = command.format_help().rstrip().splitlines()[-1]
        assert last.startswith("more: docs/"), (name, last)
        assert (ROOT / last.removeprefix("more: ")).is_file(), (name, last)


def test_the_suites_notes_are_short_and_carry_no_history() -> None:
    """A note says what an item is in about 300 characters and links the page with the rest."""
    from lagrseq.suite import load_suite

    for item in load_suite().items:
        assert len(item.note) <= 320, (item.id, len(item.note))
        assert not re.search(r"\b(issue \d|round)\b", item.note, re.I), item.id
