"""The test suite's own layout: no test module imports another test module (shared helpers live
in a ``conftest.py`` or in ``tests/support``), so a test file can be moved, renamed or split
without breaking another one."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _module_of(path: Path) -> str:
    return ".".join(("tests", *path.relative_to(TESTS).with_suffix("").parts))


def _imported(source: str, module: str) -> set[str]:
    """Every module the source of ``module`` imports, relative imports resolved, ``from P
    import N`` giving both ``P`` and ``P.N`` (N may be a module)."""
    package = module.rsplit(".", 1)[0].split(".")
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            parent = ".".join([*base, *([node.module] if node.module else [])])
            found.add(parent)
            found.update(f"{parent}.{alias.name}" for alias in node.names)
    return found


def _test_module_imports() -> set[tuple[str, str]]:
    pairs = set()
    for path in sorted(TESTS.rglob("test_*.py")):
        for name in _imported(path.read_text(encoding="utf-8"), _module_of(path)):
            if name.startswith("tests.") and name.rsplit(".", 1)[-1].startswith("test_"):
                pairs.add((path.relative_to(TESTS).as_posix(), name))
    return pairs


def test_no_test_module_imports_another_test_module() -> None:
    found = _test_module_imports()
    assert found == set(), f"move these helpers into tests/support or a conftest.py: {sorted(found)}"


def test_the_check_sees_absolute_relative_and_module_imports() -> None:
    source = (
        "import tests.logs.test_damage\n"
        "from tests.llm.test_limits import serve\n"
        "from . import test_gguf\n"
        "from .test_redaction import leaks\n"
        "def later():\n"
        "    from ..dask.test_dask import cli\n"
        "from tests.support.servers import RawServer\n"
    )
    names = _imported(source, "tests.llm.test_sample")
    assert {n for n in names if n.rsplit(".", 1)[-1].startswith("test_")} == {
        "tests.logs.test_damage",
        "tests.llm.test_limits",
        "tests.llm.test_gguf",
        "tests.llm.test_redaction",
        "tests.dask.test_dask",
    }
