"""Every numeric configuration field has a declared range, checked before any trial starts, and
the command line's numbers are read by validators that refuse NaN, infinities and values out of
range with one line."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any, get_args, get_origin

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from lagrseq.suite import load_suite

EXPERIMENTS = Path(cfg.__file__).parent / "experiments"


def _toml(value: Any) -> str:
    """``value`` written as a TOML value for ``--set``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)


def _bad_values(bounds: cfg.Range, integer: bool) -> list[Any]:
    """Values just outside ``bounds``, plus the values no number field takes."""
    if integer:
        bad: list[Any] = [True, 2**63, -(2**63) - 1]
        step = 1
    else:
        bad = [math.nan, math.inf, -math.inf, True, 10**400]
        step = 0
    if bounds.ge is not None:
        bad.append(int(bounds.ge) - 1 if integer else math.nextafter(bounds.ge, -math.inf))
    if bounds.gt is not None:
        bad.append(int(bounds.gt) if integer else bounds.gt)
    if bounds.le is not None:
        bad.append(int(bounds.le) + step if integer else math.nextafter(bounds.le, math.inf))
    if bounds.lt is not None:
        bad.append(int(bounds.lt) if integer else bounds.lt)
    return bad


def _numeric_fields() -> list[tuple[str, str, type, dataclasses.Field[Any]]]:
    out = []
    for task in cfg.tasks():
        for section, cls in {**cfg.SECTIONS[task], **cfg.COMMON_SECTIONS}.items():
            for f in cfg.numeric_fields(cls):
                out.append((task, section, cls, f))
    return out


def test_every_numeric_field_declares_a_range() -> None:
    fields = _numeric_fields()
    assert len(fields) > 60  # every section class of every task is walked
    missing = [f"{cls.__name__}.{f.name}" for _, _, cls, f in fields if "range" not in f.metadata]
    assert not missing, f"numeric fields without a declared range: {missing}"


@pytest.mark.parametrize("task", cfg.tasks())
def test_every_numeric_field_refuses_nan_inf_and_out_of_range(task: str) -> None:
    """Walk every numeric field of every section of the task: each bad value given with --set is
    refused by config.load, with the field's name, in one line."""
    checked = 0
    for field_task, section, cls, f in _numeric_fields():
        if field_task != task:
            continue
        hint = cfg._hints(cls)[f.name]
        is_tuple = get_origin(hint) is tuple
        integer = (get_args(hint)[0] if is_tuple else hint) is int
        for bad in _bad_values(f.metadata["range"], integer):
            value = [bad] if is_tuple else bad
            override = f"{section}.{f.name}={_toml(value)}"
            with pytest.raises(ConfigError) as info:
                cfg.load(task, "lagr-seq", "paper", overrides=[override])
            message = str(info.value)
            assert f"{section}.{f.name} = " in message and "\n" not in message, (override, message)
            assert len(message) < 200, message
            checked += 1
    assert checked > 100


@pytest.mark.parametrize(
    ("task", "override", "message"),
    [
        ("cube-stacking", "env.horizon=0", "env.horizon = 0; expected an integer in [1, 100000]"),
        ("cube-stacking", "env.horizon=-1", "env.horizon = -1; expected an integer in [1, 100000]"),
        ("cube-stacking", "primary.discount=2", "primary.discount = 2.0; expected a finite number in [0, 1]"),
        ("cube-stacking", "primary.learning_rate=nan", "primary.learning_rate = nan; expected a finite number in (0, 1]"),
        ("cube-stacking", "primary.epsilon_start=-1", "primary.epsilon_start = -1.0; expected a finite number in [0, 1]"),
        ("cube-stacking", "primary.epsilon_decay=-5", "primary.epsilon_decay = -5.0; expected a finite number in [0, 1000000]"),
        ("cube-stacking", "lagr.threshold=nan", "lagr.threshold = nan; expected a finite number in [0, 1]"),
        ("cube-stacking", "lagr.follow_probability=2", "lagr.follow_probability = 2.0; expected a finite number in [0, 1]"),
        ("cube-stacking", "lagr.follow_probability=7", "lagr.follow_probability = 7.0"),
        ("cube-stacking", "llm.max_tokens=-5", "llm.max_tokens = -5; expected an integer in [1, 1000000]"),
        ("cube-stacking", "llm.temperature=-1", "llm.temperature = -1.0; expected a finite number in [0, 2]"),
        ("cube-stacking", "llm.temperature=inf", "llm.temperature = inf; expected a finite number in [0, 2]"),
        ("cube-stacking", "llm.temperature=nan", "llm.temperature = nan; expected a finite number in [0, 2]"),
        ("cube-stacking", "llm.temperature=1e999", "llm.temperature = inf; expected a finite number in [0, 2]"),
        ("cube-stacking", "env.bonus=nan", "env.bonus = nan; expected a finite number in [0, 1000000]"),
        ("cube-stacking", "secondary.logistic_steepness=nan", "secondary.logistic_steepness = nan"),
        ("cube-stacking", "secondary.logistic_steepness=1000", "expected a finite number in [0, 500]"),
        ("cube-stacking", "env.horizon=true", "env.horizon = True has the wrong type; expected int, found bool"),
        ("cube-stacking", "env.horizon=99999999999999999999", "expected an integer in [1, 100000]"),
        ("image-completion", "primary.hidden_sizes=[128, 0]", "primary.hidden_sizes = [128, 0]; expected every item"),
        ("image-completion", "primary.hidden_sizes=[]", "primary.hidden_sizes = []; expected one positive width"),
        ("image-completion", "primary.epsilon_decay=1.5", 'primary.epsilon_decay = 1.5; expected a finite number in (0, 1] (the per-step factor of epsilon_schedule = "exponential")'),
        ("image-completion", "primary.buffer_size=10000000000", "primary.buffer_size = 10000000000; expected an integer in [1, 1000000]"),
        ("image-completion", "primary.batch_size=20000", "primary.batch_size = 20000; expected at most primary.buffer_size = 10000"),
        ("object-arrangement", "task.goal_threshold=0", "task.goal_threshold = 0.0; expected a finite number in (0, 1]"),
        ("object-arrangement", "run.episodes=-3", "run.episodes = -3; expected an integer in [0, 10000000]"),
        ("cube-stacking", 'llm.model=""', "llm.model = ''; expected a model name of 1 to 200 printable characters"),
        ("cube-stacking", 'llm.model="gpt\\u0000x"', "llm.model = 'gpt\\x00x'; expected a model name"),
        ("cube-stacking", 'llm.model="gpt\\nx"', "llm.model = 'gpt\\nx'; expected a model name"),
        ("cube-stacking", 'llm.model=" gpt-4"', "without surrounding spaces"),
    ],
)
def test_nonsense_values_are_refused_with_field_value_and_range(task: str, override: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        cfg.load(task, "lagr-seq", "paper", overrides=[override])
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_huge_integer_is_shown_shortened() -> None:
    with pytest.raises(ConfigError) as info:
        cfg.load("cube-stacking", "lagr", "paper", overrides=["llm.temperature=" + "9" * 500])
    text = str(info.value)
    assert text.startswith("llm.temperature = 999") and "(500 characters)" in text and len(text) < 150


def test_boundaries_and_ints_for_floats_are_accepted() -> None:
    config = cfg.load(
        "cube-stacking",
        "lagr-seq",
        "paper",
        overrides=["llm.temperature=2", "lagr.threshold=0", "primary.discount=1", "llm.max_tokens=1", "env.bonus=0"],
    )
    assert config.llm.temperature == 2.0 and isinstance(config.llm.temperature, float)
    assert (config.lagr.threshold, config.primary.discount, config.llm.max_tokens) == (0.0, 1.0, 1)


def test_ranges_hold_for_sections_built_directly() -> None:
    with pytest.raises(ConfigError, match=r"^llm.temperature = nan; expected a finite number in \[0, 2\]$"):
        cfg.LLMConfig(temperature=math.nan)
    with pytest.raises(ConfigError, match=r"env.horizon = True; expected an integer in \[1, 100000\]"):
        cfg.CubeEnvConfig(horizon=True)
    with pytest.raises(ConfigError, match="secondary.logistic_steepness = nan"):
        cfg.NeuralSecondaryConfig(logistic_steepness=math.nan)
    assert cfg.LLMConfig(temperature=1).temperature == 1  # ints for float fields are fine


def test_a_stored_configuration_with_bad_values_is_refused() -> None:
    """Logs are rebuilt with from_dict: a log whose configuration was edited is checked too."""
    data = cfg.load("cube-stacking", "lagr", "paper").to_dict()
    data["llm"]["temperature"] = math.inf
    with pytest.raises(ConfigError, match="llm.temperature = inf"):
        cfg.from_dict(data)
    data["llm"]["temperature"] = 0.0
    data["task"]["name"] = ["cube-stacking"]
    with pytest.raises(ConfigError, match="unknown task"):
        cfg.from_dict(data)


@pytest.mark.parametrize("path", sorted(EXPERIMENTS.glob("*/*.toml")), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_packaged_preset_loads_within_its_ranges(path: Path) -> None:
    for method in cfg.METHODS:
        config = cfg.load(path.parent.name, method, path.stem)
        assert cfg.from_dict(config.to_dict()) == config


def test_every_run_of_the_packaged_suite_resolves() -> None:
    assert (EXPERIMENTS / "paper_suite.toml").is_file()
    for item in load_suite().items:
        for run in item.runs:
            if run.task in cfg.tasks():
                run.resolve(quick=True)
                run.resolve(quick=False)


# --------------------------------------------------------------------------------------------
# --set values and the configuration file
# --------------------------------------------------------------------------------------------
def test_set_values_are_one_toml_value() -> None:
    assert cfg.parse_override("llm.model=gpt-4") == ("llm", "model", "gpt-4")
    assert cfg.parse_override("llm.temperature=nan")[2] != cfg.parse_override("llm.temperature=nan")[2]
    assert cfg.parse_override("env.horizon=1\nother = 2") == ("env", "horizon", "1\nother = 2")
    with pytest.raises(ConfigError, match="env.horizon = '1\\\\nother = 2' has the wrong type"):
        cfg.load("cube-stacking", "lagr", "paper", overrides=["env.horizon=1\nother = 2"])
    with pytest.raises(ConfigError, match="nested too deeply"):
        cfg.parse_override("env.horizon=" + "[" * 5000)


def test_a_config_file_of_the_wrong_shape_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text("task = 3\n")
    with pytest.raises(ConfigError, match=r"^task = 3; expected a \[task\] table of fields$"):
        cfg.load("cube-stacking", "lagr", "paper", config_file=path)
    path.write_text('[env]\n"hor\\nizon" = 3\n')
    with pytest.raises(ConfigError) as info:
        cfg.load("cube-stacking", "lagr", "paper", config_file=path)
    assert "unknown field env.'hor\\nizon'" in str(info.value) and "\n" not in str(info.value)
    path.write_text("[llm]\ntemperature = nan\n")
    with pytest.raises(ConfigError, match="llm.temperature = nan; expected a finite number in"):
        cfg.load("cube-stacking", "lagr", "paper", config_file=path)


# --------------------------------------------------------------------------------------------
# Command-line number validators
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("parse", "text", "message"),
    [
        (cfg.nonneg_float, "nan", "expected a finite number >= 0, found 'nan'"),
        (cfg.nonneg_float, "inf", "expected a finite number >= 0, found 'inf'"),
        (cfg.nonneg_float, "1e999", "found '1e999'"),
        (cfg.nonneg_float, "-0.01", "found '-0.01'"),
        (cfg.nonneg_float, "ten", "found 'ten'"),
        (cfg.nonneg_float, "", "found ''"),
        (cfg.nonneg_int, "-1", "expected an integer >= 0, found '-1'"),
        (cfg.nonneg_int, "1.5", "expected an integer >= 0, found '1.5'"),
        (cfg.positive_int, "0", "expected an integer >= 1, found '0'"),
        (cfg.positive_int, "nan", "expected an integer >= 1, found 'nan'"),
        (cfg.positive_int, "True", "found 'True'"),
        (cfg.positive_int, "9" * 5000, "expected an integer >= 1"),
        (cfg.seed_int, "-1", "expected an integer in [0, 9223372036854775807], found '-1'"),
        (cfg.seed_int, str(2**63), "found '9223372036854775808'"),
        (cfg.temperature_float, "2.5", "expected a finite number in [0, 2], found '2.5'"),
        (cfg.temperature_float, "-inf", "found '-inf'"),
        (cfg.max_tokens_int, "0", "expected an integer in [1, 1000000], found '0'"),
    ],
)
def test_option_validators_refuse_with_one_line(parse: Any, text: str, message: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError) as info:
        parse(text)
    assert message in str(info.value) and "\n" not in str(info.value) and len(str(info.value)) < 120


def test_option_validators_accept_what_they_should() -> None:
    assert cfg.nonneg_float("0") == 0.0 and cfg.nonneg_float("2.5") == 2.5
    assert cfg.nonneg_int("0") == 0 and cfg.positive_int(" 12 ") == 12
    assert cfg.seed_int(str(2**63 - 1)) == 2**63 - 1 and cfg.seed_int("0") == 0
    assert cfg.temperature_float("2") == 2.0 and cfg.max_tokens_int("256") == 256
    assert cfg.number_type("jobs", integer=True, ge=1, le=64)("64") == 64


def test_an_option_validator_makes_argparse_exit_2_with_its_message(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser(prog="lagrseq run")
    parser.add_argument("--max-cost-usd", type=cfg.nonneg_float)
    with pytest.raises(SystemExit) as info:
        parser.parse_args(["--max-cost-usd", "nan"])
    assert info.value.code == 2
    assert "argument --max-cost-usd: expected a finite number >= 0, found 'nan'" in capsys.readouterr().err


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.text(max_size=40), st.floats().map(repr), st.integers().map(str)))
def test_option_validators_return_in_range_or_refuse(text: str) -> None:
    for parse, low, high in ((cfg.nonneg_float, 0, math.inf), (cfg.seed_int, 0, 2**63 - 1), (cfg.temperature_float, 0, 2)):
        try:
            value = parse(text)
        except argparse.ArgumentTypeError as exc:
            assert "\n" not in str(exc)
            continue
        assert math.isfinite(value) and low <= value <= high
