"""``lagrseq plugins --check``: what a plugin author runs before publishing.

Each installed plugin part must load, and its names, knobs and flags collide with nothing (the
registry's ownership rules: a part that breaks one was skipped, and its line is a problem here).
Each plugin policy must decide a short trial of the built-in cube task. Each plugin task must
build its environment from its own default preset, pass Gymnasium's
``gymnasium.utils.env_checker.check_env`` (an env that is not a ``gymnasium.Env``, as the
registry allows, is reported as not checkable, with that reason), and run a short trial whose log
holds every field it declares (``episode_fields``, ``step_fields``) at least once. Provider kinds
(which may need a server or a key) and executors (a cluster) are loaded and checked for
ownership only.
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
import warnings
from pathlib import Path
from typing import Any

from lagrseq import registry
from lagrseq.progress import Reporter

CHECK_EPISODES = 3
"""Episodes of the short trial each plugin task runs."""
CHECK_STEPS = 200
"""At most this many steps in each of them (``env`` sections with a ``horizon`` field)."""


def check(reporter: Reporter) -> list[str]:
    """Every problem of the installed plugins, one line each (``reporter`` says what was checked)."""
    for one in registry.REGISTRIES.values():
        one.names()  # every group loaded first: its skipped plugins are in FAILURES
    problems = [f"plugin {registry.printable(repr(f.entry_point))} ({registry.printable(f.source)}, group {f.group}): {f.problem}"
                for f in registry.FAILURES]
    for kind, one in registry.REGISTRIES.items():
        for entry in one.entries():
            if entry.distribution == registry.BUILTIN:
                continue
            where = f"{one.kind} {registry.printable(repr(entry.name))} ({registry.printable(entry.source)})"
            found = _task_problems(entry.spec, reporter, where) if kind == "tasks" else []
            found += _policy_problems(entry.spec) if kind == "policies" else []
            problems += [f"{where}: {problem}" for problem in found]
            if not found:
                reporter.say(f"ok: {where} loads; its names, knobs and flags are its own" + CHECKED.get(kind, ""))
    return problems


CHECKED = {
    "tasks": "; its env and a short run checked",
    "policies": f"; a {CHECK_EPISODES}-episode run on cube-stacking decides with it",
}
"""What ``--check`` did with each kind of part besides loading it (provider kinds may need a
server or a key, executors a cluster: they are loaded and their flags checked only)."""


def _policy_problems(spec: registry.PolicySpec) -> list[str]:
    """A short unlogged trial of the built-in cube task asking with the plugin policy at its
    knobs' defaults ([] when it runs)."""
    from lagrseq import config as cfg
    from lagrseq.running.runner import run_one

    try:
        config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=[f"secondary.policy={json.dumps(spec.name)}", f"run.episodes={CHECK_EPISODES}"])
        run_one(config, 0, 0, "mock", Path("unused.mcap"), log=False)
    except Exception as exc:  # noqa: BLE001 - a plugin policy's run: any failure is one line
        return [f"a {CHECK_EPISODES}-episode run of cube-stacking with it failed: {registry._one_line(exc)}"]
    return []


def _task_problems(spec: registry.TaskSpec, reporter: Reporter, where: str) -> list[str]:
    """The env checker's and a short run's problems with one plugin task ([] when none)."""
    from lagrseq import config as cfg
    from lagrseq.errors import LagrseqError

    try:
        config = cfg.load(spec.name, "baseline", spec.frontier_preset if spec.frontier_preset in cfg.task_presets(spec.name) else "upstream")
    except LagrseqError as exc:
        return [f"its default configuration is refused: {exc}"]
    problem = _env_problem(spec, config, reporter, where)
    if problem:
        return [problem]
    return _run_problems(spec, config)


def _env_problem(spec: registry.TaskSpec, config: Any, reporter: Reporter, where: str) -> str:
    """Gymnasium's env checker on the task's env ("" when it passes or cannot apply)."""
    try:
        import gymnasium
        from gymnasium.utils.env_checker import check_env
    except ImportError:  # pragma: no cover - gymnasium is a dependency of every task
        reporter.say(f"note: {where}: gymnasium is not installed; its env checker was not run")
        return ""
    try:
        env = spec.make_env(config, None)
    except Exception as exc:  # noqa: BLE001 - a plugin's env: any failure is its problem, one line
        return f"make_env raised {registry._one_line(exc)}"
    try:
        if not isinstance(env, gymnasium.Env):
            reporter.say(f"note: {where}: its env is a {type(env).__name__}, not a gymnasium.Env (reset, step and close are "
                "all lagrseq needs), so Gymnasium's env checker does not apply")
            return ""
        with warnings.catch_warnings(record=True) as seen, contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("always")
            check_env(env, skip_render_check=True)
        for warning in seen:
            reporter.say(f"note: {where}: Gymnasium's env checker warns: {registry.printable(' '.join(str(warning.message).split()))}")
    except Exception as exc:  # noqa: BLE001 - what the checker finds is the plugin's problem
        return f"Gymnasium's env checker: {registry._one_line(exc)}"
    finally:
        with contextlib.suppress(Exception):
            env.close()
    return ""


def _run_problems(spec: registry.TaskSpec, config: Any) -> list[str]:
    """A short trial of the task, logged: every declared field must be in the log at least once."""
    import dataclasses

    from lagrseq.logs.reader import read_topic
    from lagrseq.running.runner import run_one

    config = dataclasses.replace(config, run=dataclasses.replace(config.run, episodes=CHECK_EPISODES))
    if hasattr(config.env, "horizon") and isinstance(config.env.horizon, int):
        config = dataclasses.replace(config, env=dataclasses.replace(config.env, horizon=min(config.env.horizon, CHECK_STEPS)))
    with tempfile.TemporaryDirectory(prefix="lagrseq-check-") as folder:
        path = Path(folder) / "trial-000.mcap"
        try:
            run_one(config, 0, 0, "mock", path)
            episodes, steps = read_topic(path, "/episode"), read_topic(path, "/transition")
        except Exception as exc:  # noqa: BLE001 - a plugin task's run: any failure is one line
            return [f"a {CHECK_EPISODES}-episode run failed: {registry._one_line(exc)}"]
    problems = []
    for what, fields, records in (("episode_fields", spec.episode_fields, episodes), ("step_fields", spec.step_fields, steps)):
        for name in fields:
            if all(record.get(name) is None for record in records):
                problems.append(f"it declares {what} {registry.printable(repr(name))}, but a {CHECK_EPISODES}-episode run never logged it "
                                f"(its env sets info[{'log_episode' if what == 'episode_fields' else 'log_step'!r}][{name!r}])")
    return problems
