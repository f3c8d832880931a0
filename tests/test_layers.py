"""The import rules of DESIGN section 2, for every module of the package, in fresh interpreters.

The layer map below is the rule, written once: each module belongs to the layer of its longest
matching prefix and must not load anything its layer forbids (``lagrseq.x`` forbids the package
and its submodules). A module that matches no layer fails the test, so a new module must be
placed on the map.
"""

from __future__ import annotations

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
WIRING = ("lagrseq.wiring", "lagrseq.runner", "lagrseq.recording", "lagrseq.probe", "lagrseq.reproduce", "lagrseq.cli")
UPPER = ("lagrseq.experiment", "lagrseq.adapters", "lagrseq.lagr", "lagrseq.seq", "lagrseq.analysis", *WIRING)
BASE = ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", "lagrseq.suite", *UPPER)

LAYERS: dict[str, tuple[str, ...]] = {
    # config, errors, seeding, paths, tomlfile: stdlib + numpy; anyone may import them
    "lagrseq": BASE + HEAVY + ("mcap", "pandas", "matplotlib"),
    "lagrseq.__main__": (),  # ``python -m lagrseq``: the command line, nothing else
    "lagrseq.cli": ("lagrseq.experiment", "lagrseq.wiring", *HEAVY, "mcap", "pandas", "matplotlib"),
    "lagrseq.tasks": ("lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", "lagrseq.suite", *UPPER, *HEAVY, "mcap"),
    "lagrseq.envs": ("lagrseq.llm", "lagrseq.agents", "lagrseq.logs", "lagrseq.suite", *UPPER, "torch", "httpx", "mcap"),
    "lagrseq.agents": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.llm", "lagrseq.logs", "lagrseq.suite", *UPPER, "gymnasium", "httpx", "mcap"),
    "lagrseq.llm": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.logs", "lagrseq.suite", *UPPER, "torch", "gymnasium"),
    "lagrseq.logs": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.suite", *UPPER, *HEAVY),
    "lagrseq.analysis": ("lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.experiment", "lagrseq.adapters", *WIRING, *HEAVY),
    "lagrseq.suite": ("lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", *UPPER, *HEAVY),
    "lagrseq.lagr": (*PROVIDERS, "lagrseq.logs", "lagrseq.envs", "lagrseq.experiment", *WIRING, *HEAVY),
    "lagrseq.seq": ("lagrseq.llm", "lagrseq.logs", "lagrseq.envs", "lagrseq.tasks", "lagrseq.experiment", *WIRING, *HEAVY),
    "lagrseq.policies": ("lagrseq.llm", "lagrseq.logs", "lagrseq.envs", "lagrseq.tasks", "lagrseq.agents", "lagrseq.experiment", *WIRING, *HEAVY),
    "lagrseq.adapters": ("lagrseq.llm", "lagrseq.logs", "lagrseq.envs", "lagrseq.experiment", *WIRING, *HEAVY),
    # the loop knows interfaces only: no concrete env, provider or sink implementation
    "lagrseq.experiment": (*PROVIDERS, "lagrseq.envs", "lagrseq.logs.mcap_writer", "lagrseq.analysis", *WIRING, *HEAVY),
    # wiring and the runners import the heavy parts lazily, where a trial needs them
    "lagrseq.wiring": ("lagrseq.analysis", "lagrseq.runner", "lagrseq.recording", "lagrseq.reproduce", "lagrseq.cli", *HEAVY),
    "lagrseq.frontier": ("lagrseq.analysis", "lagrseq.cli", *HEAVY),
    "lagrseq.runner": ("lagrseq.analysis", "lagrseq.recording", "lagrseq.reproduce", "lagrseq.cli", "dask", "distributed", *HEAVY),
    "lagrseq.probe": ("lagrseq.analysis", "lagrseq.recording", "lagrseq.reproduce", "lagrseq.cli", *HEAVY),
    "lagrseq.recording": ("lagrseq.analysis", "lagrseq.runner", "lagrseq.reproduce", "lagrseq.cli", *HEAVY),
    "lagrseq.reproduce": ("lagrseq.cli", "dask", "distributed", *HEAVY),
    # executors: the process pool and the interface; dask only in its own module, on demand
    "lagrseq.executors": ("lagrseq.analysis", "lagrseq.recording", "lagrseq.reproduce", "lagrseq.cli", "dask", "distributed", *HEAVY),
    "lagrseq.dask_executor": ("lagrseq.analysis", "lagrseq.recording", "lagrseq.reproduce", "lagrseq.cli", *HEAVY),
    # the robot behind the arm env: no RL, no LLM, no logs; pybullet and grpc only when built
    "lagrseq.robot": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", "lagrseq.suite", *UPPER, *HEAVY, "grpc", "mcap", "gymnasium"),
    # the generated gRPC code imports protobuf and grpc themselves (the arm extra)
    "lagrseq.robot.proto": ("lagrseq.tasks", "lagrseq.envs", "lagrseq.agents", "lagrseq.llm", "lagrseq.logs", *UPPER, *HEAVY, "mcap"),
    "lagrseq.audit": ("lagrseq.reproduce", "lagrseq.cli", *HEAVY),
    "lagrseq.authors": ("lagrseq.analysis", "lagrseq.runner", "lagrseq.reproduce", "lagrseq.cli", *HEAVY),
    # lagrseq info: metadata only; torch is imported inside the call that names its device
    "lagrseq.info": ("lagrseq.analysis", "lagrseq.runner", "lagrseq.reproduce", "lagrseq.cli", "dask", "distributed", *HEAVY, "mcap", "pandas", "matplotlib"),
}
OPTIONAL = {
    "lagrseq.dask_executor": ("distributed",),
    "lagrseq.robot.proto.robot_pb2": ("google.protobuf",),
    "lagrseq.robot.proto.robot_pb2_grpc": ("google.protobuf", "grpc"),
}
"""Modules that need an extra to import at all (the Dask executor, generated gRPC code): checked
only where it is installed."""
ANYONE = ("lagrseq.config", "lagrseq.errors", "lagrseq.seeding", "lagrseq.paths", "lagrseq.progress", "lagrseq.tomlfile")


def modules() -> list[str]:
    return sorted(m.name for m in pkgutil.walk_packages(lagrseq.__path__, "lagrseq."))


def layer_of(module: str) -> str:
    if module in ANYONE:
        return "lagrseq"
    matches = [layer for layer in LAYERS if module == layer or module.startswith(layer + ".")]
    return max(matches, key=len)


def loaded_after_import(names: list[str]) -> dict[str, list[str]]:
    """For each module, what ``import module`` loads in a fresh interpreter (one forked child per
    module from a parent that has imported nothing of lagrseq)."""
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
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": str(ROOT)}, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


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
    loaded = loaded_after_import(names)
    problems = {}
    for name in names:
        assert loaded[name] is not None, f"importing {name} failed"
        forbidden = LAYERS[layer_of(name)]
        bad = sorted(m for m in loaded[name] if any(m == f or m.startswith(f + ".") for f in forbidden) and m != name)
        if bad:
            problems[name] = bad
    assert problems == {}, f"layer rules broken (module: what it loads): {problems}"
