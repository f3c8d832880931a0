"""The option groups several commands share, each declared once (parent parsers), and the
number types every value from the command line is checked by where it enters."""

from __future__ import annotations

import argparse
import textwrap
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NoReturn

from lagrseq.cli.output import _say, _shown

HELP_COLUMN = 30
"""Where an option's help starts: an option with its metavar up to 26 characters shares its line."""


class _Help(argparse.RawDescriptionHelpFormatter):
    """``--help`` that fits a screen: each option's help beside it from :data:`HELP_COLUMN`, a
    usage longer than three lines cut to ``[options]`` and what is required, prose paragraphs
    wrapped to the terminal, examples (paragraphs of several lines) kept as written."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, max_help_position=HELP_COLUMN)

    def _split_lines(self, text: str, width: int) -> list[str]:  # "arm-arrangement" stays whole
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n\n".join(
            part if "\n" in part else textwrap.fill(" ".join(part.split()), width, initial_indent=indent, subsequent_indent=indent)
            for part in text.split("\n\n")
        )

    def _format_usage(self, usage: str | None, actions: Iterable[argparse.Action], groups: Iterable[Any], prefix: str | None) -> str:
        actions = list(actions)
        full = super()._format_usage(usage, actions, groups, prefix)
        if usage is not None or full.count("\n") <= 4:  # three lines at most, then a blank one
            return full
        kept = [a for a in actions if not a.option_strings or a.required]
        short = super()._format_usage(usage, kept, [], prefix)
        head = f"{'usage: ' if prefix is None else prefix}{self._prog}"
        return short.replace(head, f"{head} [options]", 1)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (the usage block is what --help is for) and :class:`_Help`."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _Help)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:  # the value refused may be the key, or hold a newline
        self.exit(2, f"{self.prog}: error: {_shown(message)} (see {self.prog} --help)\n")


def _number_types() -> dict[str, Callable[[str], Any]]:
    from lagrseq import config as cfg

    return {
        "count": cfg.number_type("count", integer=True, ge=1, le=100_000),
        "jobs": cfg.number_type("processes", integer=True, ge=1, le=1024),
        "samples": cfg.number_type("answers", integer=True, ge=1, le=10_000),
        "prompts": cfg.number_type("prompts", integer=True, ge=1, le=10_000),
        "seed": cfg.seed_int,
        "budget": cfg.number_type("US dollars", ge=0, le=1e6),
        "limit": cfg.number_type("queries", integer=True, ge=0, le=10**9),
        "retries": cfg.number_type("retries", integer=True, ge=0, le=100),
        "temperature": cfg.temperature_float,
        "max_tokens": cfg.max_tokens_int,
        "seconds": cfg.number_type("seconds", gt=0, le=86_400),
        "bytes": cfg.number_type("bytes", integer=True, ge=1024, le=2**31),
        "context": cfg.number_type("tokens", integer=True, ge=64, le=2**20),
        "threads": cfg.number_type("threads", integer=True, ge=0, le=1024),
        "port": cfg.number_type("port", integer=True, ge=0, le=65535),
        "concurrency": cfg.number_type("requests", integer=True, ge=1, le=256),
        "share": cfg.number_type("share", ge=0, le=1),
        "episodes": cfg.number_type("episodes", integer=True, ge=0, le=10**7),
        "steps": cfg.number_type("steps", integer=True, ge=-1, le=10**9),
        "objects": cfg.number_type("objects", integer=True, ge=1, le=10_000),
        "count0": cfg.number_type("count", integer=True, ge=0, le=100_000),
    }


_N = _number_types()
_COUNT, _SEED, _BUDGET, _LIMIT, _TEMPERATURE = _N["count"], _N["seed"], _N["budget"], _N["limit"], _N["temperature"]
_PORT = _N["port"]


def _formats(text: str) -> list[str]:
    from lagrseq.analysis.replay import FORMATS as FIGURE_FORMATS

    formats = [f.strip().lower() for f in text.split(",") if f.strip()]
    unknown = [f for f in formats if f not in FIGURE_FORMATS]
    if unknown or not formats:
        raise argparse.ArgumentTypeError(f"{text!r}: figure formats are {', '.join(FIGURE_FORMATS)} (comma-separated)")
    return formats


def _experiment_options() -> argparse.ArgumentParser:
    """--preset, --config, --set: how a configuration is resolved."""
    from lagrseq.config import PRESETS

    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("configuration")
    g.add_argument("--preset", choices=PRESETS, default="upstream", help="upstream (the released code's; default) or paper (docs/presets.md)")
    g.add_argument("--config", type=Path, default=None, metavar="FILE.toml", help="a TOML file of [section] fields applied over the preset")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override one field (repeatable), e.g. --set env.horizon=100")
    return p


def _task_argument(p: argparse.ArgumentParser) -> None:
    from lagrseq.config import tasks

    p.add_argument("task", metavar="TASK", choices=tasks(), help=f"one of: {', '.join(tasks())}")


def _provider_flags(per: str) -> argparse.ArgumentParser:
    """Every provider kind's option flags (run, frontier, record), each declared once, on the
    field of the options dataclass it sets (``lagrseq.registry.flag``); a flag not given is None
    (its field keeps its default). Grouped by the kinds that read them."""
    p = argparse.ArgumentParser(add_help=False)
    if not _BARE:
        _add_provider_flags(p, per)
    return p


_BARE: list[bool] = []
"""Set while :func:`_command_options` builds the commands without provider flags."""


_FLAG_COMMANDS = ("run", "frontier", "record", "screen")
"""The commands whose parsers take every provider flag."""
_FLAG_ADDERS: dict[str, Callable[[Any], None]] = {}
"""Their parsers' adders, registered by :func:`takes_provider_flags` where each is defined."""


def takes_provider_flags(command: str) -> Callable[[Callable[[Any], None]], Callable[[Any], None]]:
    """Register ``command``'s parser adder (one of :data:`_FLAG_COMMANDS`), so that
    :func:`_command_options` can build the command without its provider flags."""

    def register(add: Callable[[Any], None]) -> Callable[[Any], None]:
        _FLAG_ADDERS[command] = add
        return add

    return register


_TAKEN: dict[str, str] = {}
"""What :func:`_command_options` found (worked out once)."""


def _command_options() -> dict[str, str]:
    """Every option string and destination of the commands taking provider flags, without those
    flags, each with its command's name: what a plugin's flag may not take."""
    if _TAKEN:
        return _TAKEN
    taken = _TAKEN
    _BARE.append(True)
    try:
        for command in _FLAG_COMMANDS:
            sub = argparse.ArgumentParser(add_help=False).add_subparsers()
            _FLAG_ADDERS[command](sub)
            for action in sub.choices[command]._actions:
                for name in [*action.option_strings, action.dest]:
                    taken.setdefault(name, command)
    finally:
        _BARE.clear()
    return taken


def drop_clashing_plugin_flags() -> None:
    """Skip (one line) each plugin provider kind whose flag, or the field it sets, is taken by
    a command's own option (``--trials``): the command keeps working, without that plugin."""
    from lagrseq import registry

    plugins = [e for e in registry.PROVIDERS.entries() if e.distribution != registry.BUILTIN]
    flagged = [(e, o) for e in plugins for o in registry.option_fields(registry.options_type(e.spec)) if o.flag is not None]
    if not flagged:
        return
    taken = _command_options()
    for entry, option in flagged:
        for name in (option.flag.flag, option.name):  # type: ignore[union-attr]
            if name in taken and entry.name in registry.PROVIDERS:
                what = "option" if name.startswith("-") else "destination of an option"
                registry.drop_plugin(registry.PROVIDERS, entry.name, (
                    f"its flag {registry.printable(option.flag.flag)} (provider {registry.printable(repr(entry.name))}) "  # type: ignore[union-attr]
                    f"takes the {what} {registry.printable(name)} of lagrseq {taken[name]}, which the command owns; rename the flag"
                ))


def _add_provider_flags(p: argparse.ArgumentParser, per: str, only: tuple[str, ...] | None = None) -> None:
    """The provider flags (``only``: those setting these fields, with their defaults: serve-llm):
    those a built-in kind reads in one group, each plugin kind's own under its usage."""
    from lagrseq.registry import BUILTIN, PROVIDERS, option_fields, option_flags, options_type

    drop_clashing_plugin_flags()
    readers = {e.spec.usage: {o.name for o in option_fields(options_type(e.spec))} for e in PROVIDERS.entries()}
    built_in = {o.name for e in PROVIDERS.entries() if e.distribution == BUILTIN for o in option_fields(options_type(e.spec))}
    groups: dict[str, Any] = {}
    for name, option in option_flags().items():
        if only is not None and name not in only:
            continue
        title = PROVIDER_OPTIONS if name in built_in else "options of --provider " + ", ".join(
            usage for usage, names in readers.items() if name in names)
        group = groups.get(title) or groups.setdefault(title, p.add_argument_group(title))
        f = option.flag
        assert f is not None  # option_flags holds flagged fields only
        group.add_argument(
            f.flag, dest=name, type=f.type, choices=f.choices, metavar=f.metavar,
            default=option.default if only is not None else None,
            help=f.help.format(default=option.default, per=per).replace("%", "%%"),
        )


PROVIDER_OPTIONS = "provider options (which --provider kinds read each: docs/providers.md)"
"""The title of the built-in provider kinds' flags (a plugin kind's own flags: its own group)."""


def _executor_options() -> argparse.ArgumentParser:
    """Where trials run: this machine's processes or Dask (run and reproduce)."""
    from lagrseq.running.executors import EXECUTORS

    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("execution")
    g.add_argument("--executor", choices=EXECUTORS, default="local", help="local (--jobs processes here; default) or dask (docs/dask.md)")
    g.add_argument("--scheduler", default=None, metavar="URL", help="with --executor dask: an existing scheduler, tcp://HOST:PORT")
    g.add_argument("--retries", type=_N["retries"], default=0, metavar="N", help="rerun a trial that raised up to N times (default 0: deterministic)")
    return p


def _make_executor(args: argparse.Namespace, start: bool = True) -> Any:
    """The executor of ``--executor``/``--scheduler`` (None: the runner's own process pool, or
    nothing to ``start``)."""
    from lagrseq.registry import EXECUTORS
    from lagrseq.running.executors import check_scheduler, make_executor

    spec = EXECUTORS.get(args.executor)
    if args.scheduler is not None:
        check_scheduler(args.scheduler)
    if spec.runner_pool or not start:
        if args.scheduler is not None and not spec.takes_scheduler:
            from lagrseq.errors import UsageError

            raise UsageError("--scheduler applies to --executor dask only")
        return None
    from lagrseq.progress import Reporter

    return make_executor(args.executor, args.jobs, args.scheduler, Reporter(_say))


def _quiet() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _report_options() -> argparse.ArgumentParser:
    """What replay and reproduce share: the suite, the figure formats, the price table."""
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("report")
    g.add_argument("--formats", type=_formats, default=["png"], metavar="png,svg,pdf", help="figure formats; PNG is always written (default: png)")
    g.add_argument("--suite", default=None, metavar="FILE.toml|TASK", help="suite file or task shipping one (default: the paper's; docs/suites.md)")
    g.add_argument("--price-table", default=None, metavar="FILE.toml", help="re-cost logged queries with these prices over the built-in dated table")
    return p


def _provider_argument(p: argparse.ArgumentParser, default: str | None, role: str, records: bool = False, shown: str | None = None) -> None:
    """``--provider SPEC``, the one definition: its help lists the registered provider kinds
    (``records``: only those ``lagrseq record`` can ask; ``shown``: what no ``--provider``
    means, when ``default`` is None); ``lagrseq plugins`` describes each."""
    from lagrseq.registry import PROVIDERS

    kinds = [k for k in PROVIDERS.specs() if k.records or not records]
    forms = "; ".join(k.usage for k in kinds)
    shown = (shown or "any") if default is None else default
    p.add_argument("--provider", default=default, metavar="SPEC", help=f"{role} (default: {shown}): {forms}")


def _provider_options(args: argparse.Namespace, elsewhere: tuple[str, ...] = ()) -> Any:
    """The options of ``--provider``'s kind, built by its spec from the provider flags given (a
    flag its kind does not read: one line, exit 2; ``elsewhere``: flags the command uses itself)."""
    from lagrseq.registry import option_flags
    from lagrseq.running.wiring import load_prices, provider_options

    if args.price_table is not None:  # read now, whatever the provider: a bad file is one line before anything runs
        load_prices(args.price_table)
    return provider_options(args.provider, {name: getattr(args, name, None) for name in option_flags()}, elsewhere)
