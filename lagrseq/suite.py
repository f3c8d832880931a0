"""A suite as data: which runs feed which figure or table (SPEC section 4 and 7); the format is
docs/suites.md.

``lagrseq/experiments/paper_suite.toml`` lists the paper's items; a task may ship a suite of its
own (``TaskSpec.suite``), which ``lagrseq replay`` draws for that task's logs without ``--suite``
(:func:`logged_tasks_suite`) and ``lagrseq reproduce --suite TASK`` runs (:func:`suite_argument`). Each item names the function
that renders it (``render``) and the runs it needs; a run is a task, a method, a preset, a provider
(on a recorded store, with what answers a query the store lacks: ``on_miss``) and ``--set``
overrides, with its length for the full suite and for ``--quick``. Runs that several
items share (Fig. 5(a), Fig. 6(a) and the tau = 0 row of Table 2 use the same LaGR-SEQ runs) are
run once, because a run's directory is named after its whole configuration.

``lagrseq reproduce`` runs the suite; ``lagrseq replay`` uses the same file to tell which logs
feed which item, matching a log's stored configuration against the item's resolved one (run
length aside). Adding a figure for a new task or provider is adding entries to the file.

This module reads TOML and resolves configurations; it imports nothing but :mod:`lagrseq.config`
and :mod:`lagrseq.registry`, so analysis and running both read it (it sits below both).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq.errors import ConfigError
from lagrseq.registry import CALIBRATED_MISS, ON_MISS, kind_of
from lagrseq.tomlfile import shown as _shown_path

RENDERERS = ("returns", "query-bars", "query-table", "ratio-table", "accuracy", "config-table", "frontier")
KINDS = ("trial", "accuracy")

# The integer keys of a run and their ranges (0 episodes / -1 max_steps: the preset's).
_INT_RANGES = {
    "trials": cfg.Range(ge=1, le=100_000),
    "episodes": cfg.Range(ge=0),
    "max_steps": cfg.Range(ge=-1),
    "quick_trials": cfg.Range(ge=1, le=100_000),
    "quick_episodes": cfg.Range(ge=0),
    "quick_max_steps": cfg.Range(ge=-1),
    "samples": cfg.Range(ge=1),
    "quick_samples": cfg.Range(ge=1),
}
_INT_KEYS = tuple(_INT_RANGES)
_SEED = cfg.Range(ge=0, le=cfg.INT64_MAX)
_RUN_KEYS = {"label", "kind", "task", "method", "preset", "provider", "on_miss", "set", "row", "column"}
_RUN_KEYS |= set(_INT_KEYS)
_INHERITED = _RUN_KEYS - {"label", "row", "column"}
_OPTIONS = ("x", "band", "window", "ylabel", "numerator", "denominator", "reference", "row_header")
_CHOICES = {"x": ("episode", "global_step"), "band": ("std", "se")}
_TEXT_KEYS = ("title", "caption", "note", "label", "provider", "ylabel", "numerator", "denominator", "row_header")
_RECORDED_KEYS = ("recorded_on_miss", "recorded_trials")
_HORIZON_KEYS = ("full_horizon_trials", "quick_full_horizon_trials")
_HORIZON_RANGE = cfg.Range(ge=0, le=100_000)
_ITEM_KEYS = {"id", "title", "caption", "render", "runs", "note", "recorded", "stop_at", *_HORIZON_KEYS, *_RECORDED_KEYS, *_OPTIONS}
_ITEM_KEYS |= _INHERITED
FIRST_SOLVE = "first_solve"
"""An item's ``stop_at``: its runs' trials end with their first solved episode (``run.stop_at``)."""
FULL_HORIZON = ", full horizon"
"""The label suffix of a stopped item's full-length copies (:func:`_stopped_runs`)."""


@dataclass(frozen=True)
class RunSpec:
    """One run an item needs: what to run, and how long for the full suite and for --quick."""

    label: str
    """Legend entry or table cell name; ``{provider}`` is replaced by the provider spec."""
    task: str
    method: str
    preset: str
    provider: str | None
    """Provider spec; None means the suite's default (``lagrseq reproduce --provider``)."""
    on_miss: str | None = None
    """``recorded:STORE`` runs: what answers a query the store lacks (``--on-miss``: error, mock,
    live, refuse); None: the provider's default (error). A store whose prompts depend on the
    learner's path (a DQN's, which differs between CPUs) must say (DESIGN section 12)."""
    overrides: tuple[str, ...] = ()
    """``--set section.field=value`` overrides, run length excluded."""
    kind: str = "trial"
    """``trial``: RL trials; ``accuracy``: query the provider for every prefix of the target."""
    trials: int = 10
    episodes: int = 0
    """Episodes per trial; 0 keeps the preset's ``run.episodes``."""
    max_steps: int = -1
    """Step budget per trial; -1 keeps the preset's ``run.max_steps``."""
    quick_trials: int = 10
    quick_episodes: int = 0
    quick_max_steps: int = -1
    samples: int = 100
    """Accuracy probe: answers per prefix (the paper: 100 queries per point)."""
    quick_samples: int = 20
    row: str | None = None
    column: str | None = None
    full_horizon: bool = False
    """A full-length copy of a run of an item whose runs stop at the first solve (the item's
    ``full_horizon_trials``): it measures the full-horizon query count on fewer pairs, is never
    compared with random at its query rate, and is not run where its trials are 0 (``--quick``
    with ``quick_full_horizon_trials = 0``)."""

    def provider_spec(self, default: str) -> str:
        return self.provider if self.provider is not None else default

    def display_label(self, default_provider: str) -> str:
        return self.label.replace("{provider}", self.provider_spec(default_provider))

    def length(self, quick: bool) -> tuple[int, int, int]:
        """(trials, episodes, max_steps) for the full suite or --quick (0 / -1: the preset's)."""
        if quick:
            return self.quick_trials, self.quick_episodes, self.quick_max_steps
        return self.trials, self.episodes, self.max_steps

    def all_overrides(self, quick: bool) -> tuple[str, ...]:
        _, episodes, max_steps = self.length(quick)
        extra = []
        if episodes > 0:
            extra.append(f"run.episodes={episodes}")
        if max_steps >= 0:
            extra.append(f"run.max_steps={max_steps}")
        return (*self.overrides, *extra)

    def resolve(self, quick: bool = False) -> cfg.ExperimentConfig:
        """The run's configuration (raises ConfigError, e.g. for a task this lagrseq lacks)."""
        return cfg.load(self.task, self.method, self.preset, None, self.all_overrides(quick))

    def resolved_dict(self, quick: bool = False) -> dict[str, Any]:
        """:meth:`resolve` as the JSON a log stores (tuples become lists)."""
        return json.loads(_resolved_json(self.task, self.method, self.preset, self.all_overrides(quick)))


@functools.lru_cache(maxsize=1024)
def _resolved_json(task: str, method: str, preset: str, overrides: tuple[str, ...]) -> str:
    """A run's configuration as JSON, resolved once per process (replay matches every suite
    entry against the logs, and resolving takes about a millisecond)."""
    return cfg.load(task, method, preset, None, overrides).to_json()


@dataclass(frozen=True)
class Item:
    """A paper figure or table and the runs it is made from."""

    id: str
    title: str
    render: str
    runs: tuple[RunSpec, ...]
    caption: str = ""
    """The paper's caption (what the item shows)."""
    note: str = ""
    """How lagrseq makes it, where that differs from the paper."""
    options: Mapping[str, Any] = field(default_factory=dict)
    """Renderer options: x, band, window, ylabel, numerator, denominator, reference."""
    recorded: bool = False
    """Whether the authors' recorded GPT answers cover this item (``reproduce --authors-caches``
    adds a recorded-GPT line or row to it; see :func:`with_recorded`)."""
    recorded_on_miss: tuple[str, ...] = ()
    """What answers the authors' store misses in the recorded-GPT rows: one row per value (a
    sensitivity band: ``refuse``, ``calibrated``, ``mock``); empty: one row, misses answered by the
    mock."""
    recorded_trials: int | None = None
    """Trials of the recorded-GPT runs in the full suite (None: the run's own)."""


@dataclass(frozen=True)
class Suite:
    seed: int
    provider: str
    items: tuple[Item, ...]

    def select(self, ids: Sequence[str]) -> Suite:
        """The items named in ``ids`` (in suite order)."""
        known = {item.id for item in self.items}
        unknown = [i for i in ids if i not in known]
        if unknown:
            raise ConfigError(
                f"unknown suite item {unknown[0]!r}; items are: {', '.join(sorted(known))}"
            )
        return Suite(self.seed, self.provider, tuple(i for i in self.items if i.id in ids))


def default_path() -> Path:
    return Path(str(resources.files("lagrseq") / "experiments" / "paper_suite.toml"))


def _int(where: str, key: str, value: Any, allowed: cfg.Range) -> int:
    expected = allowed.problem(value, integer=True)
    if expected is not None:
        raise ConfigError(f"{where}: {key} = {cfg.show_value(value)}; expected {expected}")
    return int(value)


def _table(where: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where} = {cfg.show_value(value)}; expected a table of keys")
    return value


def _tables(where: str, value: Any) -> list[Mapping[str, Any]]:
    if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
        raise ConfigError(f"{where} = {cfg.show_value(value)}; expected a list of tables ([[{where}]])")
    return value


def _texts(where: str, data: Mapping[str, Any]) -> None:
    """The keys that must be strings are strings; ``set`` is a list of strings."""
    for key in _TEXT_KEYS:
        if key in data and not isinstance(data[key], str):
            raise ConfigError(f"{where}: {key} = {cfg.show_value(data[key])}; expected a string")
    if "set" in data and not (isinstance(data["set"], list) and all(isinstance(s, str) for s in data["set"])):
        raise ConfigError(f'{where}: set = {cfg.show_value(data["set"])}; expected a list of "section.field=value" strings')


def _options(where: str, raw: Mapping[str, Any]) -> dict[str, Any]:
    """The renderer options of an item, checked."""
    options = {k: raw[k] for k in _OPTIONS if k in raw}
    for key, choices in _CHOICES.items():
        if key in options and options[key] not in choices:
            raise ConfigError(
                f"{where}: {key} = {cfg.show_value(options[key])}; expected one of {', '.join(choices)}"
            )
    if "window" in options:
        _int(where, "window", options["window"], cfg.Range(ge=1))
    reference = options.get("reference", {})
    if not isinstance(reference, Mapping) or not all(isinstance(v, str) for v in reference.values()):
        raise ConfigError(f'{where}: reference = {cfg.show_value(reference)}; expected a table of "key" = "text"')
    return options


ITEM_ID_LENGTH = 100
"""The longest suite item id (it names the item's files: ``figures/ID.png``)."""


def _check_id(item_id: str) -> None:
    """An item id names files in the report folder: a path separator, a leading dot (``..``, a
    hidden file), a control character or an id past :data:`ITEM_ID_LENGTH` is refused."""
    bad = (
        "a path separator" if "/" in item_id or "\\" in item_id
        else "a leading dot" if item_id.startswith(".")
        else "a control character" if any(ord(c) < 32 or ord(c) == 127 for c in item_id)
        else f"more than {ITEM_ID_LENGTH} characters" if len(item_id) > ITEM_ID_LENGTH
        else ""
    )
    if bad:
        raise ConfigError(f"suite item id {cfg.show_value(item_id[:ITEM_ID_LENGTH])} holds {bad}; an id names the item's report files: use letters, digits, '-', '_' and '.'")


def _run(item_id: str, index: int, defaults: Mapping[str, Any], data: Mapping[str, Any]) -> RunSpec:
    where = f"suite item {item_id!r}, run {index + 1}"
    _texts(where, data)
    unknown = sorted(set(data) - _RUN_KEYS)
    if unknown:
        raise ConfigError(
            f"{where}: unknown key {cfg.show_value(unknown[0])}; keys are: {', '.join(sorted(_RUN_KEYS))}"
        )
    merged = {**{k: v for k, v in defaults.items() if k in _INHERITED}, **data}
    merged["set"] = [*defaults.get("set", []), *data.get("set", [])]
    for key in ("task", "method", "preset"):
        if not isinstance(merged.get(key), str):
            raise ConfigError(f"{where}: {key} is missing (set it on the run or the item)")
    kind = merged.get("kind", "trial")
    if kind not in KINDS:
        raise ConfigError(f"{where}: kind = {cfg.show_value(kind)}; expected one of {', '.join(KINDS)}")
    if merged["method"] not in cfg.METHODS:
        raise ConfigError(
            f"{where}: method = {cfg.show_value(merged['method'])}; expected one of {', '.join(cfg.METHODS)}"
        )
    for text in merged["set"]:
        section, name, _ = cfg.parse_override(text)
        if section == "run" and name in ("episodes", "max_steps"):
            raise ConfigError(f"{where}: give run.{name} as {name} / quick_{name}, not in set")
    ints = {key: _int(where, key, merged[key], _INT_RANGES[key]) for key in _INT_KEYS if key in merged}
    trials = ints.get("trials", 10)
    on_miss = _on_miss(where, merged, "on_miss" in data)
    label = data.get("label")
    if not isinstance(label, str) or not label:
        raise ConfigError(f"{where}: label is missing")
    return RunSpec(
        label=label,
        task=merged["task"],
        method=merged["method"],
        preset=merged["preset"],
        provider=merged.get("provider"),
        on_miss=on_miss,
        overrides=tuple(merged["set"]),
        kind=kind,
        trials=trials,
        episodes=ints.get("episodes", 0),
        max_steps=ints.get("max_steps", -1),
        quick_trials=ints.get("quick_trials", trials),
        quick_episodes=ints.get("quick_episodes", ints.get("episodes", 0)),
        quick_max_steps=ints.get("quick_max_steps", ints.get("max_steps", -1)),
        samples=ints.get("samples", 100),
        quick_samples=ints.get("quick_samples", ints.get("samples", 100)),
        row=None if data.get("row") is None else str(data["row"]),
        column=None if data.get("column") is None else str(data["column"]),
    )


def _on_miss(where: str, merged: Mapping[str, Any], own: bool) -> str | None:
    """A run's ``on_miss``: one of :data:`lagrseq.registry.ON_MISS`. Set on the run itself, its
    provider must be a store (``recorded:STORE``) or the suite's default (which ``reproduce
    --provider`` may make one); inherited from the item, it applies to the item's store runs only."""
    value = merged.get("on_miss")
    if value is None:
        return None
    if value not in ON_MISS:
        raise ConfigError(f"{where}: on_miss = {cfg.show_value(value)}; expected one of {', '.join(ON_MISS)}")
    provider = merged.get("provider")
    kind = None if provider is None else kind_of(provider)
    if kind is not None and not kind.replays:
        if own:
            raise ConfigError(
                f"{where}: on_miss = {cfg.show_value(value)} with provider = {cfg.show_value(provider)}; "
                "on_miss applies to recorded:STORE runs only: remove it or give a recorded provider"
            )
        return None
    return str(value)


def _recorded_keys(where: str, raw: Mapping[str, Any], recorded: bool) -> dict[str, Any]:
    """An item's ``recorded_on_miss`` and ``recorded_trials``, checked (only on a ``recorded =
    true`` item)."""
    given = [key for key in _RECORDED_KEYS if key in raw]
    if given and not recorded:
        raise ConfigError(f"{where}: {given[0]} applies to recorded = true items only: remove it or set recorded = true")
    out: dict[str, Any] = {}
    values = raw.get("recorded_on_miss", [])
    if not isinstance(values, list) or not all(isinstance(v, str) for v in values) or len(set(values)) != len(values):
        raise ConfigError(f"{where}: recorded_on_miss = {cfg.show_value(values)}; expected a list of distinct on_miss values")
    for value in values:
        if value not in ON_MISS or value in ("error", "live"):
            raise ConfigError(
                f"{where}: recorded_on_miss holds {cfg.show_value(value)}; expected refuse, calibrated or mock "
                "(a row on the authors' answers never stops at a miss nor pays for one)"
            )
    out["recorded_on_miss"] = tuple(values)
    if "recorded_trials" in raw:
        out["recorded_trials"] = _int(where, "recorded_trials", raw["recorded_trials"], _INT_RANGES["trials"])
    return out


def _stopped_runs(where: str, raw: Mapping[str, Any], render: str, runs: tuple[RunSpec, ...]) -> tuple[RunSpec, ...]:
    """An item's runs under its ``stop_at`` and ``full_horizon_trials`` keys (frontier items
    only): with ``stop_at = "first_solve"`` every run gets ``run.stop_at="first_solve"`` (its
    trials end with their first solved episode: steps to the first solve, the frontier's primary
    outcome, are known then), and with ``full_horizon_trials = K`` > 0 the runs are followed by
    one copy each at full length (no stop), labelled ``..., full horizon``, of K trials (``--quick``:
    ``quick_full_horizon_trials``, default K; 0: no copy), as ``lagrseq frontier
    --stop-at-first-solve --full-horizon-trials K`` runs them."""
    given = [key for key in ("stop_at", *_HORIZON_KEYS) if key in raw]
    if not given:
        return runs
    if render != "frontier":
        raise ConfigError(f"{where}: {given[0]} applies to render = \"frontier\" items only: remove it")
    stop = raw.get("stop_at")
    if stop is None:
        raise ConfigError(
            f"{where}: {given[0]} measures full-length trials beside trials stopped at the first solve; "
            'add stop_at = "first_solve" or remove it'
        )
    if stop != FIRST_SOLVE:
        raise ConfigError(f'{where}: stop_at = {cfg.show_value(stop)}; expected "{FIRST_SOLVE}"')
    for spec in runs:
        for text in spec.overrides:
            if cfg.parse_override(text)[:2] == ("run", "stop_at"):
                raise ConfigError(f"{where}: run {spec.label!r} sets run.stop_at and the item sets stop_at; give it once, on the item")
    full = _int(where, "full_horizon_trials", raw.get("full_horizon_trials", 0), _HORIZON_RANGE)
    quick = _int(where, "quick_full_horizon_trials", raw.get("quick_full_horizon_trials", full), _HORIZON_RANGE)
    if full == 0 and quick > 0:
        raise ConfigError(
            f"{where}: quick_full_horizon_trials = {quick} with full_horizon_trials = 0; "
            "the full suite would have no full-length copies: set full_horizon_trials too, or remove it"
        )
    stopped = tuple(replace(spec, overrides=(*spec.overrides, f'run.stop_at="{FIRST_SOLVE}"')) for spec in runs)
    if full == 0:
        return stopped
    copies = tuple(
        replace(
            spec, label=f"{spec.label}{FULL_HORIZON}", trials=full, quick_trials=quick, full_horizon=True,
            row=None if spec.row is None else f"{spec.row}{FULL_HORIZON}",
        )
        for spec in runs
    )
    return (*stopped, *copies)


def load_suite(path: str | Path | None = None) -> Suite:
    """Read and check a suite file (default: the packaged ``paper_suite.toml``; the format:
    docs/suites.md)."""
    data = cfg.read_toml(default_path() if path is None else path, "suite")
    unknown_sections = sorted(set(data) - {"suite", "items"})
    if unknown_sections:
        raise ConfigError(f"suite: unknown section [{cfg.show_name(unknown_sections[0])}]; sections are: suite, items")
    head = _table("suite", data.get("suite", {}))
    seed = _int("[suite]", "seed", head.get("seed", 0), _SEED)
    provider = head.get("provider", "mock")
    if not isinstance(provider, str) or not provider:
        raise ConfigError(f"[suite]: provider = {cfg.show_value(provider)}; expected a provider spec such as \"mock\"")
    items = []
    seen: set[str] = set()
    for raw in _tables("items", data.get("items", [])):
        item_id = raw.get("id")
        if not isinstance(item_id, str) or not item_id:
            raise ConfigError("suite item without an id")
        _check_id(item_id)
        if item_id in seen:
            raise ConfigError(f"suite item {item_id!r} appears twice")
        seen.add(item_id)
        unknown = sorted(set(raw) - _ITEM_KEYS)
        if unknown:
            raise ConfigError(f"suite item {item_id!r}: unknown key {cfg.show_value(unknown[0])}")
        _texts(f"suite item {item_id!r}", raw)
        render = raw.get("render")
        if render not in RENDERERS:
            raise ConfigError(
                f"suite item {item_id!r}: render = {cfg.show_value(render)}; expected one of {', '.join(RENDERERS)}"
            )
        listed = _tables(f"items.runs of suite item {item_id!r}", raw.get("runs", []))
        runs = tuple(_run(item_id, i, raw, r) for i, r in enumerate(listed))
        if not runs:
            raise ConfigError(f"suite item {item_id!r} lists no runs")
        runs = _stopped_runs(f"suite item {item_id!r}", raw, render, runs)
        options = _options(f"suite item {item_id!r}", raw)
        recorded = raw.get("recorded", False)
        if not isinstance(recorded, bool):
            raise ConfigError(f"suite item {item_id!r}: recorded = {cfg.show_value(recorded)}; expected true or false")
        items.append(
            Item(
                id=item_id,
                title=str(raw.get("title", item_id)),
                render=render,
                runs=runs,
                caption=str(raw.get("caption", "")),
                note=str(raw.get("note", "")),
                options=options,
                recorded=recorded,
                **_recorded_keys(f"suite item {item_id!r}", raw, recorded),
            )
        )
    return Suite(seed=seed, provider=str(provider), items=tuple(items))


# ------------------------------------------------------------------------------------------
# Suites a task ships (``TaskSpec.suite``): found by task, by ``replay`` and ``reproduce --suite``
# ------------------------------------------------------------------------------------------
def task_suite_path(task: str) -> Path | None:
    """The suite file the registered task ``task`` ships (``TaskSpec.suite``), None if it ships
    none or is not registered; ConfigError (one line) for a reference that names no file."""
    from lagrseq.registry import TASKS

    spec = TASKS.find(task)
    reference = None if spec is None else spec.suite
    if reference is None:
        return None
    if isinstance(reference, Path):
        path = reference
    else:
        package, sep, resource = str(reference).partition(":")
        if not sep or not package or not resource:
            raise ConfigError(
                f"task {task!r}: suite = {cfg.show_value(reference)}; expected a Path or \"package:resource.toml\""
            )
        try:
            path = Path(str(resources.files(package).joinpath(resource)))
        except (ModuleNotFoundError, TypeError, ValueError) as exc:
            raise ConfigError(f"task {task!r}: suite = {cfg.show_value(reference)} names no package file ({exc}); fix the task's TaskSpec.suite") from None
    if not path.is_file():
        raise ConfigError(f"task {task!r}: its suite file {cfg.show_value(str(path))} does not exist; fix the task's TaskSpec.suite or reinstall it")
    return path


def suite_argument(text: str | Path | None) -> Path | None:
    """``--suite``'s value as a file: a path to a suite file, or the name of a registered task
    that ships one (``lagrseq reproduce --suite number-sequence``); None stays None (the default
    suite). An existing file wins over a task of the same name."""
    if text is None:
        return None
    path = Path(text)
    if path.exists() or path.suffix == ".toml" or len(path.parts) > 1:
        return path  # a path: load_suite says what is wrong with it, naming it in full
    from lagrseq.registry import TASKS

    if str(text) in TASKS:
        found = task_suite_path(str(text))
        if found is None:
            raise ConfigError(
                f"--suite {cfg.show_value(str(text))}: the task ships no suite of its own (TaskSpec.suite); "
                "give a suite file (docs/suites.md), or leave --suite out for the paper's suite"
            )
        return found
    raise ConfigError(
        f"--suite {_shown_path(path)}: no such suite file, and no task of that name; expected FILE.toml "
        f"or a task that ships a suite ({', '.join(t for t in TASKS.names() if TASKS.get(t).suite is not None) or 'none installed'})"
    )


def suite_tasks(suite: Suite) -> set[str]:
    """Every task a suite's runs name."""
    return {run.task for item in suite.items for run in item.runs}


def _pinned(suite: Suite, provider: str) -> Suite:
    """``suite`` with its default-provider runs given its own default explicitly (so it keeps it
    when merged into a suite of another default)."""
    if suite.provider == provider:
        return suite
    items = tuple(
        replace(item, runs=tuple(run if run.provider is not None else replace(run, provider=suite.provider) for run in item.runs))
        for item in suite.items
    )
    return Suite(suite.seed, suite.provider, items)


def logged_tasks_suite(tasks: Sequence[str] | set[str]) -> tuple[Suite, tuple[str, ...]]:
    """The suite ``lagrseq replay`` draws without ``--suite`` for logs of ``tasks``, and the
    lines saying what it left out.

    The paper's suite when the logs hold a run of one of its tasks; then, for each logged task
    that ships a suite (``TaskSpec.suite``), that suite's items. A suite whose tasks no log holds
    is left out as one line (logs of a plugin's task alone do not list the paper's 23 items as
    "not run"). Item ids must be unique across the suites (ConfigError, one line)."""
    paper = load_suite()
    logged = set(tasks)
    chosen: list[tuple[str, Suite]] = []
    left_out: list[str] = []
    if suite_tasks(paper) & logged:
        chosen.append(("the paper's suite", paper))
    else:
        left_out.append(
            f"the paper's suite ({len(paper.items)} items) left out: no log is of its tasks "
            f"({', '.join(sorted(suite_tasks(paper)))}); logs of: {', '.join(sorted(logged)) or 'none'}"
        )
    seen: set[Path] = set()
    for task in sorted(logged):
        path = task_suite_path(task)
        if path is None or path.resolve() in seen:
            continue
        seen.add(path.resolve())
        chosen.append((f"the suite of task {task!r} ({path.name})", load_suite(path)))
    if not chosen:
        return Suite(paper.seed, paper.provider, ()), tuple(left_out)
    base = chosen[0][1]
    items: list[Item] = []
    owner: dict[str, str] = {}
    for where, suite in chosen:
        for item in _pinned(suite, base.provider).items:
            if item.id in owner:
                raise ConfigError(
                    f"suite item {item.id!r} is in {owner[item.id]} and in {where}; give the task's items their own ids"
                )
            owner[item.id] = where
            items.append(item)
    return Suite(base.seed, base.provider, tuple(items)), tuple(left_out)


def matches(stored: Mapping[str, Any], resolved: Mapping[str, Any]) -> bool:
    """Whether a log's stored configuration is the run an item asks for.

    Run length (``run.episodes``, ``run.max_steps``) is ignored, so quick and full runs both
    match; so are fields that only one side has (a log written before a field was added, whose
    default keeps the old behaviour, still matches).
    """
    for section, values in resolved.items():
        if section not in stored:
            continue
        other = stored[section]
        # run.stop_at is left out of a configuration at its default (ExperimentConfig.to_dict)
        if (
            section == "run" and isinstance(values, Mapping) and isinstance(other, Mapping)
            and values.get("stop_at", STOP_AT_DEFAULT) != other.get("stop_at", STOP_AT_DEFAULT)
        ):
            return False
        if isinstance(values, Mapping) and isinstance(other, Mapping):
            for name, value in values.items():
                if section == "run" and name in ("episodes", "max_steps"):
                    continue
                if name in other and other[name] != value:
                    return False
        elif other != values:
            return False
    return True


# ------------------------------------------------------------------------------------------
# The authors' recorded GPT answers (``lagrseq reproduce --authors-caches DIR``)
# ------------------------------------------------------------------------------------------
STOP_AT_DEFAULT = ""
"""``run.stop_at`` where a configuration leaves it out (its default)."""
AUTHORS_STORE_NAME = "authors-answers"
"""The store under ``--out`` that ``reproduce --authors-caches`` imports the authors' caches into;
replay recognises runs on the authors' answers by a ``recorded:`` provider ending in this name."""
RECORDED_NAME = "authors' GPT answers"
"""How a line or row on the authors' recorded answers is named."""
PAPER_MODEL_ROWS = {"gpt-4": "GPT4", "gpt-3.5-turbo": "GPT3"}
"""The paper's row names of its models (Table 3): a recorded run of that model fills that row."""
AUTHORS_HINT = (
    "Recorded GPT line: add it with `lagrseq reproduce --authors-caches DIR` (DIR: a clone of "
    "GKthom/LaGRSEQ or a folder of its cache pickles)."
)


def is_authors_provider(spec: str) -> bool:
    """Whether a provider spec reads the store ``reproduce --authors-caches`` made."""
    found = kind_of(spec)
    return found is not None and found.replays and Path(spec.partition(":")[2]).name == AUTHORS_STORE_NAME


def covered_by(resolved: cfg.ExperimentConfig) -> tuple[str, int]:
    """(task, stack size or 0): what an authors' cache must cover for this run to be made on it."""
    return resolved.task.name, int(getattr(resolved.task, "stack_size", 0) or 0)


def _recorded_label(text: str) -> str:
    if "{provider}" in text:
        return text.replace("{provider}", RECORDED_NAME)
    return f"{text}, {RECORDED_NAME}"


MISS_ROWS = {
    "refuse": "misses refused",
    "calibrated": "misses: calibrated draw, fitted",
    "mock": "misses: rule-based mock",
}
"""How a recorded-GPT row names what answered the store's misses (``Item.recorded_on_miss``)."""
MISS_VARIANT = "on-miss-"
"""The beginning of the variant (run directory suffix, ``RunKey.variant``) of a run on the
authors' answers whose misses are not answered by the mock (:func:`miss_variant`)."""


def miss_variant(provider: str, on_miss: str | None) -> str:
    """``on-miss-refuse`` / ``on-miss-calibrated`` for a trial run on the authors' answers whose
    misses are refused or drawn, and ``on-miss-calibrated`` on any store (its run directory and
    replay's run key carry it, so the three rows of one item never share logs, and a fitted run
    is known as one from its key); empty for the mock (the authors' runs' rule before
    ``recorded_on_miss`` existed: their logs keep their names) and every other run."""
    kind = kind_of(provider)
    if on_miss == CALIBRATED_MISS and kind is not None and kind.replays:
        return f"{MISS_VARIANT}{on_miss}"  # fitted, on any store: never mixed with the store's other runs
    if not is_authors_provider(provider) or on_miss in (None, "", "mock"):
        return ""
    return f"{MISS_VARIANT}{on_miss}"


def miss_row(row: str, on_miss: str) -> str:
    """The row of a recorded-GPT run whose misses ``on_miss`` answers: ``GPT4 (misses refused)``."""
    return f"{row} ({MISS_ROWS.get(on_miss, 'misses: ' + on_miss)})"


def _miss_variants(item: Item, copy: RunSpec) -> list[RunSpec]:
    """A recorded-GPT copy of a run, once per ``item.recorded_on_miss`` (one row each), with the
    item's ``recorded_trials``; unchanged without them."""
    changes: dict[str, Any] = {}
    if item.recorded_trials is not None and not copy.full_horizon:  # a full-length copy keeps its K trials
        changes["trials"] = item.recorded_trials
    if not item.recorded_on_miss:
        return [replace(copy, **changes)]
    out = []
    for on_miss in item.recorded_on_miss:
        row = None if copy.row is None else miss_row(copy.row, on_miss)
        label = f"{copy.label} ({MISS_ROWS.get(on_miss, on_miss)})"
        out.append(replace(copy, **changes, on_miss=on_miss, row=row, label=label))
    return out


def with_recorded(suite: Suite, provider: str, covers: set[tuple[str, int]]) -> Suite:
    """``suite`` with a recorded-GPT line or row added to every item marked ``recorded``.

    A run is copied onto ``provider`` when it would use the suite's default provider (or a mock
    profile standing for GPT), asks at temperature 0, is not the baseline, and its (task, stack
    size) is in ``covers``. In tables, the copied run's row is copied whole (a ratio's denominator
    comes along unchanged) under the row name with the recorded name added.
    """
    items = []
    for item in suite.items:
        if not item.recorded:
            items.append(item)
            continue
        eligible: list[RunSpec] = []
        for spec in item.runs:
            kind = None if spec.provider is None else kind_of(spec.provider)
            mocked = spec.provider is None or (kind is not None and kind.synthetic)  # the suite's default: the mock
            if spec.method == "baseline" or not mocked:
                continue
            try:
                resolved = spec.resolve()
            except ConfigError:
                continue
            if resolved.llm.temperature == 0 and covered_by(resolved) in covers:
                eligible.append(spec)
        added: list[RunSpec] = []
        seen: set[tuple[str | None, str | None, str, str | None]] = set()
        rows = {spec.row for spec in eligible if spec.row is not None}
        for spec in item.runs:
            if spec.row is not None and spec.row in rows:
                row = f"{spec.row} ({RECORDED_NAME})"
                if "{provider}" in spec.row:  # a row per model (Table 3): the paper's row of that model
                    model = spec.resolve().llm.model
                    row = spec.row.replace("{provider}", PAPER_MODEL_ROWS.get(model, RECORDED_NAME))
                copies = [
                    replace(
                        spec,
                        label=_recorded_label(spec.label),
                        row=row,
                        provider=provider if spec in eligible else spec.provider,
                    )
                ]
            elif spec in eligible and spec.row is None:
                copies = [replace(spec, label=_recorded_label(spec.label), provider=provider)]
            else:
                continue
            if spec in eligible:
                copies = [variant for copy in copies for variant in _miss_variants(item, copy)]
            for copy in copies:
                key = (copy.row, copy.column, json.dumps(copy.resolved_dict(), sort_keys=True), copy.on_miss)
                if key not in seen:
                    seen.add(key)
                    added.append(copy)
        items.append(replace(item, runs=(*item.runs, *added)) if added else item)
    return Suite(suite.seed, suite.provider, tuple(items))
