"""The import rules of DESIGN section 2, for every module of the package, in fresh interpreters.

The layer map below is the rule, written once: each module belongs to the layer of its longest
matching prefix and must not load anything its layer forbids (``lagrseq.x`` forbids the package
and its submodules). A module that matches no layer fails the test, so a new module must be
placed on the map. The map is written over the packages that name the layers (base, parts,
``lagrseq.loop``, ``lagrseq.running``, ``lagrseq.analysis``, ``lagrseq.study``, the command line),
with finer rules for single modules; ``test_no_import_cycle_between_modules`` checks the import
graph (lazy imports included) has no cycle. Analysis is also checked in its source (lazy imports
included): it imports neither the loop, running nor study; the suite's data (``lagrseq.suite``)
and the frontier protocol's helpers (``lagrseq.frontier_protocol``) sit in the base layer. The
loop and running are checked in their source too: they name no concrete task (no task, env or
built-in task registration; only the ``Task`` interface), so a built-in task reaches them through
its registered spec as a plugin's does. Planted trees show the checks catch a bad import.
"""

from __future__ import annotations

import importlib.util as importlib_util
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import lagrseq

ROOT = Path(__file__).resolve().parents[1]

HEAVY = ("torch", "gymnasium", "httpx", "httpcore", "pybullet")
PROVIDERS = ("lagrseq.llm.mock", "lagrseq.llm.live", "lagrseq.llm.recorded", "lagrseq.llm.store")
# The layers, bottom to top: base (ANYONE below), parts (tasks, envs, agents, llm, logs, robot),
# loop, running, analysis and study, the command line. A package forbids everything above it.
CLI = ("lagrseq.cli", "lagrseq.__main__")
STUDY = ("lagrseq.study", *CLI)
RUNNING = ("lagrseq.running", "lagrseq.analysis", *STUDY)
LOOP = ("lagrseq.loop", *RUNNING)
PARTS = ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", "lagrseq.robot")

ANALYSIS_FORBIDS = ("lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.loop", "lagrseq.running", *STUDY, *HEAVY)
"""DESIGN section 2: analysis imports no env, agent, provider, loop, runner or study (the suite's
data and the frontier protocol's helpers live below it, in the base layer)."""

LAYERS: dict[str, tuple[str, ...]] = {
    # base: config, errors, seeding, paths, tomlfile, registry, builtins, keys, text, outputs (stdlib + numpy; the
    # built-in parts are registered by lazy reference); anyone may import them
    "lagrseq": (*PARTS, *LOOP, *HEAVY, "mcap", "pandas", "matplotlib"),
    # parts: each knows its own interface, none the loop or anything above it
    "lagrseq.tasks": ("lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", "lagrseq.robot", *LOOP, *HEAVY, "mcap"),
    "lagrseq.envs": ("lagrseq.llm", "lagrseq.agents", "lagrseq.logs", *LOOP, "torch", "httpx", "mcap"),
    "lagrseq.agents": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.llm", "lagrseq.logs", "lagrseq.robot", *LOOP, "gymnasium", "httpx", "mcap"),
    "lagrseq.llm": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.logs", "lagrseq.robot", *LOOP, "torch", "gymnasium"),
    "lagrseq.logs": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.robot", *LOOP, *HEAVY),
    # the robot behind the arm env: no RL, no LLM, no logs; pybullet and grpc only when built
    "lagrseq.robot": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", *LOOP, *HEAVY, "grpc", "mcap", "gymnasium"),
    # the generated gRPC code imports protobuf and grpc themselves (the arm extra)
    "lagrseq.robot.proto": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", *LOOP, *HEAVY, "mcap"),
    # the built-in tasks' registrations (what a plugin's module holds): their parts, the loop only inside a call
    "lagrseq.builtin_tasks": ("lagrseq.loop", *RUNNING, *HEAVY, "mcap"),
    # loop: Algorithm 1 and its parts know interfaces only: no concrete env, provider or sink
    "lagrseq.loop": (*PROVIDERS, "lagrseq.envs", "lagrseq.logs.mcap_writer", *RUNNING, *HEAVY),
    "lagrseq.loop.lagr": (*PROVIDERS, "lagrseq.logs", "lagrseq.envs", "lagrseq.loop.experiment", *RUNNING, *HEAVY),
    "lagrseq.loop.seq": ("lagrseq.llm", "lagrseq.logs", "lagrseq.envs", "lagrseq.tasks", "lagrseq.loop.experiment", *RUNNING, *HEAVY),
    "lagrseq.loop.policies": ("lagrseq.llm", "lagrseq.logs", "lagrseq.envs", "lagrseq.tasks", "lagrseq.agents", "lagrseq.loop.experiment", *RUNNING, *HEAVY),
    "lagrseq.loop.adapters": ("lagrseq.llm", "lagrseq.logs", "lagrseq.envs", "lagrseq.loop.experiment", *RUNNING, *HEAVY),
    # running: wiring, the runner and executors import the heavy parts lazily, where a trial needs them
    "lagrseq.running": ("lagrseq.analysis", *STUDY, *HEAVY),
    "lagrseq.running.wiring": ("lagrseq.analysis", "lagrseq.running.runner", "lagrseq.running.recording", *STUDY, *HEAVY),
    "lagrseq.running.runner": ("lagrseq.analysis", "lagrseq.running.recording", *STUDY, "dask", "distributed", *HEAVY),
    "lagrseq.running.recording": ("lagrseq.analysis", "lagrseq.running.runner", *STUDY, *HEAVY),
    # executors: the interface alone; the process pool; dask only in its own module, on demand
    "lagrseq.running.executor_base": ("lagrseq.running.executors", "lagrseq.running.dask_executor", "lagrseq.running.recording", "lagrseq.analysis", *STUDY, "dask", "distributed", *HEAVY),
    "lagrseq.running.executors": ("lagrseq.running.recording", "lagrseq.analysis", *STUDY, "dask", "distributed", *HEAVY),
    "lagrseq.running.dask_executor": ("lagrseq.running.executors", "lagrseq.running.recording", "lagrseq.analysis", *STUDY, *HEAVY),
    # analysis: replay from the MCAP logs and the suite's data alone: nothing that runs anything
    "lagrseq.analysis": ANALYSIS_FORBIDS,
    # study: the commands that plan many runs and report on them; never the command line
    "lagrseq.study": (*CLI, *HEAVY),
    "lagrseq.study.frontier": ("lagrseq.analysis", *CLI, *HEAVY),
    "lagrseq.study.probe": ("lagrseq.analysis", "lagrseq.running.recording", "lagrseq.study.reproduce", *CLI, *HEAVY),
    "lagrseq.study.reproduce": (*CLI, "dask", "distributed", *HEAVY),
    "lagrseq.study.audit": ("lagrseq.study.reproduce", *CLI, *HEAVY),
    "lagrseq.study.authors": ("lagrseq.analysis", "lagrseq.running.runner", "lagrseq.study.reproduce", *CLI, *HEAVY),
    # the command line parses and calls: the loop and wiring only when a command runs
    "lagrseq.cli": ("lagrseq.loop", "lagrseq.running.wiring", *HEAVY, "mcap", "pandas", "matplotlib"),
    "lagrseq.cli.helpers": ("lagrseq.loop", "lagrseq.running", *HEAVY, "mcap", "pandas", "matplotlib"),
    "lagrseq.__main__": (),  # ``python -m lagrseq``: the command line, nothing else
    # lagrseq info: metadata only; torch is imported inside the call that names its device
    "lagrseq.info": ("lagrseq.loop", "lagrseq.running", "lagrseq.analysis", "lagrseq.study", *CLI, "dask", "distributed", *HEAVY, "mcap", "pandas", "matplotlib"),
}
OPTIONAL = {
    "lagrseq.running.dask_executor": ("distributed",),
    "lagrseq.robot.proto.robot_pb2": ("google.protobuf",),
    "lagrseq.robot.proto.robot_pb2_grpc": ("google.protobuf", "grpc"),
}
"""Modules that need an extra to import at all (the Dask executor, generated gRPC code): checked
only where it is installed."""
ANYONE = (
    "lagrseq.config",
    "lagrseq.errors",
    "lagrseq.seeding",
    "lagrseq.paths",
    "lagrseq.lifetime",
    "lagrseq.progress",
    "lagrseq.tomlfile",
    "lagrseq.registry",
    "lagrseq.builtins",
    "lagrseq.keys",
    "lagrseq.text",
    "lagrseq.outputs",
    # data and definitions that analysis and running (or study) both read, so below both
    "lagrseq.suite",
    "lagrseq.frontier_protocol",
)


def modules() -> list[str]:
    return sorted(m.name for m in pkgutil.walk_packages(lagrseq.__path__, "lagrseq."))


def layer_of(module: str) -> str:
    if module in ANYONE:
        return "lagrseq"
    matches = [layer for layer in LAYERS if module == layer or module.startswith(layer + ".")]
    return max(matches, key=len)


def loaded_after_import(names: list[str], root: Path = ROOT, *, site: bool = True) -> dict[str, list[str] | None]:
    """For each module, what ``import module`` loads in a fresh interpreter (one forked child per
    module from a parent that has imported nothing of lagrseq), with ``root`` first on the path;
    None where the import failed. ``site=False``: without site-packages (``python -S``), so a
    tree at ``root`` is not shadowed by the installed package's editable finder."""
    code = (
        "import json, os, sys\n"
        f"names = {names!r}\n"
        "out = {}\n"
        "for name in names:\n"
        "    read, write = os.pipe()\n"
        "    if os.fork() == 0:\n"
        "        os.close(read)\n"
        "        try:\n"
        "            __import__(name)\n"
        "            os.write(write, json.dumps(sorted(sys.modules)).encode())\n"
        "        except BaseException:\n"
        "            pass\n"
        "        os._exit(0)\n"
        "    os.close(write)\n"
        "    data = b''\n"
        "    while chunk := os.read(read, 1 << 16):\n"
        "        data += chunk\n"
        "    os.close(read)\n"
        "    os.wait()\n"
        "    out[name] = json.loads(data or b'null')\n"
        "print(json.dumps(out))\n"
    )
    done = subprocess.run(
        [sys.executable, *(() if site else ("-S",)), "-c", code],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(root)},
        cwd=root,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def _under(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def forbidden_loads(loaded: dict[str, list[str] | None]) -> dict[str, list[str]]:
    """Module -> what its import loaded that its layer (LAYERS) forbids; a failed import is
    reported as such (it hides what the module loads)."""
    problems = {}
    for name, modules_loaded in loaded.items():
        if modules_loaded is None:
            problems[name] = ["(import failed)"]
            continue
        bad = sorted(m for m in modules_loaded if _under(m, LAYERS[layer_of(name)]) and m != name)
        if bad:
            problems[name] = bad
    return problems


def static_imports(root: Path, package: str = "lagrseq") -> dict[str, set[str]]:
    """Module -> every dotted name its source imports, anywhere (top level or inside a function:
    a lazy import breaks a layer as much as an eager one), for the package at ``root/package``;
    relative imports resolved."""
    import ast

    out: dict[str, set[str]] = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        is_package = parts[-1] == "__init__"
        name = ".".join(parts[:-1] if is_package else parts)
        here = name if is_package else name.rpartition(".")[0]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                found |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parent = here.rsplit(".", node.level - 1)[0] if node.level > 1 else here
                    base = f"{parent}.{base}" if base else parent
                found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
        out[name] = found
    return out


def static_breaks(imports: dict[str, set[str]], layer: str, forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    """The modules of ``layer`` whose source imports anything under ``forbidden``, with what."""
    return {
        name: sorted(n for n in names if _under(n, forbidden))
        for name, names in sorted(imports.items())
        if _under(name, (layer,)) and any(_under(n, forbidden) for n in names)
    }


def test_every_module_is_on_the_layer_map() -> None:
    placed = [layer for layer in LAYERS if layer != "lagrseq"]
    unplaced = [m for m in modules() if m not in ANYONE and not any(m == p or m.startswith(p + ".") for p in placed)]
    assert unplaced == [], f"place these modules on LAYERS: {unplaced}"


@pytest.mark.skipif(sys.platform == "win32", reason="uses os.fork")
def test_no_module_imports_what_its_layer_forbids() -> None:
    import importlib.util

    def installed(name: str) -> bool:
        try:
            return importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:
            return False

    names = [m for m in modules() if m != "lagrseq.__main__"]  # importing it runs the command line
    names = [m for m in names if all(installed(x) for x in OPTIONAL.get(m, ()))]
    problems = forbidden_loads(loaded_after_import(names))
    assert problems == {}, f"layer rules broken (module: what it loads): {problems}"


def test_analysis_imports_neither_running_nor_study_nor_the_loop_even_lazily() -> None:
    """DESIGN section 2, read from the source (lazy imports inside functions included): replay
    needs only the logs, the suite's data and analysis code."""
    imports = static_imports(ROOT)
    assert "lagrseq.analysis.replay" in imports and "lagrseq.suite" in imports
    internal = tuple(f for f in ANALYSIS_FORBIDS if f.startswith("lagrseq."))
    assert static_breaks(imports, "lagrseq.analysis", internal) == {}


PLANTED = {
    "lagrseq/__init__.py": "",
    "lagrseq/suite.py": "ITEMS = ()\n",
    "lagrseq/running/__init__.py": "",
    "lagrseq/running/runner.py": "",
    "lagrseq/study/__init__.py": "",
    "lagrseq/study/frontier.py": "",
    "lagrseq/analysis/__init__.py": "",
    "lagrseq/analysis/good.py": "from lagrseq.suite import ITEMS\n",
    "lagrseq/analysis/eager.py": "import lagrseq.running.runner\n",
    "lagrseq/analysis/lazy.py": "def frontier():\n    from ..study import frontier\n    return frontier\n",
}
"""A tree shaped like the package in which two analysis modules break the layers: one imports
running at import time, one imports study inside a function (relatively)."""


@pytest.mark.skipif(sys.platform == "win32", reason="uses os.fork")
def test_the_checks_catch_a_planted_bad_import(tmp_path: Path) -> None:
    for relative, text in PLANTED.items():
        (tmp_path / relative).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / relative).write_text(text, encoding="utf-8")
    # the source check: both breaks, lazy and relative included; the good module passes
    internal = tuple(f for f in ANALYSIS_FORBIDS if f.startswith("lagrseq."))
    assert static_breaks(static_imports(tmp_path), "lagrseq.analysis", internal) == {
        "lagrseq.analysis.eager": ["lagrseq.running.runner"],
        "lagrseq.analysis.lazy": ["lagrseq.study", "lagrseq.study.frontier"],
    }
    # the fresh-interpreter check: the import-time break (the planted tree in place of the package)
    names = ["lagrseq.analysis.good", "lagrseq.analysis.eager", "lagrseq.analysis.lazy"]
    problems = forbidden_loads(loaded_after_import(names, root=tmp_path, site=False))
    assert problems == {"lagrseq.analysis.eager": ["lagrseq.running", "lagrseq.running.runner"]}


CONCRETE_TASKS = ("lagrseq.tasks", "lagrseq.envs", "lagrseq.builtin_tasks")
"""Concrete task code: the tasks, their envs and the built-in tasks' registrations."""
TASK_INTERFACE = ("lagrseq.tasks.base",)
"""What of it the loop and running may name: the ``Task`` interface (and the ``lagrseq.tasks``
package that holds it)."""


def concrete_task_imports(imports: dict[str, set[str]], layer: str) -> dict[str, list[str]]:
    """The modules of ``layer`` whose source names concrete task code, with what."""

    def concrete(name: str) -> bool:
        return _under(name, CONCRETE_TASKS) and name != "lagrseq.tasks" and not _under(name, TASK_INTERFACE)

    found = {name: sorted(n for n in names if concrete(n)) for name, names in sorted(imports.items()) if _under(name, (layer,))}
    return {name: names for name, names in found.items() if names}


def test_running_and_the_loop_name_no_concrete_task_even_lazily() -> None:
    """A built-in task reaches the loop and running only through its registered spec, as a
    plugin's does: their source (lazy imports included) names no task, env or registration."""
    imports = static_imports(ROOT)
    assert "lagrseq.running.wiring" in imports and "lagrseq.loop.adapters" in imports
    assert "lagrseq.tasks.base" in imports["lagrseq.running.wiring"]  # the interface is allowed
    assert concrete_task_imports(imports, "lagrseq.running") == {}
    assert concrete_task_imports(imports, "lagrseq.loop") == {}


PLANTED_TASK_IMPORTS = {
    "lagrseq/loop/adapters.py": "from lagrseq.tasks import cube\n",
    "lagrseq/running/wiring.py": "def planted_env():\n    from ..envs import image_completion\n    return image_completion\n",
    "lagrseq/running/runner.py": "def planted_spec():\n    import lagrseq.builtin_tasks.cube_stacking\n",
}
"""Imports planted at the end of a copy of the package: the loop names a task at import time,
running an env inside a function (relatively) and a built-in task's registration."""


def test_the_concrete_task_check_catches_a_planted_import(tmp_path: Path) -> None:
    import shutil

    shutil.copytree(ROOT / "lagrseq", tmp_path / "lagrseq", ignore=shutil.ignore_patterns("__pycache__"))
    assert concrete_task_imports(static_imports(tmp_path), "lagrseq.running") == {}  # the copy is clean
    for relative, text in PLANTED_TASK_IMPORTS.items():
        with (tmp_path / relative).open("a", encoding="utf-8") as source:
            source.write("\n\n" + text)
    imports = static_imports(tmp_path)
    assert concrete_task_imports(imports, "lagrseq.loop") == {"lagrseq.loop.adapters": ["lagrseq.tasks.cube"]}
    assert concrete_task_imports(imports, "lagrseq.running") == {
        "lagrseq.running.runner": ["lagrseq.builtin_tasks.cube_stacking"],
        "lagrseq.running.wiring": ["lagrseq.envs", "lagrseq.envs.image_completion"],
    }


def import_graph() -> dict[str, set[str]]:
    """Module -> the lagrseq modules it imports, anywhere in its source (top level or inside a
    function: a lazy import is still a dependency), read from the syntax tree."""
    import ast

    names = set(modules())
    graph: dict[str, set[str]] = {}
    for name in names:
        spec = importlib_util.find_spec(name)
        assert spec is not None and spec.origin is not None
        package = name if spec.origin.endswith("__init__.py") else name.rpartition(".")[0]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(Path(spec.origin).read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                edges |= {_owner(alias.name, names) for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                    base = f"{parent}.{base}" if base else parent
                edges |= {_owner(f"{base}.{alias.name}", names) for alias in node.names}
        graph[name] = {e for e in edges if e in names and e != name}
    return graph


def _owner(dotted: str, names: set[str]) -> str:
    """The module ``dotted`` names or lives in (``lagrseq.x.func`` -> ``lagrseq.x``)."""
    while dotted and dotted not in names:
        dotted = dotted.rpartition(".")[0]
    return dotted


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in sorted(graph.get(node, ())):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules() -> None:
    """No two modules import each other, directly or through others (lazy imports included):
    the package's modules form layers, not a knot (the package ``lagrseq`` itself, which every
    module's import loads, is left out)."""
    graph = import_graph()
    graph.pop("lagrseq", None)
    graph = {m: e - {"lagrseq"} for m, e in graph.items()}
    assert cycles(graph) == []
