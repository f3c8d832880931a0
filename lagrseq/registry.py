"""The registries: every task, provider kind, asking policy and executor lagrseq knows, by name.

Each kind of part has one :class:`Registry`. The built-in parts are registered by
``lagrseq.builtins`` (read on first use); third-party packages add theirs through entry points in
the groups ``lagrseq.tasks``, ``lagrseq.providers``, ``lagrseq.policies``, ``lagrseq.executors`` (groups
loaded lazily, on first use of that registry). An entry point names a
spec (:class:`TaskSpec`, :class:`ProviderKind`, :class:`PolicySpec`, :class:`ExecutorSpec`), a
sequence of specs, or a function of no arguments returning either. A plugin whose import or
registration raises is skipped with one stderr line naming it; the others, and every built-in,
keep working.

Plugins load the Gymnasium way (:func:`_load_plugins`): each entry point is loaded, called and
registered, nothing process-wide patched for it. A plugin is trusted code (``pip`` already ran
it): whatever it raises while it loads but ``KeyboardInterrupt`` (``SystemExit`` included) skips
it with one line, and a load that does not finish within :data:`PLUGIN_TIMEOUT_ENV` seconds
(default :data:`DEFAULT_PLUGIN_TIMEOUT_S`) is abandoned in its daemon thread and skipped; that
bound is no sandbox (docs/security.md).

Every name, knob and flag has one owner (docs/extending.md): built-ins win a part's name, and
two plugins claiming one name are both skipped (whatever the order of their entry points); a
plugin policy's knob may not name a ``[secondary]`` field, a reserved word or another policy's
knob; a plugin provider's flag, option or logged name may not be another kind's declaration;
each such plugin is skipped with one line naming both owners. Text from
plugins is printed through :func:`printable`. Where several processes load plugins (``--jobs``
workers), only the process named by :data:`NOTICES_ENV` prints the skip lines (the command line
sets it to its own pid), so a broken plugin is named once per command.

This module is stdlib only: a spec's factories are plain callables, and the built-ins import
the heavy parts inside them, so reading a registry never imports torch, gymnasium or httpx.
Callers ask a spec what a part can do instead of comparing its name (``spec.paid``, not
``kind == "live"``).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import os
import sys
import threading
import typing
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from lagrseq.errors import UsageError
from lagrseq.text import printable  # re-exported: the one escaping of outside text

if TYPE_CHECKING:
    from lagrseq.progress import Reporter

BUILTIN = "lagrseq"
"""The source of the built-in parts (``lagrseq plugins``)."""

GROUPS = {kind: f"lagrseq.{kind}" for kind in ("tasks", "providers", "policies", "executors")}
"""Registry name -> entry-point group (``lagrseq.tasks`` ...)."""


# ------------------------------------------------------------------------------------------
# Specs
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TaskSpec:
    """A pattern-completion task, registered in one place (entry-point group ``lagrseq.tasks``).

    Every callable takes the resolved ``ExperimentConfig`` first. Only ``name``, ``sections``,
    ``presets``, ``make_task``, ``make_env`` and ``extrapolator`` are required; the rest have
    defaults that suit a task without pictures, guidance of its own or extras. An example (the
    full walk-through, tested: docs/extending.md):

    ```python
    TaskSpec(
        name="countdown",
        sections={"task": CountdownTaskConfig, "env": CountdownEnvConfig,
                  "primary": TabularConfig, "secondary": TabularSecondaryConfig},
        presets=Path(__file__).parent / "presets",      # upstream.toml (paper.toml optional)
        make_task=lambda config: Countdown(config.task.length),
        make_env=lambda config, render_dir: CountdownEnv(Countdown(config.task.length)),
        extrapolator=extrapolator,                       # (config, profile) -> answer function
        profiles=("lazy",),                              # --provider mock:lazy
        description="count down to zero one number at a time",
        suite="countdown_plugin:suite.toml",             # replay draws it without --suite
    )
    ```"""

    name: str
    """The task's name (``[task] name``, ``lagrseq run NAME``): printable, no ``:`` or ``,``."""
    sections: Mapping[str, type]
    """The frozen dataclass reading each task-specific section, by section name: ``task``,
    ``env``, ``primary``, ``secondary`` (the ``[lagr]``, ``[llm]`` and ``[run]`` sections are
    shared by every task). Each field is checked against its annotation, unknown fields are
    refused, and the field's docstring is what ``lagrseq config`` shows."""
    presets: Path
    """The folder holding the task's preset files: ``upstream.toml`` (required: the default
    preset) and ``paper.toml`` (optional: a task with no paper leaves it out, and ``--preset
    paper`` on it is refused in one line)."""
    make_task: Callable[[Any], Any]
    """config -> the task (``lagrseq.tasks.base.Task``): prompt, parser, evaluation, guidance."""
    make_env: Callable[[Any, Path | None], Any]
    """(config, render_dir) -> the task's Gymnasium env, or any object with Gymnasium's
    ``reset``, ``step`` and ``close`` (the built-in cube task hands a run its env's dynamics
    without Gymnasium, ``lagrseq.tasks.cube_dynamics``)."""
    extrapolator: Callable[[Any, str], Callable[..., str]]
    """(config, profile) -> what ``--provider mock[:PROFILE]`` answers with (``ideal``: the
    rule-based extrapolator; raises UsageError for a profile the task lacks)."""
    profiles: tuple[str, ...] | Callable[[], tuple[str, ...]] = ()
    """The names of the mock profiles besides ``ideal`` (``--provider mock:PROFILE``), as a
    tuple of strings or a function of no arguments returning one (called when a provider spec
    is parsed, so the profiles may live in a module imported only then). ``extrapolator`` gets
    the name."""
    view_topics: Callable[[Any], dict[str, tuple[str, str, bytes]] | None] | None = None
    """config -> the picture topics the sink registers (None: no pictures)."""
    views: Callable[[Any, Any], Callable[[dict[str, Any], int], list[Any]] | None] | None = None
    """(config, env) -> the pictures after each step, from the step's info (``View`` records)."""
    guide: Callable[[Any, Any, Any], Callable[..., Any]] | None = None
    """(config, task, env) -> pi_LLM, ``(solution, observation, info) -> Guided or None``
    (``lagrseq.loop.experiment.Guided``: its action, the same action as ``env.step`` takes it,
    and the observation and info it acts on), where the env's actions let it name where it acts
    (None: the task's ``guidance`` wherever the env is)."""
    missing_dependency: Callable[[Any], str] | None = None
    """config -> why it cannot run with the installed extras ("" when it can)."""
    estimated_tokens: Callable[[dict[str, Any]], tuple[float, float] | None] | None = None
    """A logged configuration (JSON data) -> (prompt, answer) tokens of one query, estimated
    (the frontier's cost of answers that logged no usage)."""
    miss_calibration: Callable[[Any], Any] | None = None
    """config -> the ``lagrseq.llm.calibrated.MissCalibration`` of ``--on-miss calibrated``: the
    kind of a prompt (bins whose acceptance rates are fitted to a store's answers), whether an
    answer is accepted, a right and a wrong answer (None: the task refuses ``calibrated``)."""
    renders: bool = False
    """``--render DIR`` draws its episodes (``make_env`` gets the folder)."""
    calibration_steps: int | None = None
    """``lagrseq reproduce --calibrate``: steps per calibration run (None: the default)."""
    frontier_preset: str = "upstream"
    """The preset ``lagrseq frontier`` runs when ``--preset`` is not given (cube stacking: the
    paper's, whose environment pays nothing for wrong cubes, so fewer guided episodes earn no
    return of their own)."""
    solution_scopes: tuple[str, ...] = ()
    """The ``lagr.solution_scope`` regimes ``frontier --scopes auto`` compares (the grid tasks
    keep an accepted answer for the trial, so asking again only matters per episode); empty: the
    preset's own."""
    state_keys: Mapping[str, Callable[[Any], Callable[[Any], Any]]] = field(default_factory=dict)
    """The tabular agent's state indices of its own (``primary.state_index``), by name -> (task ->
    (pattern -> its Q-table row, hashable)); ``exact`` (a row per pattern) needs none (cube
    stacking: the released code's ``upstream-aliased`` rows)."""
    episode_fields: Mapping[str, str] = field(default_factory=dict)
    """Fields of its own that its env logs per episode (``info["log_episode"]``, counted since
    the env's reset), by name -> JSON type (one of :data:`FIELD_TYPES`): added to the
    ``/episode`` record and its schema in the task's logs, read back by ``lagrseq replay`` (the
    runs table and its CSV). An episode whose env leaves one out logs it as null."""
    step_fields: Mapping[str, str] = field(default_factory=dict)
    """Fields of its own that its env logs per step (``info["log_step"]``, on the steps that have
    them), by name -> JSON type: added to the ``/transition`` record (a column of
    ``/transitions``) and its schema; null on steps that do not set them."""
    description: str = ""
    """One line on what the task asks for, shown by ``lagrseq plugins`` (empty: nothing shown)."""
    suite: Path | str | None = None
    """The task's own suite file (docs/suites.md): a ``Path``, or ``"package:resource.toml"`` (a
    file inside an installed package, read with ``importlib.resources``). ``lagrseq replay``
    draws its items for logs of this task without ``--suite``, and ``lagrseq reproduce --suite
    NAME`` runs it (None: the task ships no suite)."""

    def __post_init__(self) -> None:
        for what, fields, taken in (("episode_fields", self.episode_fields, LOGGED_EPISODE_FIELDS), ("step_fields", self.step_fields, LOGGED_STEP_FIELDS)):
            if not isinstance(fields, Mapping):
                raise TypeError(f"task {self.name!r}: {what} is a {type(fields).__name__}; expected a mapping of field name -> JSON type")
            for name, kind in fields.items():
                if not isinstance(name, str) or not name.isidentifier():
                    raise ValueError(f"task {self.name!r}: {what} name {name!r} is not an identifier; expected e.g. 'wrong_bits'")
                if name in taken:
                    raise ValueError(f"task {self.name!r}: {what} {name!r} is a field lagrseq logs itself; give the task's own field another name")
                if kind not in FIELD_TYPES:
                    raise ValueError(f"task {self.name!r}: {what} {name!r} has the type {kind!r}; expected one of {', '.join(FIELD_TYPES)}")


FIELD_TYPES = ("integer", "number", "boolean", "string")
"""The JSON types of a task's own logged fields (:attr:`TaskSpec.episode_fields`,
:attr:`TaskSpec.step_fields`)."""
LOGGED_EPISODE_FIELDS = frozenset(
    {"trial", "episode", "return", "return_", "length", "queries", "accepted", "epsilon", "solved", "guided_steps", "global_step", "cut_by_step_budget", "placements", "failed_placements"}
)
"""The ``/episode`` fields lagrseq writes itself (``lagrseq.logs.events.EpisodeEvent`` and the
arm's record; a test keeps the two equal): a task's own fields take other names."""
LOGGED_STEP_FIELDS = frozenset(
    {"trial", "episode", "step", "global_step", "state", "action", "reward", "terminated", "truncated", "guided", "placement"}
)
"""The ``/transition`` fields lagrseq writes itself (``lagrseq.logs.events.Transition``)."""


def task_profiles(spec: TaskSpec) -> tuple[str, ...]:
    """The mock profiles of a task."""
    return tuple(spec.profiles() if callable(spec.profiles) else spec.profiles)


@dataclass(frozen=True)
class ProviderSpec:
    """A parsed ``--provider`` value: ``kind[:argument]``."""

    kind: str
    argument: str = ""
    """The mock's profile, the recorded store's directory (or JSONL file), the live model, or
    the local model's GGUF file."""

    def __str__(self) -> str:
        return f"{self.kind}:{self.argument}" if self.argument else self.kind


@dataclass(frozen=True)
class Flag:
    """The command-line flag that sets one field of a provider kind's options dataclass, written
    into the field's metadata with :func:`flag`. Declared once, on the field: every kind whose
    options hold that field (directly or in a dataclass composed into them) reads the flag."""

    flag: str
    """``--base-url``; the parsed value goes to the field's name."""
    help: str
    """Its help; ``{default}`` is the field's default, ``{per}`` what a budget counts (the command's)."""
    metavar: str | None = None
    type: Callable[[str], Any] | None = None
    """Reads and checks the text (argparse ``type=``: one line for a bad value)."""
    choices: tuple[str, ...] | None = None


def flag(
    name: str,
    help: str,  # noqa: A002 - argparse's word
    *,
    metavar: str | None = None,
    type: Callable[[str], Any] | None = None,  # noqa: A002 - argparse's word
    choices: tuple[str, ...] | None = None,
    logged_as: str | None = None,
) -> dict[str, Any]:
    """The metadata of an options field set by the flag ``name``: ``field(default=...,
    metadata=flag("--n-ctx", "..."))``. ``logged_as``: its name in the trial metadata's
    ``provider_options`` record (default: the field's)."""
    out: dict[str, Any] = {"flag": Flag(name, help, metavar, type, choices)}
    if logged_as is not None:
        out["logged_as"] = logged_as
    return out


NOT_LOGGED: dict[str, Any] = {"logged": False}
"""The metadata of an options field no flag sets and no log holds (set by the runner: where,
not what)."""


@dataclass(frozen=True)
class ProviderKind:
    """A kind of answer source (``--provider KIND[:ARGUMENT]``; entry-point group
    ``lagrseq.providers``). ``name``, ``usage`` and ``make`` are required; the flags below say
    what the kind can do, so no code compares kind names. An example:

    ```python
    ProviderKind(
        name="echo",
        usage="echo, echo:PROFILE",
        make=make_echo,                # (spec, config, rng, options) -> a Provider
        options=EchoOptions,           # its own flags (lagrseq.registry.flag)
        source="mock",                 # what its answers' /query records say
        synthetic=True,                # made up by the task's extrapolator
        description="the task's mock under another name (example plugin)",
    )
    ```"""

    name: str
    """The spec prefix, ``KIND`` in ``--provider KIND[:ARGUMENT]``."""
    usage: str
    """How the spec is written (``recorded:STORE``; several forms joined by ``, `` or
    `` or ``), for help and errors."""
    make: Callable[..., Any]
    """(spec, config, rng, options) -> the provider of one trial (``options``: an instance of
    ``options``, or None for a kind without options)."""
    options: type | str | None = None
    """The frozen dataclass of this kind's own options, or its ``module:Name`` (imported when
    first needed); None: it has none. Each field is set by the flag in its metadata
    (:func:`flag`) or is a dataclass of such fields (settings several kinds share, composed in);
    a flag given for a kind whose options lack its field is refused (one line)."""
    check_spec: Callable[[ProviderSpec], None] | None = None
    """Checks the argument at parse time; raises UsageError (one line)."""
    check: Callable[..., None] | None = None
    """(spec, config, options) -> None: fail before any trial starts (no answer is sent). Default:
    build the provider once and close it."""
    with_model: Callable[[Any, ProviderSpec], Any] | None = None
    """(config, spec) -> the configuration naming the model this spec asks (logs say so)."""
    source: str = ""
    """The ``source`` its answers carry in the ``/query`` log (``mock``, ``recorded``, ``live``)."""
    synthetic: bool = False
    """Its answers are made up by the task's extrapolator, no model is asked (the suite's
    default runs, which recorded answers may replace)."""
    local_server: bool = False
    """It starts a model server on this machine (checked without starting one)."""
    paid: bool = False
    """Its answers may cost money (budgets, the oracle's refusal, ledgers)."""
    records: bool = False
    """``lagrseq record`` can ask it and store its answers."""
    replays: bool = False
    """It answers from stored answers (``--on-miss`` applies)."""
    description: str = ""
    """One line on the kind, shown by ``lagrseq plugins`` and in every ``--provider`` help."""


@dataclass(frozen=True)
class Knob:
    """A setting of an asking policy, declared once by its :class:`PolicySpec`: read from
    ``[secondary] NAME = VALUE`` (a config file, a preset, ``--set secondary.NAME=VALUE``) and
    from ``lagrseq frontier --policies POLICY:NAME=VALUE``; ``candidates`` are what
    ``frontier --tune`` tries. A built-in policy's knob is the ``[secondary]`` field of its name
    (its type, range and default are the field's, and a test keeps the two equal); a plugin's
    knob may not take a field's name, a reserved word or another plugin's knob (the plugin is
    skipped: :func:`_policy_problems`), and is kept in the section's ``knobs``
    (``section.knob(NAME)``). An example:

    ```python
    Knob("backoff_factor", 0.5, ge=0.0, le=1.0, candidates=("0.25", "0.5", "0.75"),
         help="what the asking probability is multiplied by after a rejected answer")
    ```

    Signature: ``Knob(name, default, ge=None, le=None, choices=(), candidates=(), help="")``."""

    name: str
    """``[secondary] NAME``, ``--set secondary.NAME=V``, ``frontier --policies POLICY:NAME=V``
    (a built-in's: the ``[secondary]`` field of that name)."""
    default: Any
    """Its value when not set; its type (bool, int, float, str) is the knob's (an int is taken
    for a float)."""
    ge: float | None = None
    """Least value (numbers), inclusive."""
    le: float | None = None
    """Greatest value (numbers), inclusive."""
    choices: tuple[Any, ...] = ()
    """The values allowed (empty: any of its type and range)."""
    candidates: tuple[str, ...] = ()
    """The values ``lagrseq frontier --tune`` tries, as written on the command line (empty: the
    knob is not tuned; a policy's first knob with candidates is its tuned one)."""
    help: str = ""
    """One line on what it does, for people reading ``lagrseq plugins`` and the docs."""

    def check(self, value: Any, where: str) -> Any:
        """``value`` as this knob's type, or ConfigError (one line naming ``where``)."""
        from lagrseq.errors import ConfigError

        kind = type(self.default)
        ok = isinstance(value, kind) and not (kind is not bool and isinstance(value, bool))
        try:
            shown = repr(value)
        except ValueError:  # an integer past Python's digit limit
            shown = "an integer of thousands of digits"
        shown = shown if len(shown) <= 60 else shown[:57] + "..."
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            try:
                value, ok = float(value), True
            except OverflowError:  # an integer beyond any float
                raise ConfigError(f"{where} = {shown} is out of range; expected {self.ge} <= value <= {self.le}") from None
        if not ok:
            raise ConfigError(f"{where} = {shown} has the wrong type; expected {kind.__name__}, found {type(value).__name__}")
        if kind in (int, float) and (value != value or (self.ge is not None and value < self.ge) or (self.le is not None and value > self.le)):
            raise ConfigError(f"{where} = {shown} is out of range; expected {self.ge if self.ge is not None else '-inf'} <= value <= {self.le if self.le is not None else 'inf'}")
        if self.choices and value not in self.choices:
            raise ConfigError(f"{where} = {shown} is not allowed; expected one of {', '.join(map(repr, self.choices))}")
        return value


@dataclass(frozen=True)
class PolicySpec:
    """An asking policy (``secondary.policy``, ``lagrseq frontier --policies``; entry-point
    group ``lagrseq.policies``). ``name`` and ``make`` are required. An example:

    ```python
    PolicySpec(
        name="backoff",
        make=make_backoff,             # (section, seq_agent) -> decide / update
        knobs=("ask_probability", "min_progress", "budget", "budget_scope", "query_cost",
               Knob("backoff_factor", 0.5, ge=0.0, le=1.0)),
        order=20,                      # after the built-ins (0 to 5)
        description="halve the asking probability after each rejected answer",
    )
    ```"""

    name: str
    """``secondary.policy = "NAME"``, ``frontier --policies NAME``."""
    make: Callable[[Any, Callable[[], Any]], Any]
    """(the ``[secondary]`` section, a builder of the paper's SEQ agent) -> the policy
    (``decide(context)``, ``update(context, asked, query_reward)``)."""
    knobs: tuple[str | Knob, ...] = ()
    """What it reads: a name is a ``[secondary]`` field every policy shares (the progress gate,
    the budget); a :class:`Knob` is its own (``lagrseq frontier``'s NAME:KNOB=VALUE)."""
    method: str = "lagr-seq"
    """The method that runs it without knobs (``never``: baseline, ``always``: lagr)."""
    order: int = 100
    """Its place in frontier tables and figures, lowest first: the built-ins use 0 (never) to 5
    (oracle); a plugin's default, 100, puts it after them; a plugin may choose its own, e.g. 20."""
    peeks: bool = False
    """It looks at the provider's answer before deciding (refused with paid answers)."""
    comparator: bool = False
    """It is the frontier's yardstick: the other policies are compared with it run at their
    own query rate (``random``), so it is never matched itself."""
    description: str = ""
    """One line on how it decides, shown by ``lagrseq plugins``."""
    design_seeds: tuple[int, ...] = ()
    """Run seeds whose logs its rule or defaults were read from: a frontier point on one of them
    is shown with the role ``design`` and never credited (not evidence)."""


@dataclass(frozen=True)
class ExecutorSpec:
    """Where a run's trials run (``--executor NAME``; entry-point group ``lagrseq.executors``).
    ``name`` and ``make`` are required. An example:

    ```python
    ExecutorSpec(
        name="threads",
        make=lambda jobs, scheduler, reporter: ThreadExecutor(jobs),   # a TrialExecutor
        workers=("thread", "threads"),
        description="trials in threads of this process",
    )
    ```"""

    name: str
    """``--executor NAME``."""
    make: Callable[[int, str | None, Reporter], Any]
    """(jobs, scheduler address or None, reporter) -> a ``TrialExecutor``; ``reporter``
    (:class:`lagrseq.progress.Reporter`) is told lines such as a started cluster's address."""
    takes_scheduler: bool = False
    """``--scheduler`` applies to it."""
    runner_pool: bool = False
    """The runner's own pool: trials run in this process with one job, else in a pool of local
    processes (``make`` is called only where a pool object is needed)."""
    workers: tuple[str, str] = ("process", "processes")
    """What its workers are called, one and many (the suite's time estimate)."""
    description: str = ""
    """One line on where trials run, shown by ``lagrseq plugins``."""


# ------------------------------------------------------------------------------------------
# Registries
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Entry:
    """A registered part and where it came from."""

    name: str
    spec: Any
    source: str
    """``lagrseq`` for a built-in, else the plugin's distribution (``name version``)."""
    entry_point: str = ""
    distribution: str = BUILTIN
    """The distribution that made the part (``lagrseq`` for a built-in)."""
    version: str = ""
    """That distribution's version ("" for a built-in: lagrseq's own, :func:`part_origin`)."""


@dataclass(frozen=True)
class Failure:
    """A plugin that could not be loaded (skipped)."""

    group: str
    entry_point: str
    source: str
    problem: str


_S = TypeVar("_S")


@dataclass
class Registry(Generic[_S]):
    """Named specs of one kind: the built-ins, then the plugins of ``group``."""

    kind: str
    group: str
    spec_type: type
    _entries: dict[str, Entry] = field(default_factory=dict)
    _loaded: bool = False

    def register(self, spec: _S, source: str = BUILTIN, entry_point: str = "", distribution: str = BUILTIN, version: str = "") -> _S:
        """Add ``spec`` under its name; a name already taken raises ValueError."""
        if not isinstance(spec, self.spec_type):
            raise TypeError(f"a {self.kind} registry takes {self.spec_type.__name__}, not {type(spec).__name__}")
        name = getattr(spec, "name")  # noqa: B009 - every spec type has a name
        if not isinstance(name, str) or not name or not name.isprintable() or ":" in name or "," in name:
            raise ValueError(f"{self.kind} name {name!r}: expected a printable name without ':' or ','")
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is already registered by {self._entries[name].source}")
        self._entries[name] = Entry(name, spec, source, entry_point, distribution, version)
        return spec

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        _builtins()
        _load_plugins(self)

    def get(self, name: str) -> _S:
        """The spec called ``name``; UsageError (one line naming the choices) if none is."""
        self._load()
        entry = self._entries.get(name)
        if entry is None:
            raise UsageError(f"unknown {self.kind} {name!r}; expected one of: {', '.join(self.names())}")
        spec: _S = entry.spec
        return spec

    def find(self, name: str) -> _S | None:
        self._load()
        entry = self._entries.get(name)
        return None if entry is None else entry.spec  # type: ignore[no-any-return]

    def names(self) -> tuple[str, ...]:
        self._load()
        return tuple(self._entries)

    def entries(self) -> tuple[Entry, ...]:
        self._load()
        return tuple(self._entries.values())

    def specs(self) -> Iterator[_S]:
        for entry in self.entries():
            yield entry.spec

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._entries


def part_origin(kind: str, name: str) -> tuple[str, str]:
    """``(distribution, version)`` of the registered part ``name`` of ``kind`` (a registry's key,
    ``tasks``, or its kind, ``task``): ``("lagrseq", lagrseq's version)`` for a built-in, the
    plugin's distribution and version otherwise. UsageError (one line) for an unknown kind or
    part."""
    registry = REGISTRIES.get(kind) or next((r for r in REGISTRIES.values() if r.kind == kind), None)
    if registry is None:
        raise UsageError(f"unknown kind of part {kind!r}; expected one of: {', '.join(REGISTRIES)}")
    registry.get(name)  # one line naming the choices when unknown
    entry = registry._entries[name]
    if entry.distribution == BUILTIN:
        from lagrseq import __version__

        return BUILTIN, __version__
    return entry.distribution, entry.version


TASKS: Registry[TaskSpec] = Registry("task", GROUPS["tasks"], TaskSpec)
PROVIDERS: Registry[ProviderKind] = Registry("provider", GROUPS["providers"], ProviderKind)
POLICIES: Registry[PolicySpec] = Registry("policy", GROUPS["policies"], PolicySpec)
EXECUTORS: Registry[ExecutorSpec] = Registry("executor", GROUPS["executors"], ExecutorSpec)
REGISTRIES: dict[str, Registry[Any]] = {"tasks": TASKS, "providers": PROVIDERS, "policies": POLICIES, "executors": EXECUTORS}
FAILURES: list[Failure] = []
"""Plugins skipped in this process (``lagrseq plugins`` lists them)."""

_builtins_done = False


def _builtins() -> None:
    """Register the built-in parts once (``lagrseq.builtins`` calls :meth:`Registry.register`)."""
    global _builtins_done
    if _builtins_done:
        return
    _builtins_done = True
    importlib.import_module("lagrseq.builtins")


PLUGIN_TIMEOUT_ENV = "LAGRSEQ_PLUGIN_TIMEOUT_S"
"""The environment variable bounding one plugin's import and registration, in seconds."""
DEFAULT_PLUGIN_TIMEOUT_S = 10.0
"""A plugin whose import, call and registration take longer is reported and skipped."""
NOTICES_ENV = "LAGRSEQ_PLUGIN_NOTICES_PID"
"""The pid of the process that prints plugin skip lines (set by the command line to its own);
other processes of the command (pool workers, which inherit it) skip plugins silently. Unset:
every process prints its own."""



def _text(value: Any) -> str:
    """A plugin's text (a description: meant to be a string) made printable, never raising."""
    try:
        return printable(value if isinstance(value, str) else repr(value))
    except BaseException:  # noqa: BLE001 - a hostile __repr__
        return "(unreadable)"


def _say(line: str) -> None:
    print(f"lagrseq: {line}", file=sys.stderr, flush=True)


def _one_line(exc: BaseException) -> str:
    """``Type: message`` on one printable line; an exception whose ``str`` (or type name)
    raises is named as such, never raising itself."""
    try:
        name = printable(str(type(exc).__name__))
    except BaseException:  # noqa: BLE001 - a hostile type: its name unreadable too
        name = "an exception"
    try:
        text = printable(" ".join(str(exc).split()))
    except BaseException as inner:  # noqa: BLE001 - a plugin's __str__ may raise anything
        try:
            text = f"(its message cannot be read: str() raised {type(inner).__name__})"
        except BaseException:  # noqa: BLE001
            text = "(its message cannot be read)"
    text = text if len(text) <= 200 else text[:197] + "..."
    return f"{name}: {text}" if text else name


_ENTRY_POINTS: list[Any] = []


def _entry_points() -> Any:
    """Every installed entry point, read once per process: each registry selects its group
    from the one scan (a scan of the installed distributions' metadata costs about 6 ms of CPU,
    and four registries used to make four)."""
    if not _ENTRY_POINTS:
        if _may_declare_plugins():
            from importlib.metadata import entry_points

            _ENTRY_POINTS.append(entry_points())
        else:
            _ENTRY_POINTS.append(_NoEntryPoints())
    return _ENTRY_POINTS[0]


class _NoEntryPoints:
    """The scan's answer where no installed distribution names a lagrseq group."""

    def select(self, group: str) -> tuple[Any, ...]:
        return ()


def _may_declare_plugins() -> bool:
    """False only when no distribution on ``sys.path`` can declare a lagrseq entry point: no
    ``entry_points.txt`` of a ``.dist-info``/``.egg-info`` directory mentions a lagrseq group.
    It reads the files ``importlib.metadata`` would, without importing it (with the ``email``
    and ``zipfile`` modules it brings, about 20 ms of a run's start-up). Anything it cannot
    judge (a zip on the path, another distribution finder, an unreadable directory) counts as
    a maybe, and the full scan decides."""
    import os
    from importlib.machinery import PathFinder

    if any(getattr(finder, "find_distributions", None) is not None and finder is not PathFinder for finder in sys.meta_path):
        return True
    groups = [group.encode() for group in GROUPS.values()]
    for entry in sys.path:
        where = entry or "."
        if not os.path.isdir(where):
            if os.path.exists(where):
                return True  # a zip file: its distributions are for importlib.metadata to find
            continue
        try:
            names = os.listdir(where)
        except OSError:
            return True
        for name in names:
            if not name.lower().endswith((".dist-info", ".egg-info")):
                continue
            try:
                with open(os.path.join(where, name, "entry_points.txt"), "rb") as file:
                    text = file.read()
            except (FileNotFoundError, NotADirectoryError):
                continue
            except OSError:
                return True
            if any(group in text for group in groups):
                return True
    return False


def plugin_timeout_s() -> float:
    """The bound on one plugin's loading (:data:`PLUGIN_TIMEOUT_ENV`, else the default); a value
    that is not a positive number is the default."""
    try:
        value = float(os.environ.get(PLUGIN_TIMEOUT_ENV, ""))
    except ValueError:
        return DEFAULT_PLUGIN_TIMEOUT_S
    return value if 0 < value < float("inf") else DEFAULT_PLUGIN_TIMEOUT_S


_HUNG_MODULES: set[str] = set()
"""Modules whose import did not finish in time (their import lock is held by the abandoned
thread: importing them again would wait for it)."""


def _notices() -> bool:
    owner = os.environ.get(NOTICES_ENV)
    return owner is None or owner == str(os.getpid())


def _skip(registry: Registry[Any], name: str, source: str, problem: str) -> None:
    FAILURES.append(Failure(registry.group, name, source, problem))
    if _notices():
        _say(f"plugin {printable(repr(name))} ({printable(source)}, group {registry.group}) skipped: {problem}")


def _origin(ep: Any) -> tuple[str, str]:
    """(distribution, version) of an entry point's distribution, never raising."""
    try:
        dist = getattr(ep, "dist", None)
        return (str(dist.name), str(dist.version)) if dist is not None else ("unknown distribution", "")
    except Exception:  # noqa: BLE001 - metadata without a name or version
        return ("unknown distribution", "")


def _load_one(ep: Any, timeout_s: float) -> list[Any] | str:
    """The specs an entry point gives (``ep.load()``, called when it is a function), or one
    line saying why it is skipped. The load runs in a daemon thread that this thread waits for
    at most ``timeout_s``: one that does not finish is abandoned (a daemon never holds the exit).
    Nothing process-wide is changed for it, and it is not a sandbox: a plugin is trusted code
    (docs/security.md). Whatever it raises is one line, except ``KeyboardInterrupt``, which
    stops the command as Ctrl-C does."""
    result: list[Any] = []

    def load() -> None:
        try:
            loaded = ep.load()
            if callable(loaded) and not isinstance(loaded, type):
                loaded = loaded()
            result.append(list(loaded) if isinstance(loaded, (list, tuple)) else [loaded])
        except BaseException as exc:  # noqa: BLE001 - whatever a plugin raises, it is only skipped
            result.append(exc)

    loader = threading.Thread(target=load, name=f"lagrseq-plugin-{ep.name}"[:60], daemon=True)
    loader.start()
    loader.join(timeout_s)
    if loader.is_alive():
        _HUNG_MODULES.add(str(getattr(ep, "module", "") or ep.value.partition(":")[0]))
        return (
            f"its loading did not finish within {timeout_s:g} s (an import that loops, sleeps or waits); "
            f"it is left in a background thread: fix or uninstall the plugin, or raise {PLUGIN_TIMEOUT_ENV}"
        )
    if not result:
        return "its loading ended without a result"
    if isinstance(result[0], KeyboardInterrupt):
        raise KeyboardInterrupt
    return _one_line(result[0]) if isinstance(result[0], BaseException) else result[0]  # type: ignore[no-any-return]


@dataclass
class _Loaded:
    """An entry point's specs, loaded and checked against the built-ins (not yet registered)."""

    ep: Any
    origin: tuple[str, str]
    specs: list[Any]

    @property
    def source(self) -> str:
        return " ".join(part for part in self.origin if part)


def _load_plugins(registry: Registry[Any]) -> None:
    """Add the specs of every entry point of ``registry.group``, the Gymnasium way: load, call,
    register. One that raises, does not finish within :func:`plugin_timeout_s`, or takes a name,
    knob or flag someone else owns (:func:`_refused`, :func:`_contested`) is skipped with one
    stderr line naming it; which plugins load never depends on the order of entry points."""
    try:
        found = sorted(_entry_points().select(group=registry.group), key=lambda ep: (ep.name, str(ep.value)))
    except Exception as exc:  # noqa: BLE001 - broken metadata of some distribution: skip them all, say so
        if _notices():
            _say(f"plugins of {registry.group} skipped: the installed packages' metadata cannot be read ({_one_line(exc)})")
        return
    timeout_s = plugin_timeout_s()
    loaded: list[_Loaded] = []
    for ep in found:
        origin = _origin(ep)
        source = " ".join(part for part in origin if part)
        module = str(getattr(ep, "module", "") or str(ep.value).partition(":")[0])
        if module in _HUNG_MODULES:
            _skip(registry, ep.name, source, f"its module {printable(module)} did not finish importing for another entry point")
            continue
        specs = _load_one(ep, timeout_s)
        problem = specs if isinstance(specs, str) else _refused(registry, specs)
        if problem:
            _skip(registry, ep.name, source, problem)
            continue
        loaded.append(_Loaded(ep, origin, specs))  # type: ignore[arg-type]
    contested = _contested(registry, loaded)
    for item in loaded:
        if id(item) in contested:
            _skip(registry, item.ep.name, item.source, contested[id(item)])
            continue
        for spec in item.specs:
            registry.register(spec, item.source, f"{item.ep.name} = {item.ep.value}", *item.origin)


# ------------------------------------------------------------------------------------------
# Ownership: one owner per name, knob and flag
# ------------------------------------------------------------------------------------------
RESERVED_KNOBS = frozenset({"policy", "knobs"})
"""Words no plugin knob may take: ``[secondary] policy`` chooses the policy, ``knobs`` holds
the plugins' knobs in a logged configuration."""
KNOB_TYPES = (bool, int, float, str)
"""The types a plugin knob's default may have (its type is the knob's)."""


def _refused(registry: Registry[Any], specs: list[Any]) -> str:
    """Why the specs of one entry point cannot be registered beside the built-ins ("" when
    they can): a wrong spec type or name, a built-in's name (built-ins win), a policy knob that
    names a shared field, a reserved word or a knob of another of its policies, a knob whose
    type, range or candidates do not hold together, a provider flag or option another kind
    declares."""
    staged: Registry[Any] = Registry(registry.kind, registry.group, registry.spec_type, dict(registry._entries), True)
    try:
        for spec in specs:
            name = getattr(spec, "name", None) if isinstance(spec, registry.spec_type) else None
            if isinstance(name, str) and name in registry._entries:
                return f"its {registry.kind} {printable(repr(name))} is a built-in (lagrseq's own); built-ins win: rename the plugin's"
            staged.register(spec, "this very plugin")
        if registry is POLICIES:
            return _policy_problems(specs)
        if registry is PROVIDERS:
            return _flag_problems(specs)
    except BaseException as exc:  # noqa: BLE001 - a hostile spec (a property that raises, a bad options type)
        if isinstance(exc, KeyboardInterrupt):
            raise
        return _one_line(exc)
    return ""


def shared_fields() -> frozenset[str]:
    """The ``[secondary]`` fields of every registered task (what ``[secondary] NAME`` already
    means: a knob of that name would silently become the field)."""
    names: set[str] = set()
    for spec in TASKS.specs():
        section = spec.sections.get("secondary") if isinstance(spec.sections, Mapping) else None
        if isinstance(section, type) and dataclasses.is_dataclass(section):
            names.update(f.name for f in dataclasses.fields(section))
    return frozenset(names)


def _policy_problems(specs: list[PolicySpec]) -> str:
    """The first knob of these plugin policies that is not theirs alone to declare ("": none)."""
    shared = shared_fields()
    seen: dict[str, str] = {}
    for spec in specs:
        if not isinstance(spec.knobs, tuple):
            return f"policy {printable(repr(spec.name))}: its knobs are a {type(spec.knobs).__name__}; expected a tuple of Knob and [secondary] field names"
        for knob in spec.knobs:
            if isinstance(knob, str):
                continue
            if not isinstance(knob, Knob):
                return f"policy {printable(repr(spec.name))}: a knob is a {type(knob).__name__}; expected a Knob or a [secondary] field's name"
            where = f"knob {printable(repr(knob.name))} of policy {printable(repr(spec.name))}"
            if knob.name in RESERVED_KNOBS:
                return f"{where} is a reserved word of [secondary] (owned by lagrseq); rename the knob"
            if knob.name in shared:
                return f"{where} is a [secondary] field (owned by lagrseq and the tasks); rename the knob, or name the field as a string to read it"
            if knob.name in seen:
                return f"{where} is also a knob of its policy {printable(repr(seen[knob.name]))}; a knob has one owner: rename one"
            seen[knob.name] = spec.name
            problem = knob_problem(knob)
            if problem:
                return f"{where}: {problem}"
    return ""


def knob_problem(knob: Knob) -> str:
    """Why a plugin knob's declaration does not hold together ("" when it does): a name that
    cannot be written as ``secondary.NAME``, a type lagrseq cannot read, a range on a knob that
    is not a number, a default, choice or candidate its own check refuses."""
    if not isinstance(knob.name, str) or not knob.name.isidentifier():
        return "its name is not an identifier (it is written secondary.NAME)"
    kind = type(knob.default)
    if kind not in KNOB_TYPES:
        return f"its default {_text(repr(knob.default))} is a {kind.__name__}; expected bool, int, float or str"
    if (knob.ge is not None or knob.le is not None) and kind not in (int, float):
        return f"it has a range (ge/le) but its default {_text(repr(knob.default))} is a {kind.__name__}; a range applies to numbers only"
    from lagrseq.errors import ConfigError

    try:
        knob.check(knob.default, "its default")
        for choice in knob.choices:
            knob.check(choice, "a choice")
        for text in knob.candidates:  # read as --set and frontier's POLICY:KNOB=VALUE read them
            from lagrseq.tomlfile import value_of

            knob.check(value_of(text), f"the candidate {text!r}")
    except (ConfigError, ValueError) as exc:
        return str(exc)
    return ""


@dataclass(frozen=True)
class _Declared:
    """One leaf field of a provider kind's options: where it is declared, and what it takes."""

    owner: type
    field: str
    flag: str | None
    logged_as: str | None

    @property
    def names(self) -> list[tuple[str, str]]:
        """What this declaration owns: its field's name (the parsed flag's destination), its flag
        and its logged name."""
        out = [("option", self.field)]
        if self.flag is not None:
            out.append(("flag", self.flag))
        if self.logged_as is not None:
            out.append(("logged option", self.logged_as))
        return out


def _declarations(cls: type | None) -> list[_Declared]:
    """The leaf fields of an options dataclass with the class declaring each."""
    if cls is None:
        return []
    hints = _type_hints(cls)
    out: list[_Declared] = []
    for f in dataclasses.fields(cls):
        hint = hints.get(f.name)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out += _declarations(hint)
            continue
        declared = f.metadata.get("flag")
        logged = f.metadata.get("logged_as", f.name) if f.metadata.get("logged", True) else None
        out.append(_Declared(cls, f.name, declared.flag if isinstance(declared, Flag) else None, logged))
    return out


def _owned(kinds: list[ProviderKind]) -> dict[tuple[str, str], tuple[_Declared, str]]:
    """(what, name) -> (its declaration, the kind declaring it), over ``kinds``."""
    out: dict[tuple[str, str], tuple[_Declared, str]] = {}
    for kind in kinds:
        for declared in _declarations(options_type(kind)):
            for key in declared.names:
                out.setdefault(key, (declared, kind.name))
    return out


def _flag_problems(kinds: list[ProviderKind]) -> str:
    """The first option, flag or logged name of these plugin kinds that a built-in kind declares
    otherwise ("": none). A flag is declared once, on one field: a kind that composes that very
    dataclass reads it; another declaration of the same flag is never merged with it."""
    taken = _owned([entry.spec for entry in PROVIDERS._entries.values()])
    for kind in kinds:
        for declared in _declarations(options_type(kind)):
            if declared.flag is not None and (not declared.flag.startswith("--") or not declared.flag[2:].replace("-", "").isalnum()):
                return f"provider {printable(repr(kind.name))}: its flag {printable(repr(declared.flag))} is not of the form --word-word"
            for what, name in declared.names:
                owner = taken.get((what, name))
                if owner is not None and owner[0] != declared:
                    return (f"provider {printable(repr(kind.name))}'s {what} {printable(name)} is already declared by "
                            f"provider {printable(repr(owner[1]))} (lagrseq); flags are never merged: rename it")
    return ""


def _contested(registry: Registry[Any], loaded: list[_Loaded]) -> dict[int, str]:
    """The plugins (by ``id``) that claim a name, knob or flag another plugin claims too, each
    with its line: both are refused, whichever loaded first."""
    claims: dict[tuple[str, str], list[tuple[_Loaded, Any]]] = {}
    for item in loaded:
        for spec in item.specs:
            for key, declared in _claims(registry, spec):
                claims.setdefault(key, []).append((item, declared))
    out: dict[int, str] = {}
    for (what, name), claimants in claims.items():
        items = {id(item): item for item, _ in claimants}
        declarations = {id(declared) for _, declared in claimants}
        if len(items) < 2 or len(declarations) < 2:
            continue  # one plugin, or one declaration composed into several of its kinds
        for item in items.values():
            others = sorted({other.source for other in items.values() if other is not item})
            out.setdefault(id(item), (
                f"its {what} {printable(repr(name))} is also claimed by {printable(', '.join(others))}; "
                f"two plugins claiming one {what} are both skipped: uninstall or rename one"
            ))
    return out


def _claims(registry: Registry[Any], spec: Any) -> list[tuple[tuple[str, str], Any]]:
    """What one plugin spec claims: its name, its own knobs (a policy), its options, flags and
    logged names (a provider kind); each with the object declaring it."""
    out: list[tuple[tuple[str, str], Any]] = [((registry.kind, spec.name), spec)]
    if isinstance(spec, PolicySpec):
        out += [(("knob", knob.name), knob) for knob in own_knobs(spec)]
    if isinstance(spec, ProviderKind):
        out += [(key, declared) for declared in _declarations(options_type(spec)) for key in declared.names]
    return out


def drop_plugin(registry: Registry[Any], name: str, problem: str) -> None:
    """Unregister the plugin part ``name`` after loading (a provider flag that a command's own
    option takes: found where the command line is built), with its skip line."""
    entry = registry._entries.get(name)
    if entry is None or entry.distribution == BUILTIN:
        return
    del registry._entries[name]
    _skip(registry, entry.entry_point.partition(" = ")[0] or name, entry.source, problem)


ON_MISS = ("error", "mock", "live", "refuse", "calibrated")
"""What answers a query a recorded store lacks (``--on-miss``, a suite run's ``on_miss``): stop
with an error, the rule-based mock, the live server (recorded), a refusal (source ``miss``,
never accepted), or a draw fixed per prompt at the acceptance rate the store's own answers show
for prompts of its kind (source ``calibrated``, ``lagrseq.llm.calibrated``; tasks with a
``miss_calibration`` only). Here, below both the command line and the suite file, which both
check it."""
REFUSED_SOURCE = "miss"
"""The ``source`` of a refused miss (``on_miss = refuse``) in a ``/query`` record."""
CALIBRATED_MISS = "calibrated"
"""The ``on_miss`` value, and the ``source`` of its answers, whose rates are fitted to the store's
answers (numbers made with it are ``fitted``: ``lagrseq.analysis.provenance``)."""


def kind_of(spec: str) -> ProviderKind | None:
    """The registered kind of a ``--provider`` value (``KIND[:ARGUMENT]``), None if unknown."""
    return PROVIDERS.find(spec.partition(":")[0])


def stored_sources() -> set[str]:
    """The ``source`` of answers read from stored answers (``recorded``): any other source in a
    run on a store is a miss a fallback answered."""
    return {kind.source for kind in PROVIDERS.specs() if kind.replays}


def paid_sources() -> set[str]:
    """The ``source`` of answers that may have cost money (``live``)."""
    return {kind.source for kind in PROVIDERS.specs() if kind.paid}


def _knob_lines(spec: Any) -> list[str]:
    """A policy's knobs for ``lagrseq plugins``: the shared ``[secondary]`` fields it reads, then
    each knob of its own with its default and help."""
    if not isinstance(spec, PolicySpec) or not spec.knobs:
        return []
    shared = [k for k in spec.knobs if isinstance(k, str)]
    lines = [f"      reads [secondary] {_text(', '.join(shared))}"] if shared else []
    for knob in own_knobs(spec):  # a plugin's text: control characters escaped
        lines.append(f"      knob {_text(knob.name)} = {_text(repr(knob.default))}" + (f": {_text(knob.help)}" if knob.help else ""))
    return lines


def listing() -> list[str]:
    """``lagrseq plugins``: every registered part by registry, with its source distribution,
    then the plugins that were skipped."""
    lines: list[str] = []
    for kind, registry in REGISTRIES.items():
        entries = registry.entries()
        lines.append(f"{kind} (entry-point group {registry.group}): {len(entries)}")
        width = max((len(e.name) for e in entries), default=0)
        for entry in entries:
            about = _text(getattr(entry.spec, "description", ""))
            where = entry.source if not entry.entry_point else f"{entry.source} [{entry.entry_point}]"
            lines.append(f"  {printable(entry.name):<{width}}  {printable(where)}" + (f": {about}" if about else ""))
            lines += _knob_lines(entry.spec)
    if FAILURES:
        lines.append(f"skipped plugins: {len(FAILURES)}")
        lines += [f"  {printable(f.entry_point)} ({printable(f.source)}, group {f.group}): {f.problem}" for f in FAILURES]
    return lines


# ------------------------------------------------------------------------------------------
# Provider options: each kind's own dataclass, its fields set by flags declared on them
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OptionField:
    """A field of a provider kind's options (a leaf: nested dataclasses are walked through)."""

    name: str
    default: Any
    flag: Flag | None
    logged_as: str | None
    """Its name in the logged ``provider_options`` record (None: not logged)."""


def options_type(kind: ProviderKind) -> type | None:
    """The options dataclass of ``kind`` (its ``module:Name`` imported), None if it has none."""
    if kind.options is None or isinstance(kind.options, type):
        return kind.options
    module, _, name = kind.options.partition(":")
    found = getattr(importlib.import_module(module), name)
    if not isinstance(found, type) or not dataclasses.is_dataclass(found):
        raise TypeError(f"provider {kind.name!r}: options {kind.options!r} is not a dataclass")
    return found


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints`` of an options dataclass, worked out once per class: it compiles
    every annotation, which cost about a millisecond of every logged trial (the log's
    ``provider_options`` metadata). Read only."""
    return typing.get_type_hints(cls)


def option_fields(cls: type | None) -> tuple[OptionField, ...]:
    """The leaf fields of an options dataclass, in order (composed dataclasses walked through)."""
    if cls is None:
        return ()
    hints = _type_hints(cls)
    out: list[OptionField] = []
    for f in dataclasses.fields(cls):
        hint = hints.get(f.name)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out += option_fields(hint)
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None  # type: ignore[misc]
        )
        logged = f.metadata.get("logged", True)
        out.append(OptionField(f.name, default, f.metadata.get("flag"), f.metadata.get("logged_as", f.name) if logged else None))
    return tuple(out)


def option_flags() -> dict[str, OptionField]:
    """Every provider flag, by the field it sets, from the registered kinds' options (each field
    name has one declaration: a plugin that redeclares one is skipped, :func:`_flag_problems`)."""
    out: dict[str, OptionField] = {}
    for kind in PROVIDERS.specs():
        for option in option_fields(options_type(kind)):
            if option.flag is not None and option.name not in out:
                out[option.name] = option
    return out


def build_options(kind: ProviderKind, given: Mapping[str, Any], elsewhere: tuple[str, ...] = ()) -> Any:
    """``kind``'s options from the flags ``given`` (field name -> parsed value; None: not
    given), each field not given at its default. A flag given for a kind whose options lack its
    field raises UsageError (one line), unless the command uses it ``elsewhere`` itself."""
    cls = options_type(kind)
    own = {option.name for option in option_fields(cls)}
    given = {name: value for name, value in given.items() if value is not None}
    for name in given:
        if name not in own and name not in elsewhere:
            flags = option_flags()
            shown = flags[name].flag.flag if name in flags and flags[name].flag is not None else name  # type: ignore[union-attr]
            users = [k.usage.replace(" or ", ", ").split(", ")[0] for k in PROVIDERS.specs() if name in {o.name for o in option_fields(options_type(k))}]
            raise UsageError(f"{shown} applies to --provider {' or '.join(users) or 'none'} only, not {kind.name}; leave it out")
    return None if cls is None else _build(cls, given)


def _build(cls: type, given: Mapping[str, Any]) -> Any:
    hints = _type_hints(cls)
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        hint = hints.get(f.name)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            values[f.name] = _build(hint, given)
        elif f.name in given:
            values[f.name] = given[f.name]
    return cls(**values)


def logged_options(options: Any) -> str:
    """The trial metadata's ``provider_options`` record: every built-in kind's logged options at
    their defaults, then the fields of ``options`` (the run's provider kind's) at their values,
    as sorted JSON (a log names each built-in option whatever the provider; the API key never,
    only the name of its variable)."""
    import json

    record = dict(_builtin_logged_defaults())
    if options is not None:
        record.update(_logged_values(options))
    return json.dumps(record, sort_keys=True)


_BUILTIN_DEFAULTS: dict[tuple[int, ...], tuple[tuple[Any, ...], dict[str, Any]]] = {}
"""Per set of built-in provider kinds (their specs' ids; the specs are kept, so no id is reused):
the specs and their logged options at their defaults."""


def _builtin_logged_defaults() -> dict[str, Any]:
    """Every built-in provider kind's logged options at their defaults, made once: walking the
    kinds' option fields costs about 0.1 ms, and every trial's metadata holds them."""
    specs = tuple(entry.spec for entry in PROVIDERS.entries() if entry.source == BUILTIN)
    key = tuple(map(id, specs))
    made = _BUILTIN_DEFAULTS.get(key)
    if made is None:
        defaults = {o.logged_as: o.default for spec in specs for o in option_fields(options_type(spec)) if o.logged_as}
        made = _BUILTIN_DEFAULTS[key] = (specs, defaults)
    return made[1]


def _logged_values(options: Any) -> dict[str, Any]:
    kind: type = type(options)
    hints = _type_hints(kind)
    out: dict[str, Any] = {}
    for f in dataclasses.fields(options):
        value = getattr(options, f.name)
        hint = hints.get(f.name)
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out.update(_logged_values(value))
        elif f.metadata.get("logged", True):
            out[f.metadata.get("logged_as", f.name)] = value
    return out


def find_part(options: Any, cls: type) -> Any:
    """The ``cls`` instance composed into ``options`` (``options`` itself if it is one), or None."""
    if isinstance(options, cls):
        return options
    if options is None or not dataclasses.is_dataclass(options):
        return None
    for f in dataclasses.fields(options):
        found = find_part(getattr(options, f.name), cls)
        if found is not None:
            return found
    return None


def replace_part(options: Any, part: Any) -> Any:
    """``options`` with its composed ``type(part)`` instance replaced by ``part``."""
    if isinstance(options, type(part)):
        return part
    changes = {
        f.name: replace_part(getattr(options, f.name), part)
        for f in dataclasses.fields(options)
        if find_part(getattr(options, f.name), type(part)) is not None
    }
    return dataclasses.replace(options, **changes)


# ------------------------------------------------------------------------------------------
# Policy knobs
# ------------------------------------------------------------------------------------------
def knob_names(spec: PolicySpec) -> tuple[str, ...]:
    """The names of everything ``spec`` reads (shared fields and its own knobs), in order."""
    return tuple(k if isinstance(k, str) else k.name for k in spec.knobs)


def own_knobs(spec: PolicySpec) -> tuple[Knob, ...]:
    return tuple(k for k in spec.knobs if isinstance(k, Knob))


def find_knob(name: str) -> Knob | None:
    """The registered :class:`Knob` called ``name`` (None: no policy has one). A plugin knob's
    name has one owner; built-ins that share a knob share its ``[secondary]`` field."""
    for spec in POLICIES.specs():
        for knob in own_knobs(spec):
            if knob.name == name:
                return knob
    return None


def tuned_knob(spec: PolicySpec) -> Knob | None:
    """The knob ``lagrseq frontier --tune`` chooses for ``spec``: its first with candidates."""
    return next((k for k in own_knobs(spec) if k.candidates), None)
