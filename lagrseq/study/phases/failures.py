"""What ``reproduce`` says about runs that failed: one line on the terminal, a reason and a
rerun command on the report, the whole text in :data:`ERRORS_LOG`."""

from __future__ import annotations

import contextlib
import os
import re
import shlex
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq import outputs
from lagrseq.config import ExperimentConfig

ERRORS_LOG = "reproduce-errors.log"
"""``OUT/reproduce-errors.log``: the whole text of every failure of the latest ``reproduce`` into
OUT (removed by a run in which nothing failed). The terminal gets one short line per run."""
LINE_WIDTH = 300
"""At most this many characters in a failed run's line on the terminal."""
REASON_WIDTH = 200
"""At most this many characters in a failed item's reason on the report."""
_ABSOLUTE = re.compile(r"(?<![\w.~/-])/(?!/)[^\s;,()'\"`<>|]+")


def _clip(text: str, width: int) -> str:
    one = " ".join(text.split())
    return one if len(one) <= width else one[: max(0, width - 1)].rstrip() + "…"


def without_absolute_paths(text: str) -> str:
    """``text`` with every absolute path shortened to its file or folder name (a report's bytes
    must not depend on where its inputs sat)."""
    return _ABSOLUTE.sub(lambda m: Path(m.group(0).rstrip(".")).name + ("." if m.group(0).endswith(".") else ""), text)


@dataclass(frozen=True)
class RunFailure:
    """A run of the suite (or of one of its audits) some of whose trials failed, or that could
    not start: what ``reproduce`` says about it on the terminal, in the report and in
    :data:`ERRORS_LOG`."""

    what: str
    """The run as people name it: task, method, preset, provider, config digest."""
    path: Path
    """Its run directory (or probe log)."""
    failed: int
    total: int
    """Trials that failed, of those it had to run."""
    errors: tuple[str, ...]
    """One whole text per failed trial (``trial N (seed S, config D) failed: ...``)."""
    error: str
    """The first failure's error (whole)."""
    advice: str
    """What to do, by the cause (:func:`lagrseq.running.runner.rerun_advice`)."""
    items: tuple[str, ...] = ()
    """The suite items it feeds."""
    audit: str = ""
    """The task whose suite audit it belongs to ("" for a suite item's run)."""
    short: str = ""
    """The run's name on the terminal (default: :attr:`what`)."""

    @property
    def owner(self) -> str:
        return f"{self.audit} audit" if self.audit else ",".join(self.items)

    def reason(self) -> str:
        """One short line, with no absolute path (for the report)."""
        return _clip(without_absolute_paths(f"{self.failed} of {self.total} trials of {self.what} failed: {self.error}"), REASON_WIDTH)

    def line(self) -> str:
        """One line of at most :data:`LINE_WIDTH` characters (for the terminal): who, which run,
        the error cut short (at least 60 characters of it) and what to do; the whole text is in
        :data:`ERRORS_LOG`, which the summary line names."""
        head = f"failed: {self.owner}: {self.failed} of {self.total} trials of "
        tail = f"; {self.advice}"
        what = _clip(without_absolute_paths(self.short or self.what), max(20, LINE_WIDTH - len(head) - len(tail) - 2 - 60))
        room = LINE_WIDTH - len(head) - len(what) - 2 - len(tail)
        return _clip(f"{head}{what}: {_clip(self.error, max(room, 20))}{tail}", LINE_WIDTH)

    def log_text(self, out: Path) -> str:
        """Its block of :data:`ERRORS_LOG`: everything, paths relative to ``out`` where inside it."""
        try:
            where = self.path.relative_to(out).as_posix()
        except ValueError:
            where = str(self.path)
        lines = [
            f"== {self.owner}: {self.what}",
            f"run: {where}; {self.failed} of {self.total} trials failed",
            f"what to do: {self.advice}",
            *self.errors,
            "",
        ]
        return "\n".join(lines)


def describe_config(config: ExperimentConfig, provider: str) -> str:
    return f"{config.task.name} {config.method} --preset {config.preset} on {provider} (config {config.digest()})"


def short_name(config: ExperimentConfig, provider: str) -> str:
    return f"{config.task.name} {config.method} on {provider}"


def item_failures(failures: Sequence[RunFailure], rerun: Callable[[list[str]], str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The suite items the failed runs feed (item id -> :class:`~lagrseq.analysis.items.ItemFailure`,
    in the order first failed) and the audits that failed ("TASK audit" -> the same), each with
    the first failed run's reason, every distinct advice and ``rerun([item id])``, the command that
    reruns it alone (an audit: ``--items audit-TASK``, :func:`audit_item`)."""
    from lagrseq.analysis.items import ItemFailure

    by_item: dict[str, list[RunFailure]] = {}
    by_audit: dict[str, list[RunFailure]] = {}
    for failure in failures:
        if failure.audit:
            by_audit.setdefault(f"{failure.audit} audit", []).append(failure)
        for item in failure.items:
            by_item.setdefault(item, []).append(failure)

    def made(runs: list[RunFailure], command: str) -> ItemFailure:
        advice = "; ".join(dict.fromkeys(f.advice for f in runs))
        return ItemFailure(runs[0].reason(), advice, command, len(runs), tuple(str(f.path) for f in runs))

    return (
        {item: made(runs, rerun([item])) for item, runs in by_item.items()},
        {audit: made(runs, rerun([audit_item(runs[0].audit)])) for audit, runs in by_audit.items()},
    )


def rerun_command(
    items: Sequence[str],
    quick: bool,
    suite_path: Path | None,
    provider: str | None,
    out: Path,
    seed: int | None,
    authors_caches: Path | None,
    relative: bool = False,
) -> str:
    """The ``lagrseq reproduce`` command that reruns ``items`` alone (none: the whole suite), with the user's flags that
    change what runs or where it goes (``relative``: paths relative to this directory, for a
    report, which must hold no absolute path)."""

    def shown(path: Path) -> str:
        text = os.path.relpath(path) if relative and path.is_absolute() else str(path)
        return shlex.quote(text)

    words = ["lagrseq reproduce"] + (["--quick"] if quick else []) + (["--items", ",".join(items)] if items else [])
    if suite_path is not None:
        words += ["--suite", shown(suite_path)]
    if provider is not None:
        words += ["--provider", shlex.quote(provider)]
    if seed is not None:
        words += ["--seed", str(seed)]
    if authors_caches is not None:
        words += ["--authors-caches", shown(authors_caches)]
    if out != Path("lagrseq-out"):  # the command line's default (lagrseq.cli.DEFAULT_REPRODUCE_OUT)
        words += ["--out", shown(out)]
    return " ".join(words)


def write_errors_log(out: Path, failures: Sequence[RunFailure], reruns: Mapping[str, str] | None = None) -> Path:
    """``OUT/reproduce-errors.log`` with every failure's whole text (secrets blanked), then the
    command that reruns each failed item (``reruns``: item id or "TASK audit" -> command); a
    stale one is removed when nothing failed."""
    from lagrseq.keys import redact_key_like

    path = out / ERRORS_LOG
    if not failures:
        if os.path.isfile(path) and not os.path.islink(path):  # a folder or FIFO there is not ours
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        return path
    header = [
        f"lagrseq reproduce: {len(failures)} failed run{'s' if len(failures) != 1 else ''} "
        "(each: who, the run, what to do, then every failed trial's whole error)",
        "",
    ]
    text = "\n".join(header) + "\n".join(f.log_text(out) for f in failures)
    if reruns:
        text += "\n".join(["== to rerun each alone", *(f"{key}: {command}" for key, command in reruns.items()), ""])
    outputs.write_text(path, redact_key_like(without_checkout(text)), "--out")  # every key form blanked there
    return path


def without_checkout(text: str) -> str:
    """``text`` with the folder holding lagrseq (a traceback's file names) written relative to it:
    a log must not tell where the checkout lies."""
    from lagrseq.paths import source_checkout

    folder = str(source_checkout())
    return text.replace(folder + os.sep, "") if len(folder) > 1 else text


def failure_summary(failed: Mapping[str, Any], problems: Mapping[str, Any], items_total: int, out: Path) -> str:
    """The one line ``reproduce`` ends with when something failed: ``3 of 23 items failed: table3
    (2 runs), ...; details in OUT/reproduce-errors.log`` (``failed``: item id -> its
    :class:`~lagrseq.analysis.items.ItemFailure`; ``problems``: the audits that failed)."""

    def runs(n: int) -> str:
        return f"{n} run{'s' if n != 1 else ''}"

    parts = []
    if failed:
        parts.append(f"{len(failed)} of {items_total} items failed: " + ", ".join(f"{key} ({runs(f.runs)})" for key, f in failed.items()))
    if problems:
        parts.append(("also " if failed else "") + ", ".join(f"the {key} ({runs(f.runs)})" for key, f in problems.items()) + " failed")
    return "; ".join(parts) + f"; details in {out / ERRORS_LOG}"


AUDIT_ITEM_PREFIX = "audit-"


def audit_item(task: str) -> str:
    """The ``--items`` id that runs ``task``'s audit alone (``audit-TASK``: the stem of its tables)."""
    return f"{AUDIT_ITEM_PREFIX}{task}"
