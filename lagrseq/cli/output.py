"""What the commands print: lines above any progress bar, with keys blanked and controls
escaped; the bars; a report's closing lines."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any


def _shown(text: object) -> str:
    """Outside text for one line of the terminal: every guarded key blanked (:func:`lagrseq.keys.scrub`),
    control and format characters escaped (:func:`lagrseq.text.printable`)."""
    from lagrseq.text import shown

    return shown(text)


def _warn(command: str) -> Callable[[str], None]:
    return lambda message: print(f"lagrseq {command}: warning: {_shown(message)}", file=sys.stderr)


def _reporter(command: str, quiet: bool = False) -> Any:
    """A :class:`lagrseq.progress.Reporter` for ``lagrseq COMMAND``: lines on stdout above any
    bar (:func:`_say`), warnings on stderr (:func:`_warn`)."""
    from lagrseq.progress import Reporter

    return Reporter(_say, _warn(command), quiet)


def _say(line: str) -> None:
    """A line on stdout, above any progress bar (never glued onto the bar's line)."""
    from lagrseq.progress import say

    say(_shown(line))


def _say_error(line: str) -> None:
    """A line on stderr, above any progress bar (keys blanked, controls escaped)."""
    from lagrseq.progress import say

    say(_shown(line), stderr=True)


def _bar(total: float, unit: str, desc: str | None, quiet: bool) -> Any:
    from lagrseq.progress import bar

    return bar(total, unit, desc, quiet)


def _print_report(
    report: Any, elapsed: float | None = None, not_run_said: bool = False, width: int | None = None,
    said: Callable[[str], bool] | None = None,
) -> None:
    """The items not made and the warnings (``width``: each warning cut to that many characters;
    the whole text is on the report's page; ``said``: warnings already said otherwise, left out),
    then one line on what was made."""
    made = [r for r in report.items if r.made]
    for r in report.items:
        if not r.made:
            if not_run_said:  # said while it ran (not run: before; failed: when its run failed)
                continue
            print(f"{r.item.id}: {r.not_run_line()}")
        elif r.status == "partial":
            print(f"{r.item.id}: partial; missing {'; '.join(r.missing())}")
    for note in report.notes:
        print(note)
    for warning in report.warnings:
        if said is not None and said(warning):
            continue
        line = f"warning: {' '.join(_shown(warning).split())}"
        if width is not None and len(line) > width:
            line = line[: width - 1] + "…"
        print(line, file=sys.stderr)
    took = f" in {elapsed:.1f} s" if elapsed is not None else ""
    if not report.items:  # no suite covers the logs (the lines above say why): their runs are still shown
        print(_shown(f"no suite item covers these {report.logs.files} logs{took}; their runs and parts: {report.out / 'index.html'}"))
        return
    print(_shown(f"{len(made)} of {len(report.items)} suite items made from {report.logs.files} logs{took}: {report.out / 'index.html'}"))


def _price_function(price_table: str | None) -> Any:
    """``(model, prompt tokens, completion tokens) -> USD or None`` for replay's costs tables
    (analysis never imports the provider layer itself)."""
    from lagrseq.cli.helpers import price_function

    return price_function(price_table)
