"""Configuration: presets, overrides, validation messages, round trip."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from lagrseq.progress import Reporter


@pytest.mark.parametrize("task", cfg.tasks())
@pytest.mark.parametrize("preset", cfg.PRESETS)
def test_every_preset_loads_and_round_trips(task: str, preset: str) -> None:
    for method in cfg.METHODS:
        config = cfg.load(task, method, preset)
        assert config.method == method and config.preset == preset
        assert cfg.from_dict(config.to_dict()) == config


def test_presets_differ_only_in_fields() -> None:
    upstream = cfg.load("cube-stacking", "lagr-seq", "upstream")
    paper = cfg.load("cube-stacking", "lagr-seq", "paper")
    assert (upstream.env.horizon, paper.env.horizon) == (50, 100)
    assert (upstream.lagr.trigger, paper.lagr.trigger) == ("new-max-prefix", "positive-reward")
    assert upstream.primary.state_index == "upstream-aliased"
    assert paper.lagr.update_primary_while_guided and not upstream.lagr.update_primary_while_guided


def test_overrides_are_typed_toml_values() -> None:
    config = cfg.load(
        "cube-stacking",
        "lagr",
        "upstream",
        overrides=["env.horizon=100", "llm.temperature=1", 'lagr.trigger="positive-reward"', "task.stack_size=11"],
    )
    assert config.env.horizon == 100
    assert config.llm.temperature == 1.0 and isinstance(config.llm.temperature, float)
    assert config.lagr.trigger == "positive-reward"
    assert config.task.stack_size == 11
    bare = cfg.load("cube-stacking", "lagr", "upstream", overrides=["lagr.trigger=every-step"])
    assert bare.lagr.trigger == "every-step"


def test_config_file_overrides_the_preset(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text("[env]\nhorizon = 77\n[run]\nepisodes = 5\n")
    config = cfg.load("cube-stacking", "baseline", "paper", config_file=path)
    assert (config.env.horizon, config.run.episodes) == (77, 5)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["env.horizn=100"], "unknown field env.horizn; fields of [env] are: horizon"),
        (["envv.horizon=100"], "unknown section [envv]"),
        (["lagr.trigger=sometimes"], "lagr.trigger = 'sometimes' is not allowed; expected one of"),
        (["env.horizon=ten"], "env.horizon = 'ten' has the wrong type; expected int, found str"),
        (["env.revert_wrong_cube=1"], "expected bool"),
        (["task.stack_size=9"], "task.stack_size = 9 is not allowed; expected one of 5 | 8 | 11"),
        (["horizon=100"], "expected section.field=value"),
        (["env.horizon"], "expected section.field=value"),
    ],
)
def test_bad_fields_give_one_clear_line(overrides: list[str], message: str) -> None:
    with pytest.raises(ConfigError) as info:
        cfg.load("cube-stacking", "lagr", "upstream", overrides=overrides)
    text = str(info.value)
    assert message in text and "\n" not in text


def test_bad_names_and_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown task 'cubes'"):
        cfg.load("cubes", "lagr", "upstream")
    with pytest.raises(ConfigError, match="unknown preset 'mine'; expected one of upstream, paper"):
        cfg.load("cube-stacking", "lagr", "mine")
    with pytest.raises(ConfigError, match="unknown method 'seq'"):
        cfg.load("cube-stacking", "seq", "upstream")
    with pytest.raises(ConfigError, match="does not exist"):
        cfg.load("cube-stacking", "lagr", "upstream", config_file=tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[env\nhorizon = 1\n")
    with pytest.raises(ConfigError, match="is not valid TOML"):
        cfg.load("cube-stacking", "lagr", "upstream", config_file=bad)


def test_every_field_has_a_docstring() -> None:
    import dataclasses

    for classes in [*cfg.SECTIONS.values(), cfg.COMMON_SECTIONS]:
        for cls in classes.values():
            docs = cfg.field_docs(cls)
            missing = [f.name for f in dataclasses.fields(cls) if f.name not in docs]
            assert not missing, f"{cls.__name__} fields without a docstring: {missing}"


def test_digest_tells_configurations_apart() -> None:
    a = cfg.load("cube-stacking", "lagr", "upstream")
    b = cfg.load("cube-stacking", "lagr", "upstream", overrides=["env.horizon=51"])
    assert a.digest() != b.digest() and a.digest() == cfg.load("cube-stacking", "lagr", "upstream").digest()


@dataclasses.dataclass(frozen=True)
class PaperlessTask(cfg.CubeTaskConfig):
    """The cube task's section under another task's name (a task that has no paper)."""

    name: str = "paperless"  # type: ignore[assignment]


def test_a_task_without_a_paper_ships_upstream_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """paper.toml is optional: a task whose preset folder holds only upstream.toml runs on it,
    and ``--preset paper`` (or the audit, which needs both) is one line naming what it has."""
    from lagrseq.errors import UsageError
    from lagrseq.registry import TASKS, Entry
    from lagrseq.study.audit import plan

    cube = TASKS.get("cube-stacking")
    upstream = (Path(cube.presets) / "upstream.toml").read_text(encoding="utf-8")
    (tmp_path / "upstream.toml").write_text(upstream.replace('name = "cube-stacking"', 'name = "paperless"'), encoding="utf-8")
    sections = {**cube.sections, "task": PaperlessTask}
    spec = dataclasses.replace(cube, name="paperless", presets=tmp_path, sections=sections)
    monkeypatch.setitem(TASKS._entries, "paperless", Entry("paperless", spec, "a test"))
    assert cfg.task_presets("paperless") == ("upstream",)
    assert cfg.task_presets("cube-stacking") == ("upstream", "paper")
    assert cfg.load("paperless", "lagr", "upstream").task.name == "paperless"
    with pytest.raises(ConfigError, match=r"task 'paperless' has no 'paper' preset .*expected one of upstream") as refused:
        cfg.load("paperless", "lagr", "paper")
    assert "\n" not in str(refused.value)
    with pytest.raises(UsageError, match="ships no 'paper' preset"):
        plan("paperless", "mock", 1, 1, -1, tmp_path / "runs", 0, Reporter.silent())
