"""The ``lagrseq`` command line. Exit status: 0 success, 2 bad usage or bad input (one line on
stderr), 3 ``reproduce`` finished but some items failed (their runs failed; every other item is
reported, one summary line on stderr), 4 a verdict flips between the two reports ``lagrseq
compare`` read, 130 interrupted by Ctrl-C (SIGINT), 143 stopped by SIGTERM (a batch scheduler,
``kill``: the same clean stop as Ctrl-C, logs kept), 1 an unexpected failure.

This module assembles the parser and runs a command (errors, interrupts, exit status). Each
command group is a module of its own: :mod:`~lagrseq.cli.run` (run, config, robot),
:mod:`~lagrseq.cli.providers` (record, cache, serve-llm, models), :mod:`~lagrseq.cli.reports`
(reproduce, replay, compare, recover), :mod:`~lagrseq.cli.study` (frontier, audit, screen) and
:mod:`~lagrseq.cli.plugins` (plugins, info); the option groups they share are declared once in
:mod:`~lagrseq.cli.options` (parent parsers, taking their choices from the code's own constants),
what they print in :mod:`~lagrseq.cli.output`. Each ``cmd_*`` handler parses, calls one function
and prints.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any

from lagrseq import __version__
from lagrseq.cli.options import _Parser, drop_clashing_plugin_flags
from lagrseq.cli.output import _shown
from lagrseq.cli.plugins import _add_info, _add_plugins, cmd_info, cmd_plugins
from lagrseq.cli.providers import (
    _add_cache,
    _add_models,
    _add_record,
    _add_serve_llm,
    cmd_cache,
    cmd_models,
    cmd_record,
    cmd_serve_llm,
)
from lagrseq.cli.reports import (
    COMPARE_FLIPPED,
    DEFAULT_REPRODUCE_OUT,
    ITEMS_FAILED,
    _add_compare,
    _add_recover,
    _add_replay,
    _add_reproduce,
    cmd_compare,
    cmd_recover,
    cmd_replay,
    cmd_reproduce,
)
from lagrseq.cli.run import _add_config, _add_robot, _add_run, cmd_config, cmd_robot, cmd_run
from lagrseq.cli.study import (
    _add_audit,
    _add_frontier,
    _add_screen,
    cmd_audit,
    cmd_frontier,
    cmd_screen,
)
from lagrseq.errors import LagrseqError

__all__ = [
    "COMMANDS", "COMPARE_FLIPPED", "DEFAULT_REPRODUCE_OUT", "INTERRUPTED", "ITEMS_FAILED", "Terminated",
    "build_parser", "cmd_audit", "cmd_cache", "cmd_compare", "cmd_config", "cmd_frontier", "cmd_info",
    "cmd_models", "cmd_plugins", "cmd_record", "cmd_recover", "cmd_replay", "cmd_reproduce", "cmd_robot",
    "cmd_run", "cmd_screen", "cmd_serve_llm", "drop_clashing_plugin_flags", "main",
]


_ADDERS: dict[str, Callable[[Any], None]] = {
    "run": _add_run, "config": _add_config, "record": _add_record, "cache": _add_cache,
    "reproduce": _add_reproduce, "replay": _add_replay, "recover": _add_recover, "robot": _add_robot,
    "frontier": _add_frontier, "audit": _add_audit, "serve-llm": _add_serve_llm, "plugins": _add_plugins,
    "models": _add_models, "screen": _add_screen, "compare": _add_compare, "info": _add_info,
}
"""Each command's parser, in the order ``lagrseq --help`` lists them."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser: every command's, or (``command``) only that command's, which
    parses that command's arguments the same way and leaves out what the other commands' options
    and help texts import (the study, recording and report modules a run never uses)."""
    parser = _Parser(
        prog="lagrseq",
        description=(
            "LaGR-SEQ reproducibility toolkit: run RL agents guided by (mock, recorded or live) "
            "LLM answers, log every step to MCAP, and rebuild the paper's results offline."
        ),
    )
    parser.add_argument("--version", action="version", version=f"lagrseq {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, add in _ADDERS.items():
        if command is None or name == command:
            add(sub)
    for name, page in _DOCS.items():  # every command's help ends with the page that explains it
        if name in sub.choices:
            shown = sub.choices[name]
            shown.epilog = f"{shown.epilog}\n\nmore: {page}" if shown.epilog else f"more: {page}"
    return parser


_DOCS = {
    "run": "docs/tasks.md", "config": "docs/reference/config.md", "record": "docs/providers.md",
    "cache": "docs/providers.md", "reproduce": "docs/reproduce.md", "replay": "docs/reproduce.md",
    "recover": "docs/reproduce.md", "robot": "docs/arm.md", "audit": "docs/audit.md",
    "serve-llm": "docs/providers.md", "plugins": "docs/extending.md", "models": "docs/providers.md",
    "screen": "docs/open-models.md", "compare": "docs/reproduce.md", "info": "docs/install.md",
}
"""The documentation page of each command, named at the end of its ``--help``."""


COMMANDS = {
    "plugins": cmd_plugins,
    "audit": cmd_audit,
    "info": cmd_info,
    "run": cmd_run,
    "config": cmd_config,
    "record": cmd_record,
    "cache": cmd_cache,
    "recover": cmd_recover,
    "replay": cmd_replay,
    "reproduce": cmd_reproduce,
    "robot": cmd_robot,
    "frontier": cmd_frontier,
    "serve-llm": cmd_serve_llm,
    "models": cmd_models,
    "screen": cmd_screen,
    "compare": cmd_compare,
}


INTERRUPTED = {
    "run": "finished trial logs are kept, unfinished ones left as .partial (lagrseq recover); run the same command to go on",
    "record": "answers recorded so far are kept in the store; run the same command to go on",
    "reproduce": "finished trial logs are kept, unfinished ones left as .partial; run the same command to go on",
    "frontier": "finished trial logs are kept, unfinished ones left as .partial; run the same command to go on",
    "audit": "finished trial logs are kept, unfinished ones left as .partial; run the same command to go on",
    "serve-llm": "the server is stopped",
    "robot": "the service is stopped",
}


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread is, so it stops a command as Ctrl-C does."""


def _terminate(*_: Any) -> None:
    raise Terminated


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:  # the program itself prints plugin skip lines, its pool workers do not
        from lagrseq import registry

        os.environ[registry.NOTICES_ENV] = str(os.getpid())
        sys.excepthook = _key_guarded_traceback  # an unforeseen error's traceback never shows a key
    return _main(argv)


def _key_guarded_traceback(kind: type[BaseException], value: BaseException, trace: Any) -> None:
    """Python's traceback of an error nothing caught, with every guarded key blanked."""
    import traceback

    from lagrseq.keys import scrub

    sys.stderr.write(scrub("".join(traceback.format_exception(kind, value, trace))))


def _main(argv: Sequence[str] | None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    # a command named first (the only place argparse takes it): build that command's parser alone
    parser = build_parser(words[0] if words and words[0] in _ADDERS else None)
    if argv is None:  # the program itself: a name its encoding cannot write is escaped, never a traceback
        from lagrseq.text import safe_streams

        safe_streams()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    previous = None
    previous_int = None
    with contextlib.suppress(ValueError):  # not the main thread (a caller's own thread): left alone
        previous = signal.signal(signal.SIGTERM, _terminate)  # a batch scheduler's stop: as Ctrl-C
        # a wrapper that blocked SIGTERM (or SIGINT) hands the mask down across exec: undo that,
        # or the stop would never arrive (the handler above also replaces an inherited SIG_IGN)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM, signal.SIGINT})
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            # started in the background by a shell (``lagrseq run ... &`` in a script), which
            # ignores SIGINT for its children; Python then installs no Ctrl-C handler and
            # ``kill -INT`` did nothing. A command stops on SIGINT as on SIGTERM.
            previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _dispatch(args, argv)
    finally:
        if argv is not None:  # a caller's main([...]): its handlers back
            with contextlib.suppress(ValueError):
                if previous is not None:
                    signal.signal(signal.SIGTERM, previous)
                if previous_int is not None:
                    signal.signal(signal.SIGINT, previous_int)


def _exit_on_next_interrupt() -> None:
    """From now on a Ctrl-C ends the process at once with status 130, a SIGTERM with 143 (as
    :func:`lagrseq.running.executor_base.exit_on_next_interrupt`; here, so that the way out imports
    nothing: a second signal during an import would raise a second traceback)."""
    with contextlib.suppress(ValueError):  # not the main thread: nothing to install
        signal.signal(signal.SIGINT, lambda *_: os._exit(130))
        signal.signal(signal.SIGTERM, lambda *_: os._exit(143))


def _dispatch(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    from lagrseq.agents.numerics import numerics

    try:
        numerics()  # LAGRSEQ_NUMERICS checked before anything runs (a bad value: one line, exit 2)
        return COMMANDS[args.command](args)
    except LagrseqError as exc:
        print(f"lagrseq {args.command}: error: {_shown(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:
        _exit_on_next_interrupt()
        kept = INTERRUPTED.get(args.command, "nothing finished is lost")
        terminated = isinstance(stop, Terminated)
        status = 143 if terminated else 130
        print(f"lagrseq {args.command}: {'stopped by SIGTERM' if terminated else 'interrupted'}; {kept}", file=sys.stderr)
        if argv is None:  # the program itself (not a caller's main([...])): leave now, because an
            # interpreter shutdown joins worker threads and restores SIGINT's default action, so a
            # second Ctrl-C in that time would kill the process mid-way
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(status)
        return status
    except BrokenPipeError:  # pragma: no cover - e.g. piped into head
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:  # the last resort: a full disk, a path that vanished, a read-only file system
        where = f" ({os.fsdecode(exc.filename) if isinstance(exc.filename, (str, bytes)) else exc.filename})" if exc.filename else ""
        reason = exc.strerror or str(exc) or type(exc).__name__
        print(f"lagrseq {args.command}: error: {_shown(reason + where)}; nothing finished is lost", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
