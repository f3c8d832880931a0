"""Plugins by entry point: real distributions (a ``.dist-info`` with ``entry_points.txt`` on
PYTHONPATH) loaded by fresh interpreters. A broken plugin is one stderr line naming it and is
skipped; every other plugin and every built-in keeps working."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lagrseq import registry
from lagrseq.errors import UsageError
from tests.support.plugins import GOOD, distribution, lagrseq


@pytest.fixture()
def plugins(tmp_path: Path) -> Path:
    site = tmp_path / "site"
    site.mkdir()
    distribution(site, "good-plugin", "1.2", "goodplug", GOOD, "[lagrseq.policies]\ncoin = goodplug:policy\n")
    distribution(site, "broken-plugin", "0.1", "brokenplug", "raise ImportError('no module named numsq')\n", "[lagrseq.tasks]\nbroken = brokenplug:task\n")
    distribution(
        site, "clash-plugin", "0.3", "clashplug",
        "from lagrseq.registry import PolicySpec\nspec = PolicySpec('seq', lambda s, a: None)\n",
        "[lagrseq.policies]\nclash = clashplug:spec\n",
    )
    return site


def test_plugins_lists_builtins_and_plugins_and_names_each_broken_one_once(plugins: Path, tmp_path: Path) -> None:
    done = lagrseq(plugins, "plugins", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 2, lines
    broken = next(line for line in lines if "'broken'" in line)
    assert "broken-plugin 0.1" in broken and "ImportError: no module named numsq" in broken and "skipped" in broken
    clash = next(line for line in lines if "'clash'" in line)
    assert "its policy 'seq' is a built-in (lagrseq's own); built-ins win" in clash
    out = done.stdout
    assert re.search(r"\n  coin +good-plugin 1\.2 \[coin = goodplug:policy\]: every other decision\n", out)
    for builtin in ("cube-stacking", "arm-arrangement", "recorded", "thompson", "dask"):
        assert f"  {builtin} " in out
    assert "skipped plugins: 2" in out


def test_a_broken_plugin_does_not_break_a_run_and_a_plugin_policy_runs(plugins: Path, tmp_path: Path) -> None:
    small = ["--trials", "1", "--set", "run.episodes=3", "--quiet", "--jobs", "1", "--out", str(tmp_path / "runs")]
    done = lagrseq(plugins, "run", "cube-stacking", "--method", "lagr-seq", "--set", 'secondary.policy="coin"', *small, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    skipped = [line for line in done.stderr.splitlines() if line.startswith("lagrseq: plugin")]
    assert len(skipped) == 2 and "'broken'" in skipped[0] + skipped[1] and "'clash'" in skipped[0] + skipped[1]
    logs = list((tmp_path / "runs").rglob("trial-000.mcap"))
    assert len(logs) == 1
    replayed = lagrseq(plugins, "replay", str(tmp_path / "runs"), "--out", str(tmp_path / "report"), cwd=tmp_path)
    assert replayed.returncode == 0, replayed.stderr
    unknown = lagrseq(plugins, "run", "broken", *small, cwd=tmp_path)
    assert unknown.returncode == 2
    assert "invalid choice: 'broken'" in unknown.stderr


def test_registry_refuses_bad_names_and_wrong_spec_types() -> None:
    scratch: registry.Registry[registry.PolicySpec] = registry.Registry("policy", "none", registry.PolicySpec, {}, True)
    with pytest.raises(ValueError, match="without ':' or ','"):
        scratch.register(registry.PolicySpec("a:b", lambda s, a: None))
    with pytest.raises(TypeError, match="takes PolicySpec"):
        scratch.register(registry.ExecutorSpec("x", lambda j, s, y: None))  # type: ignore[arg-type]
    scratch.register(registry.PolicySpec("fine", lambda s, a: None))
    with pytest.raises(UsageError, match="unknown policy 'other'; expected one of: fine"):
        scratch.get("other")


ECHO = '''
from dataclasses import dataclass, field

from lagrseq.registry import ProviderKind, flag


@dataclass(frozen=True)
class EchoOptions:
    echo_profile: str = field(default="ideal", metadata=flag("--echo-profile", "the mock profile it answers with (default {default})", metavar="NAME"))


def make(spec, config, rng, options):
    from lagrseq.llm.mock import MockProvider
    from lagrseq.running.wiring import extrapolator

    return MockProvider(extrapolator(config, options.echo_profile), rng, name=f"echo/{options.echo_profile}")


def provider():
    return ProviderKind("echo", "echo", make, options=EchoOptions, source="mock", synthetic=True, description="the mock, profile by option")
'''


def test_a_plugin_provider_declares_its_own_options(tmp_path: Path) -> None:
    """A plugin provider kind's options dataclass brings its own flag: parsed, built into its
    options, written into the logged provider_options beside the built-ins' defaults; refused
    (one line) with another provider, as a built-in kind's flag is with the plugin's."""
    import json

    from lagrseq.logs.reader import read_info

    site = tmp_path / "site"
    site.mkdir()
    distribution(site, "echo-plugin", "0.2", "echoplug", ECHO, "[lagrseq.providers]\necho = echoplug:provider\n")
    small = ["--trials", "1", "--set", "run.episodes=2", "--quiet", "--jobs", "1", "--out", str(tmp_path / "runs")]
    done = lagrseq(site, "run", "cube-stacking", "--method", "lagr", "--provider", "echo", "--echo-profile", "authors-t0", *small, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    (log,) = (tmp_path / "runs").rglob("trial-000.mcap")
    logged = json.loads(read_info(log).run["provider_options"])
    assert logged["echo_profile"] == "authors-t0" and logged["on_miss"] == "error" and logged["local_n_ctx"] == 2048
    for argv, named in [(["--provider", "mock", "--echo-profile", "authors-t0"], "--echo-profile applies to --provider echo only, not mock"),
                        (["--provider", "echo", "--max-queries", "3"], "--max-queries applies to --provider recorded:STORE or live or local only, not echo")]:
        refused = lagrseq(site, "run", "cube-stacking", *argv, *small, cwd=tmp_path)
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and named in refused.stderr, refused.stderr
    helped = lagrseq(site, "run", "--help", cwd=tmp_path)
    assert "--echo-profile NAME" in helped.stdout and "options of --provider echo" in helped.stdout


EVERY = '''
from lagrseq.registry import Knob, PolicySpec


class Every:
    """Ask at every n-th decision."""

    def __init__(self, n):
        self.n, self.seen = n, 0

    def decide(self, context):
        self.seen += 1
        return int(self.seen % self.n == 0)

    def update(self, context, asked, query_reward):
        pass


def policy():
    knob = Knob("every_n", 2, ge=1, le=100, candidates=("2", "4"), help="ask at every n-th decision")
    return PolicySpec("every", lambda section, seq_agent: Every(section.knob("every_n")), ("budget", knob), description="every n-th decision")
'''


def test_a_plugin_policy_declares_its_own_knob(tmp_path: Path) -> None:
    """A plugin policy's Knob is read from [secondary] (--set), checked (type, range, owner: one
    line, exit 2), logged in the configuration, and set by the frontier's POLICY:KNOB=VALUE."""
    import json

    from lagrseq.logs.reader import read_info

    site = tmp_path / "site"
    site.mkdir()
    distribution(site, "every-plugin", "0.1", "everyplug", EVERY, "[lagrseq.policies]\nevery = everyplug:policy\n")
    small = ["--set", "run.episodes=3", "--quiet", "--jobs", "1"]
    every = ["--method", "lagr-seq", "--set", 'secondary.policy="every"']
    done = lagrseq(site, "run", "cube-stacking", *every, "--set", "secondary.every_n=3", "--trials", "1", *small, "--out", str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    (log,) = (tmp_path / "runs").rglob("trial-000.mcap")
    secondary = json.loads(read_info(log).run["config"])["secondary"]
    assert secondary["knobs"] == {"every_n": 3} and secondary["policy"] == "every"
    shown = lagrseq(site, "config", "cube-stacking", *every, "--set", "secondary.every_n=3", cwd=tmp_path)
    assert shown.returncode == 0 and re.search(r"\nevery_n = 3  # .*a knob of policy every, set \(default \d+\)\n", shown.stdout), shown.stderr
    for sets, message in [
        (["--set", "secondary.every_n=0"], "secondary.every_n = 0 is out of range"),
        (["--set", 'secondary.every_n="3"'], "secondary.every_n = '3' has the wrong type; expected int"),
        (["--set", "secondary.every_m=3"], "unknown field secondary.every_m"),
        (["--set", 'secondary.policy="seq"', "--set", "secondary.every_n=3"], "secondary.every_n is a knob of policy every, not of secondary.policy = 'seq'"),
    ]:
        refused = lagrseq(site, "run", "cube-stacking", *every, *sets, "--trials", "1", *small, "--out", str(tmp_path / "bad"), cwd=tmp_path)
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and message in refused.stderr, refused.stderr
    frontier = ["frontier", "cube-stacking", "--trials", "1", *small, "--no-matched-random"]
    done = lagrseq(site, *frontier, "--policies", "always,every:every_n=4", "--out", str(tmp_path / "fr"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "every (every_n 4)" in done.stdout, done.stdout
    for policies, message in [("every:every_n=0", "secondary.every_n = 0 is out of range"), ("every:every_m=1", "expected NAME:FIELD=VALUE with FIELD one of")]:
        refused = lagrseq(site, *frontier, "--policies", policies, "--out", str(tmp_path / "fr-bad"), cwd=tmp_path)
        assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and message in refused.stderr, refused.stderr


def test_the_builtin_policies_knobs_are_their_secondary_fields() -> None:
    """A built-in knob is the [secondary] field of its name (so their logged configuration is
    what it was): every section has the field, and the knob accepts the field's default (the
    tabular section's default is the knob's)."""
    import dataclasses

    from lagrseq import config as cfg

    for cls in (cfg.TabularSecondaryConfig, cfg.NeuralSecondaryConfig):
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        for spec in registry.POLICIES.specs():
            for name in registry.knob_names(spec):
                assert name in defaults, (cls.__name__, spec.name, name)
            for knob in registry.own_knobs(spec):
                assert knob.check(defaults[knob.name], knob.name) == defaults[knob.name]
                if cls is cfg.TabularSecondaryConfig:
                    assert knob.default == defaults[knob.name], (spec.name, knob.name)
    from lagrseq.study.frontier import TUNE_GRID

    assert TUNE_GRID == {"seq": ("query_cost", ("0", "0.25", "0.5")), "random": ("ask_probability", ("0.05", "0.1", "0.25", "0.5")),
                         "thompson": ("query_cost", ("0", "0.25", "0.5", "1")), "advance": ("stall_steps", ("16", "64", "256", "1000000"))}


def test_the_builtin_providers_log_their_options_as_before() -> None:
    """The trial metadata's provider_options record of a built-in kind is the JSON the shared
    options bag wrote: every built-in option at its default, the run's kind's as given."""
    import json

    from lagrseq.running.wiring import default_options, provider_options

    legacy = {
        "base_url": "https://api.openai.com/v1", "api_key_env": "OPENAI_API_KEY", "server": "openai", "on_miss": "error",
        "price_table": None, "max_cost_usd": None, "max_queries": None, "read_timeout_s": 120.0, "request_deadline_s": 300.0,
        "max_response_bytes": 4 * 1024 * 1024, "local_n_ctx": 2048, "local_threads": 0,
    }
    for spec in ("mock", "mock:authors-t0", "live", "recorded:store", "local"):
        assert registry.logged_options(default_options(spec)) == json.dumps(legacy, sort_keys=True), spec
    given = {"on_miss": "live", "base_url": "http://127.0.0.1:9/v1", "max_queries": 6, "read_timeout_s": 3.0}
    recorded = provider_options("recorded:store", given)
    assert registry.logged_options(recorded) == json.dumps({**legacy, **given}, sort_keys=True)
    limited = registry.replace_part(recorded, dataclasses_replace(registry.find_part(recorded, type(recorded.live.limits)), budget_ledger="x.sqlite"))
    assert limited.live.limits.budget_ledger == "x.sqlite" and registry.logged_options(limited) == registry.logged_options(recorded)
    local = provider_options("local", {"n_ctx": 4096, "threads": 2})
    assert json.loads(registry.logged_options(local)) == {**legacy, "local_n_ctx": 4096, "local_threads": 2}


def dataclasses_replace(obj: object, **changes: object) -> object:
    import dataclasses

    return dataclasses.replace(obj, **changes)  # type: ignore[type-var]


@given(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True), st.text(max_size=80), st.lists(st.integers(), max_size=3)))
def test_a_knob_takes_only_values_of_its_type_and_range(value: object) -> None:
    from lagrseq.errors import ConfigError

    for knob in (registry.Knob("n", 2, ge=1, le=100), registry.Knob("f", 0.5, ge=0.0, le=1.0), registry.Knob("s", "a", choices=("a", "b")),
                 registry.Knob("b", False)):
        try:
            checked = knob.check(value, f"secondary.{knob.name}")
        except ConfigError as error:
            assert "\n" not in str(error) and f"secondary.{knob.name} = " in str(error) and len(str(error)) < 300
            continue
        assert type(checked) is type(knob.default)
        if isinstance(checked, (int, float)) and not isinstance(checked, bool):
            assert knob.ge is not None and knob.le is not None and knob.ge <= checked <= knob.le
        if knob.choices:
            assert checked in knob.choices
