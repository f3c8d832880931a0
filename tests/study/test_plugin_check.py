"""``lagrseq plugins --check``: exit 0 for the example plugin, and one line per problem (exit 2)
for plugins whose knob or flag another owner holds, whose env fails Gymnasium's env checker, or
whose task declares a logged field its env never logs."""

from __future__ import annotations

from pathlib import Path

from tests.support.plugins import ROOT, distribution, example_code, lagrseq

ENTRY_POINTS = "[lagrseq.tasks]\nnumber-sequence = lagrseq_numseq:task_spec\n[lagrseq.policies]\nbackoff = lagrseq_numseq:policy_spec\n"
VARIANTS = '''
import dataclasses

import numpy as np
from lagrseq_numseq import task_spec
from lagrseq.registry import Knob, PolicySpec


class Outside:
    """The example's env, its first observation outside its observation space."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, *, seed=None, options=None):
        observation, info = self.env.reset(seed=seed, options=options)
        return np.full_like(observation, 10**6), info


def outside():
    spec = task_spec()
    make = spec.make_env
    return dataclasses.replace(spec, suite=None, make_env=lambda config, where: OutsideEnv(make(config, where)))


def silent():
    spec = task_spec()
    return dataclasses.replace(spec, suite=None, episode_fields={**spec.episode_fields, "never_set": "integer"})


def budget():
    return PolicySpec("budgeted", lambda section, seq_agent: None, (Knob("budget", 5, le=10),))


class Crash:
    def decide(self, context):
        raise RuntimeError("cannot decide")

    def update(self, context, asked, query_reward):
        pass


def crash():
    return PolicySpec("crashy", lambda section, seq_agent: Crash(), ("budget",))
'''


def _site(root: Path, variant: str = "") -> Path:
    """The example plugin installed, or (``variant``) a plugin giving its task with one fault and
    a policy whose knob is a [secondary] field."""
    site = root / "site"
    site.mkdir()
    if not variant:
        distribution(site, "lagrseq-numseq", "0.1.0", "numseq_unused", "", ENTRY_POINTS)
        return site
    source = VARIANTS.replace("class Outside:", "import gymnasium\n\n\nclass OutsideEnv(gymnasium.Wrapper):").replace(
        "    def __init__(self, env):\n        self.env = env\n\n    def __getattr__(self, name):\n        return getattr(self.env, name)\n\n", "")
    distribution(site, "variants-plugin", "0.3", "variantsplug", source,
                 f"[lagrseq.tasks]\nnumber-sequence = variantsplug:{variant}\n[lagrseq.policies]\nbudgeted = variantsplug:budget\ncrashy = variantsplug:crash\n")
    return site


def _check(site: Path, cwd: Path):  # type: ignore[no-untyped-def]
    code = example_code(site.parent)
    return lagrseq(site, "plugins", "--check", cwd=cwd, env={"PYTHONPATH": f"{site}:{code}:{ROOT}"})


def test_the_example_plugin_passes_the_check(tmp_path: Path) -> None:
    done = _check(_site(tmp_path), tmp_path)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert "ok: task 'number-sequence' (lagrseq-numseq 0.1.0) loads" in done.stdout
    assert "ok: policy 'backoff' (lagrseq-numseq 0.1.0) loads" in done.stdout and "0 problems found" in done.stdout


def test_the_check_names_each_problem_in_one_line(tmp_path: Path) -> None:
    shown = {}
    for variant in ("outside", "silent"):
        (tmp_path / variant).mkdir()
        done = _check(_site(tmp_path / variant, variant), tmp_path)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.splitlines()
        assert len(lines) == 3 and all(line.startswith("lagrseq plugins --check: ") for line in lines), lines
        budget = next(line for line in lines if "'budgeted'" in line)
        crashy = next(line for line in lines if "'crashy'" in line)
        shown[variant] = next(line for line in lines if "'number-sequence'" in line)
        assert "plugin 'budgeted' (variants-plugin 0.3, group lagrseq.policies)" in budget and "is a [secondary] field" in budget
        assert "policy 'crashy' (variants-plugin 0.3): a 3-episode run of cube-stacking with it failed: RuntimeError: cannot decide" in crashy
        assert "3 problems found" in done.stdout
    assert "task 'number-sequence' (variants-plugin 0.3): Gymnasium's env checker: " in shown["outside"] and "observation" in shown["outside"]
    assert "it declares episode_fields 'never_set', but a 3-episode run never logged it" in shown["silent"]
