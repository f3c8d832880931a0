"""One owner per name, knob and flag. A policy's knob set under a policy that does not read it is
refused on every command and in config files (one line naming the knob, its owners and the
policy in use); a plugin that takes a name, knob or flag someone else owns is skipped at
registration with one line naming both owners, whatever the order of the entry points; a plugin
flag that takes a command's own option skips that plugin and never breaks the command."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from tests.support.plugins import GOOD, distribution, lagrseq, skipped


@pytest.mark.parametrize(
    ("policy", "knob", "owners"),
    [
        ("random", "stall_steps=16", "advance"),
        ("thompson", "reask_decay=0.5", "advance"),
        ("seq", "ask_probability=0.2", "random"),
        ("random", "thompson_prior=[2.0, 2.0]", "thompson"),
        ("advance", 'query_reward="logistic"', "seq, thompson"),
        ("thompson", "learning_rate=0.5", "seq"),
    ],
)
def test_a_builtin_policys_knob_under_another_policy_is_refused(policy: str, knob: str, owners: str, tmp_path: Path) -> None:
    name = knob.partition("=")[0]
    sets = [f'secondary.policy="{policy}"', f"secondary.{knob}"]
    with pytest.raises(ConfigError) as refused:
        cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=sets)
    message = str(refused.value)
    assert "\n" not in message and f"secondary.{name} (--set) is a knob of policy {owners}, not of secondary.policy = '{policy}'" in message
    file = tmp_path / "mine.toml"
    file.write_text(f'[secondary]\npolicy = "{policy}"\n{knob.replace("=", " = ")}\n')
    with pytest.raises(ConfigError, match=rf"secondary\.{name} \(.*mine\.toml\) is a knob of policy {owners}, not of"):
        cfg.load("object-arrangement", "lagr-seq", "upstream", config_file=file)


def test_a_knob_of_the_policy_in_use_and_the_presets_own_values_are_accepted() -> None:
    random = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=['secondary.policy="random"', "secondary.ask_probability=0.2"])
    assert random.secondary.ask_probability == 0.2  # the preset's learning_rate and query_reward are not the user's
    seq = cfg.load("cube-stacking", "lagr-seq", "paper", overrides=['secondary.query_reward="logistic"', "secondary.query_cost=0.5"])
    assert seq.secondary.query_reward == "logistic" and seq.secondary.query_cost == 0.5


def test_run_refuses_another_policys_knob_in_one_line(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    done = lagrseq(tmp_path, "run", "cube-stacking", "--set", 'secondary.policy="random"', "--set", "secondary.stall_steps=16",
                   "--trials", "1", "--out", str(out), cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "secondary.stall_steps (--set) is a knob of policy advance, not of secondary.policy = 'random'" in done.stderr
    assert not out.exists()


def _policy(name: str, knob: str) -> str:
    """A plugin policy ``name`` with the own knob ``knob`` (a ``Knob(...)`` expression)."""
    return GOOD.replace("import PolicySpec", "import Knob, PolicySpec").replace(
        'PolicySpec("coin", lambda section, seq_agent: Coin(), ("budget",)', f'PolicySpec("{name}", lambda section, seq_agent: Coin(), ("budget", {knob})'
    )


OPTIONS = '''
from dataclasses import dataclass, field

from lagrseq.registry import ProviderKind, flag


@dataclass(frozen=True)
class Options:
    {field}: {type} = field(default={default}, metadata=flag("{flag}", "a setting"))


def provider():
    return ProviderKind("{name}", "{name}", lambda spec, config, rng, options: None, options=Options, source="mock", synthetic=True)
'''


def _provider(name: str, field: str, flag: str, kind: str = "int", default: str = "1") -> str:
    return OPTIONS.format(name=name, field=field, type=kind, default=default, flag=flag)


@pytest.fixture(scope="module")
def contested(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Plugins that each take a name, knob or flag another part owns (and two that behave)."""
    site = tmp_path_factory.mktemp("site")
    policies = {
        "budgetknob": _policy("budgetknob", 'Knob("budget", 5, le=10)'),  # a [secondary] field
        "policyknob": _policy("policyknob", 'Knob("policy", "x")'),  # a reserved word
        "costknob": _policy("costknob", 'Knob("query_cost", "high")'),  # a float field, as a str
        "rangedword": _policy("rangedword", 'Knob("level", "high", ge=0)'),  # a range on a str
        "listknob": _policy("listknob", 'Knob("weights", [1, 2])'),  # a type no config holds
        "alphaint": _policy("alphaint", 'Knob("alpha", 2, ge=1)'),  # two plugins, one knob name
        "alphafloat": _policy("alphafloat", 'Knob("alpha", 0.5, ge=0.0, le=1.0)'),
        "fine": _policy("fine", 'Knob("fine_k", 3, ge=1, le=9, candidates=("2", "4"))'),
    }
    for name, source in policies.items():
        distribution(site, f"{name}-plugin", "0.1", f"{name}plug", source, f"[lagrseq.policies]\n{name} = {name}plug:policy\n")
    # two plugins claiming one policy name: the impostor's entry point sorts first
    for dist, entry in (("impostor-dist", "aaa"), ("real-dist", "zzz")):
        distribution(site, dist, "1.0", f"{entry}plug", GOOD.replace('"coin"', '"shared"'), f"[lagrseq.policies]\n{entry} = {entry}plug:policy\n")
    providers = {
        "ctx": _provider("ctx", "n_ctx", "--n-ctx"),  # the local kind's flag and option
        "fooone": _provider("fooone", "foo_a", "--foo"),  # two plugins, one flag
        "footwo": _provider("footwo", "foo_b", "--foo", "float", "0.5"),
        "trialsy": _provider("trialsy", "trials_n", "--trials"),  # a command's own option
        "echoish": _provider("echoish", "echoish_level", "--echoish-level"),
    }
    for name, source in providers.items():
        distribution(site, f"{name}-plugin", "0.2", f"{name}plug", source, f"[lagrseq.providers]\n{name} = {name}plug:provider\n")
    return site


def test_plugins_that_take_another_owners_name_knob_or_flag_are_skipped_naming_both(contested: Path, tmp_path: Path) -> None:
    done = lagrseq(contested, "plugins", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    found = skipped(done.stderr)
    assert len(done.stderr.splitlines()) == len(found)
    assert "knob 'budget' of policy 'budgetknob' is a [secondary] field (owned by lagrseq and the tasks)" in found["budgetknob"]
    assert "knob 'policy' of policy 'policyknob' is a reserved word of [secondary] (owned by lagrseq)" in found["policyknob"]
    assert "knob 'query_cost' of policy 'costknob' is a [secondary] field" in found["costknob"]
    assert "a range applies to numbers only" in found["rangedword"]
    assert "its default [1, 2] is a list; expected bool, int, float or str" in found["listknob"]
    assert "its knob 'alpha' is also claimed by alphafloat-plugin 0.1" in found["alphaint"]
    assert "its knob 'alpha' is also claimed by alphaint-plugin 0.1" in found["alphafloat"]
    assert "its policy 'shared' is also claimed by real-dist 1.0" in found["aaa"]
    assert "its policy 'shared' is also claimed by impostor-dist 1.0" in found["zzz"]
    assert "option n_ctx is already declared by provider 'local' (lagrseq); flags are never merged" in found["ctx"]
    assert "its flag '--foo' is also claimed by footwo-plugin 0.2" in found["fooone"]
    assert "its flag '--foo' is also claimed by fooone-plugin 0.2" in found["footwo"]
    assert "its flag --trials (provider 'trialsy') takes the option --trials of lagrseq run, which the command owns" in found["trialsy"]
    assert "fine" not in found and "echoish" not in found
    assert "\n  fine " in done.stdout and "knob fine_k = 3" in done.stdout and "\n  echoish " in done.stdout
    assert "\n  shared " not in done.stdout and "\n  alphaint  " not in done.stdout  # not registered, only listed as skipped
    assert f"skipped plugins: {len(found)}" in done.stdout


def test_a_run_goes_on_past_a_plugin_flag_that_takes_a_command_option(contested: Path, tmp_path: Path) -> None:
    out = tmp_path / "runs"
    done = lagrseq(contested, "run", "cube-stacking", "--trials", "1", "--set", "run.episodes=2", "--quiet", "--out", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and "'trialsy'" in skipped(done.stderr)["trialsy"]
    assert len(list(out.rglob("trial-000.mcap"))) == 1
    help_text = lagrseq(contested, "run", "--help", cwd=tmp_path)
    assert help_text.returncode == 0 and "--echoish-level" in help_text.stdout and "--foo" not in help_text.stdout


def test_a_plugin_knob_checks_its_values_by_its_own_type(contested: Path, tmp_path: Path) -> None:
    policy = ["--method", "lagr-seq", "--set", 'secondary.policy="fine"']
    for value, message in [("0", "secondary.fine_k = 0 is out of range"), ('"4"', "secondary.fine_k = '4' has the wrong type; expected int")]:
        done = lagrseq(contested, "config", "cube-stacking", *policy, "--set", f"secondary.fine_k={value}", cwd=tmp_path)
        assert done.returncode == 2 and message in done.stderr.splitlines()[-1], done.stderr
