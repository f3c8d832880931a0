"""``lagrseq replay``: MCAP logs in, the paper's figures, tables and costs out. The only module of
:mod:`lagrseq.analysis` that writes files.

For every item of the suite (``lagrseq/experiments/paper_suite.toml``) that the logs cover, it
writes the figure (``figures/ID.png``, plus SVG/PDF on request, and the numbers behind it as
``figures/ID.csv``) and the tables (``tables/ID.md`` and ``.csv``); then the costs and runs tables,
``index.html`` showing all of it with a line on how each item was made, and ``index.md`` (the same
for a Markdown viewer). Items the logs do not cover get one line saying why.

Same logs in, same bytes out: figures are saved without timestamps or software versions (PNG
``Software``, PDF dates, SVG ids from a fixed salt), runs and rows are sorted, floats have fixed
formats, and no wall-clock time is written. No absolute path is written either: the
warnings about skipped logs name each log by its path from the folder replay was given (as the
user typed it when relative, else from that folder's name), while the terminal names it by its full
path so that the command a warning suggests runs as written. The header's totals count the logs
read; skipped logs are counted apart.
"""

from __future__ import annotations

import contextlib
import dataclasses
import html
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib
import matplotlib.axes
import pandas as pd
from matplotlib.figure import Figure

from lagrseq import __version__, outputs
from lagrseq.analysis import audit, costs, figures, findings, items, loading, scoreboard, stats
from lagrseq.analysis.items import ItemFailure
from lagrseq.analysis.tables import Table, plus_minus, to_csv, to_html, to_markdown
from lagrseq.errors import LagrseqError, LogError, UsageError
from lagrseq.suite import (
    AUTHORS_HINT,
    Item,
    Suite,
    is_authors_provider,
    logged_tasks_suite,
    with_recorded,
)
from lagrseq.text import markdown_text

FORMATS = ("png", "svg", "pdf")
DPI = 150
_SAVE_METADATA: dict[str, dict[str, None]] = {
    "png": {"Software": None},
    "svg": {"Date": None, "Creator": None},
    "pdf": {"CreationDate": None, "ModDate": None, "Producer": None, "Creator": None},
}
_RC = {**figures.STYLE, "svg.hashsalt": "lagrseq", "pdf.compression": 6, "path.simplify": True}


FAILED = "failed"
"""The status of an item a failed run feeds (shown as FAILED)."""


@dataclass
class ItemReport:
    """What replay made of one suite item."""

    item: Item
    matched: list[items.Match]
    figure: str | None = None
    figure_size: tuple[int, int] = (0, 0)
    """Pixel width and height of the PNG."""
    figure_files: list[str] = field(default_factory=list)
    figure_data: str | None = None
    tables: list[tuple[Table, str, str]] = field(default_factory=list)
    method: str = ""
    animation: str | None = None
    """Arm items: a GIF of the arm in one episode (from the camera frames of a log)."""
    animation_note: str = ""
    failure: ItemFailure | None = None
    """A run it needs failed (``lagrseq reproduce``): reported as failed, not made."""

    @property
    def status(self) -> str:
        if self.failure is not None:
            return FAILED
        present = sum(m.run is not None for m in self.matched)
        if present == 0:
            return "not run"
        return "made" if present == len(self.matched) else "partial"

    def missing(self) -> list[str]:
        return [f"{m.label}: {m.reason}" for m in self.matched if m.run is None]

    def not_run_line(self) -> str:
        if self.failure is not None:
            return self.failure.line()
        reasons = sorted({m.reason for m in self.matched if m.run is None})
        return "not run: " + "; ".join(reasons)

    @property
    def made(self) -> bool:
        """Whether replay made anything of it (neither "not run" nor failed)."""
        return self.status not in ("not run", FAILED)


@dataclass
class Report:
    """Everything one replay wrote."""

    out: Path
    logs: loading.Logs
    items: list[ItemReport]
    written: list[Path]
    failed: dict[str, ItemFailure] = field(default_factory=dict)
    """Suite items that a failed run feeds (item id -> why, what to do, the command to rerun it)."""
    problems: dict[str, ItemFailure] = field(default_factory=dict)
    """Other failures the report names (``lagrseq reproduce``'s suite audits: "TASK audit" -> ...)."""
    notes: tuple[str, ...] = ()
    """Suites left out because no log is of their tasks (one line each; replay without a suite)."""

    @property
    def warnings(self) -> tuple[str, ...]:
        return self.logs.warnings


class _Painter:
    """Draws figures into files: in this process, or in the worker processes of ``pool`` (the
    figures are made here, pickled, and drawn there, where most of a figure's time goes; their
    bytes come back and are written here)."""

    def __init__(self, pool: Executor | None) -> None:
        self.pool = pool
        self.pending: list[tuple[Future[list[bytes]], list[Path]]] = []

    def save(self, figure: Figure, files: Sequence[tuple[Path, str]], styled: bool) -> None:
        """Write ``figure`` to each (path, format), with replay's rcParams when ``styled``."""
        paths, formats = [path for path, _ in files], [fmt for _, fmt in files]
        args = (figure, formats, DPI, _SAVE_METADATA, _RC if styled else None)
        if self.pool is None:
            self._write(paths, figures.render(*args))
        else:
            self.pending.append((self.pool.submit(figures.render, *args), paths))

    def wait(self) -> None:
        """Every figure written (a worker's error is raised here)."""
        for future, paths in self.pending:
            self._write(paths, future.result())
        self.pending.clear()

    @staticmethod
    def _write(paths: Sequence[Path], drawn: Sequence[bytes]) -> None:
        for path, data in zip(paths, drawn, strict=True):
            outputs.write_bytes(path, data, "--out")


def _save_figure(
    axes: matplotlib.axes.Axes, stem: Path, formats: Sequence[str], painter: _Painter
) -> tuple[list[Path], tuple[int, int]]:
    """Save the figure of ``axes`` in each format; returns the paths and the PNG's pixel size."""
    figure = axes.figure
    while not isinstance(figure, Figure):  # a SubFigure: save its root figure
        figure = figure.figure
    paths = [stem.with_suffix(f".{fmt}") for fmt in formats]
    painter.save(figure, list(zip(paths, formats, strict=True)), styled=True)
    width, height = figure.get_size_inches() * DPI
    return paths, (round(width), round(height))


def _write(path: Path, text: str, written: list[Path]) -> None:
    outputs.write_text(path, text, "--out")
    written.append(path)


_TASK_FIELD_HEADINGS = {
    "integer": "{name} per episode (mean ± s.e. over trials)",
    "number": "{name} per episode (mean ± s.e. over trials)",
    "boolean": "{name} (share of episodes, mean ± s.e. over trials)",
    "string": "{name} (most common)",
}


_STEP_FIELD_HEADINGS = {
    "integer": "{name} per step (mean ± s.e. over trials)",
    "number": "{name} per step (mean ± s.e. over trials)",
    "boolean": "{name} (share of steps, mean ± s.e. over trials)",
    "string": "{name} (most common, of steps)",
}


def _task_field_cells(
    run: loading.Run, name: str, kind: str, frame: pd.DataFrame | None = None, unit: str = "episode",
) -> tuple[str, dict[str, float | int | str]]:
    """One task's own ``/episode`` field of one run (or, with ``frame`` its steps and ``unit``
    ``step``, a ``/transition`` field), for the runs table: a number or boolean as its mean per
    episode (step), averaged over the trials (mean ± s.e., n = the trials that logged it; a
    boolean's mean is the share of episodes where it was true); a string as its most frequent
    value with the episodes (steps) that had it. Markdown cell, CSV columns."""
    frame = run.episodes if frame is None else frame
    logged = frame[["trial", name]].dropna() if name in frame else pd.DataFrame(columns=["trial", name])
    if kind == "string":
        counts = logged[name].astype(str).value_counts(sort=False)
        if counts.empty:
            return "—", {f"{name}_most_common": "", f"{name}_most_common_{unit}s": 0, f"{name}_{unit}s": 0}
        top = min(counts.items(), key=lambda kv: (-kv[1], kv[0]))  # ties: the first in sort order
        return f"{top[0]} ({top[1]} of {len(logged)} {unit}s)", {
            f"{name}_most_common": top[0], f"{name}_most_common_{unit}s": int(top[1]), f"{name}_{unit}s": len(logged),
        }
    per_trial = logged.astype({name: float}).groupby("trial")[name].mean() if not logged.empty else pd.Series(dtype=float)
    mean, _, se = stats.mean_std_se(list(per_trial.values))
    cell = "—" if per_trial.empty else f"{plus_minus(mean, se, 2)} (n = {len(per_trial)})"
    return cell, {f"{name}_per_{unit}_mean": mean, f"{name}_per_{unit}_se": se, f"{name}_trials": len(per_trial)}


def runs_table(runs: Sequence[loading.Run]) -> Table:
    """Every run found: trials, length, queries and return per trial; then the tasks' own
    ``/episode`` fields (``TaskSpec.episode_fields``) and ``/transition`` fields
    (``TaskSpec.step_fields``) where some run logged them."""
    rows = []
    data = []
    own: dict[str, str] = {}
    own_steps: dict[str, str] = {}
    for run in runs:
        for name, kind in run.task_fields:
            own.setdefault(name, kind)
        for name, kind in run.step_fields:
            own_steps.setdefault(name, kind)
    for run in runs:
        if run.key.kind == "accuracy":
            length = f"{run.samples} answers per prefix"
            queries = f"{len(run.queries)} (probe)"
            ret = "—"
            q_mean = r_mean = q_se = r_se = float("nan")
        else:
            length = f"{run.episodes_per_trial} episodes"
            q_mean, _, q_se = stats.mean_std_se(list(run.total_per_trial("queries").values()))
            r_mean, _, r_se = stats.mean_std_se(list(run.total_per_trial("return").values()))
            queries = plus_minus(q_mean, q_se, 1)
            ret = plus_minus(r_mean, r_se, 1)
        cells: list[str] = []
        columns: dict[str, float | int | str] = {}
        for name, kind in own.items():
            cell, values = _task_field_cells(run, name, kind) if run.key.kind != "accuracy" else ("—", {})
            cells.append(cell)
            columns.update(values)
        for name, kind in own_steps.items():
            steps = run.steps if run.steps is not None else pd.DataFrame(columns=["trial"])
            cell, values = _task_field_cells(run, name, kind, steps, "step")
            cells.append(cell)
            columns.update(values)
        rows.append(
            (run.key.name, str(len(run.trials)), length, str(run.transitions), queries, ret, *cells)
        )
        data.append(
            {
                "run": run.key.name,
                **run.key.columns(),
                "trials": len(run.trials),
                "episodes_per_trial": run.episodes_per_trial,
                "transitions": run.transitions,
                "queries_per_trial_mean": q_mean,
                "queries_per_trial_se": q_se,
                "return_per_trial_mean": r_mean,
                "return_per_trial_se": r_se,
                **columns,
            }
        )
    return Table(
        "Runs in these logs",
        (
            "run",
            "trials",
            "length",
            "transitions",
            "queries per trial (mean ± s.e.)",
            "return per trial (mean ± s.e.)",
            *(_TASK_FIELD_HEADINGS[kind].format(name=name) for name, kind in own.items()),
            *(_STEP_FIELD_HEADINGS[kind].format(name=name) for name, kind in own_steps.items()),
        ),
        tuple(rows),
        pd.DataFrame(data),
    )


_ROLE_ORDER = {"task": 0, "provider": 1, "policy": 2, "executor": 3}


def parts_table(runs: Sequence[loading.Run]) -> Table:
    """Which distribution and version made the runs' tasks, providers, policies and executors
    (each log's ``parts`` metadata): one row per part, with the runs it made; runs whose logs
    do not name their parts (made before they were logged) counted on a row of their own."""
    counts: dict[tuple[str, str, str, str], int] = {}
    unnamed = 0
    for run in runs:
        if not run.parts:
            unnamed += 1
        for role, part in run.parts.items():
            key = (role, part.get("name", ""), part.get("distribution", "unknown"), part.get("version", "unknown"))
            counts[key] = counts.get(key, 0) + 1
    ordered = sorted(counts.items(), key=lambda kv: (_ROLE_ORDER.get(kv[0][0], 9), *kv[0]))
    rows = [(role, name or "—", distribution, version, str(n)) for (role, name, distribution, version), n in ordered]
    if unnamed:
        rows.append(("(not logged)", "—", "—", "—", str(unnamed)))
    data = pd.DataFrame(
        [{"part": r[0], "name": r[1] if r[1] != "—" else "", "distribution": r[2], "version": r[3], "runs": int(r[4])} for r in rows],
        columns=["part", "name", "distribution", "version", "runs"],
    )
    return Table("Parts of these runs: distribution and version", ("part", "name", "distribution", "version", "runs"), tuple(rows), data)


def missing_plugin_notes(runs: Sequence[loading.Run]) -> tuple[str, ...]:
    """One line per logged task that no installed distribution registers: the plugin
    distribution its logs name (and the command that installs it), so that a report of its
    logs says why its suite items are not listed."""
    from lagrseq.registry import TASKS

    made_by: dict[str, set[str]] = {}
    for run in runs:
        if TASKS.find(run.key.task) is None:
            part = run.parts.get("task", {})
            made_by.setdefault(run.key.task, set()).add(part.get("distribution", ""))
    lines = []
    for task, distributions in sorted(made_by.items()):
        named = sorted(d for d in distributions if d and d not in ("unknown", "lagrseq"))
        if "lagrseq" in distributions and not named:
            lines.append(f"task {task!r} was a built-in task of the lagrseq that made its logs, and this one has none of that name: its suite items cannot be listed")
        elif named:
            lines.append(
                f"the suite of task {task!r} comes from plugin distribution {' or '.join(named)}, which is not "
                f"installed: pip install {' '.join(named)}, then replay again to make its items"
            )
        else:
            lines.append(
                f"task {task!r} is not installed and its logs do not name the plugin distribution that made it: "
                "install that plugin, then replay again to make its suite's items"
            )
    return tuple(lines)


def report_title(runs: Sequence[loading.Run], suite: Suite) -> str:
    """The report's heading: the paper's where its suite or runs are of the paper's tasks, else
    one naming the logged tasks (a plugin's runs alone are no rebuild of the paper)."""
    from lagrseq.suite import load_suite, suite_tasks

    paper = suite_tasks(load_suite())
    if paper & ({run.key.task for run in runs} | suite_tasks(suite)):
        return PAPER_TITLE
    tasks = sorted({run.key.task for run in runs}) or ["no task"]
    return f"lagrseq: runs of {', '.join(tasks)}, rebuilt from MCAP logs"


PAPER_TITLE = "LaGR-SEQ: the paper's figures and tables, rebuilt from MCAP logs"


def replay(
    roots: Sequence[str | Path],
    out: str | Path,
    formats: Sequence[str] = ("png",),
    suite: Suite | None = None,
    provider: str | None = None,
    unavailable: Mapping[str, str] | None = None,
    price: costs.Price | None = None,
    produced_by: str = "lagrseq replay",
    jobs: int | None = None,
    sections: Sequence[tuple[str, Table, Figure | None]] = (),
    failed: Mapping[str, ItemFailure] | None = None,
    problems: Mapping[str, ItemFailure] | None = None,
) -> Report:
    """Rebuild the suite's items that ``roots`` cover into ``out`` (see the module docstring).

    ``suite`` None: the suites of the logged tasks (:func:`lagrseq.suite.logged_tasks_suite`:
    the paper's when a log is of one of its tasks, and each logged task's own); a suite none of
    whose tasks the logs hold is left out with one line (``Report.notes``), not item by item.
    ``provider`` restricts the suite's default-provider runs to one provider; ``unavailable``
    (provider spec -> reason) lets ``lagrseq reproduce`` say why an item was not run; ``price``
    re-costs queries from their token usage; ``jobs``: processes that read the logs (see
    :func:`lagrseq.analysis.loading.load`; the output does not depend on it); ``sections``:
    report sections made from something other than the logs (``lagrseq reproduce``'s "open
    models", from recorded answers), as (stem, table, figure or None), written after the tables;
    ``failed`` (item id -> :class:`~lagrseq.analysis.ItemFailure`): items whose runs failed
    (``lagrseq reproduce``), shown as FAILED on the index and the scoreboard with their reason and
    the command that reruns them, and not made from what their runs left; ``problems``: other
    failures to list (its suite audits), with the same fields.
    """
    out = Path(out)
    formats = _checked_formats(formats, out)
    jobs = loading.default_jobs() if jobs is None else jobs
    # the figures' artists are many small objects too (see loading.no_cycle_collection)
    with contextlib.ExitStack() as stack, loading.no_cycle_collection():
        stack.enter_context(outputs.outputs(out))  # every file of the report inside OUT
        painter = _Painter(None)
        logs = loading.load(roots, jobs, _painter_starter(painter, stack, jobs))
        if not logs.runs and not failed and not problems:  # with failures: a report that lists them
            detail = f" ({'; '.join(logs.warnings)})" if logs.warnings else ""
            raise LogError(f"no complete lagrseq trial logs under {', '.join(map(str, roots))}{detail}")
        failed = dict(failed or {})
        problems = dict(problems or {})
        notes: tuple[str, ...] = ()
        if suite is None:
            suite, notes = logged_tasks_suite({run.key.task for run in logs.runs})
        notes += missing_plugin_notes(logs.runs)
        reports, extra, board, written = _make(logs, suite, out, formats, provider, unavailable, price, sections, painter, failed)
        tables = findings.report_tables(((t, md) for r in reports for t, md, _csv in r.tables), extra)
        _overview(tables, out, painter, written)
        painter.wait()
    shown = dataclasses.replace(logs, warnings=tuple(report_warnings(logs.warnings, roots)))
    title = report_title(logs.runs, suite)
    shown_board = board if board.rows or title == PAPER_TITLE else None  # no empty scoreboard atop a plugin's report
    _write(out / findings.PAGE, findings.page(board, tables, produced_by), written)
    answer = findings.headline(board, len(findings.studies(tables))) if title == PAPER_TITLE else []
    _write(out / "index.html", _index_html(reports, extra, shown, produced_by, shown_board, problems, notes, title, answer), written)
    _write(out / "index.md", _index_markdown(reports, extra, shown, produced_by, shown_board, problems, notes, title, answer), written)
    _drop_stale(out, written)
    return Report(out, logs, reports, written, {r.item.id: r.failure for r in reports if r.failure is not None}, problems, notes)


def _checked_formats(formats: Sequence[str], out: Path) -> list[str]:
    """The figure formats to write, png first, once they and the index files under ``out`` are checked."""
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise UsageError(f"unknown figure format {bad[0]!r}; expected some of {', '.join(FORMATS)}")
    shown = ["png", *[f for f in FORMATS if f in formats and f != "png"]]
    for name in ("index.html", "index.md", MANIFEST):  # a link, folder or FIFO there: refused before the logs are read
        outputs.check(out / name, "--out")
    return shown


def _painter_starter(painter: _Painter, stack: contextlib.ExitStack, jobs: int) -> Callable[[int], None]:
    """The callback that starts the figures' process once :func:`loading.load` knows the logs' count."""

    def found(count: int) -> None:
        # Where the logs are read in worker processes, one more draws the figures while this
        # one makes the next item (one: each process that draws pays importing matplotlib,
        # about 1 s, which it does while the logs are read).
        if loading.parallel(count, jobs):
            painter.pool = stack.enter_context(loading.worker_pool(1))
            painter.pending.append((painter.pool.submit(figures.ready), []))

    return found


def _overview(tables: Sequence[tuple[str, Table]], out: Path, painter: _Painter, written: list[Path]) -> None:
    """The overview figure of the report's frontier, where its tables hold one."""
    if (shown_frontier := findings.overview_table(tables)) is not None:
        with matplotlib.rc_context(_RC):  # type: ignore[arg-type]
            painter.save(findings.overview_axes(*shown_frontier).figure, [(out / findings.OVERVIEW, "png")], styled=True)
        written.append(out / findings.OVERVIEW)


def report_warnings(warnings: Sequence[str], roots: Sequence[str | Path]) -> list[str]:
    """``warnings`` as a report file shows them: every absolute spelling of a folder (or file)
    replay was given replaced by that folder as the user typed it when it is relative, else by its
    name, so that a report's bytes do not depend on where its logs sat."""
    spellings: dict[str, str] = {}
    for root in roots:
        given = Path(root).expanduser()
        base = given if given.is_dir() or not given.suffix else given.parent
        name = base.as_posix() if not base.is_absolute() else (base.name or "logs")
        for absolute in {str(base.absolute()), str(base.resolve())}:
            spellings.setdefault(absolute, name)
    cwd = str(Path.cwd())
    shown = []
    for text in warnings:
        for absolute in sorted(spellings, key=len, reverse=True):
            text = text.replace(absolute, spellings[absolute])
        shown.append(text.replace(cwd + "/", ""))
    return shown


def _make(
    logs: loading.Logs,
    suite: Suite,
    out: Path,
    formats: Sequence[str],
    provider: str | None,
    unavailable: Mapping[str, str] | None,
    price: costs.Price | None,
    sections: Sequence[tuple[str, Table, Figure | None]],
    painter: _Painter,
    failed: Mapping[str, ItemFailure] | None = None,
) -> tuple[list[ItemReport], list[tuple[str, Table]], Table, list[Path]]:
    """Every item, table and figure of the report (the figures through ``painter``)."""
    suite = with_logged_authors_runs(suite, logs.runs)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    (out / "tables").mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    with matplotlib.rc_context(_RC):  # type: ignore[arg-type]
        reports = [
            _item_report(item, logs, suite, out, formats, provider, unavailable, price, painter, failed, written)
            for item in suite.items
        ]
    extra = _extra_tables(logs, price, sections, out, painter, written)
    audits = audit.build(logs.runs)
    board = scoreboard.build(
        [(r.item, r.matched) for r in reports if r.made], audits,
        failed=[(r.item, r.failure) for r in reports if r.failure is not None],
    )
    _write(out / "scoreboard.md", to_markdown(board), written)
    _write(out / "tables" / "scoreboard.csv", to_csv(board.data), written)
    testable = scoreboard.testability(board)  # which rows can read reproduced at the paper's precision
    _write(out / "tables" / "scoreboard-testability.md", to_markdown(testable), written)
    _write(out / "tables" / "scoreboard-testability.csv", to_csv(testable.data), written)
    for made in audits:  # lagrseq audit runs in these logs: what each deviation does (and its interaction runs)
        for stem, table, fig in audit.outputs(made):
            _write_table(out, stem, table, written)
            path = out / "figures" / f"{stem}.png"
            painter.save(fig, [(path, "png")], styled=False)
            written.append(path)
            extra.append((stem, table))
    return reports, extra, board, written


def _item_report(
    item: Item,
    logs: loading.Logs,
    suite: Suite,
    out: Path,
    formats: Sequence[str],
    provider: str | None,
    unavailable: Mapping[str, str] | None,
    price: costs.Price | None,
    painter: _Painter,
    failed: Mapping[str, ItemFailure] | None,
    written: list[Path],
) -> ItemReport:
    """One item's report, its figure, figure data, animation and tables written (the figure through ``painter``)."""
    matched = items.match(
        item, logs.runs, suite.provider, provider, dict(unavailable or {})
    )
    report = ItemReport(item, matched, failure=(failed or {}).get(item.id))
    if not report.made:
        return report
    built = items.build(item, matched, price, logs.runs)
    report.method = built.method
    if built.axes is not None:
        paths, report.figure_size = _save_figure(
            built.axes, out / "figures" / item.id, formats, painter
        )
        written += paths
        report.figure = f"figures/{item.id}.png"
        report.figure_files = [p.relative_to(out).as_posix() for p in paths]
    if built.figure_data is not None:
        _write(out / "figures" / f"{item.id}.csv", to_csv(built.figure_data), written)
        report.figure_data = f"figures/{item.id}.csv"
    _arm_animation(report, out, written)
    for stem, table in built.tables:
        _write_table(out, stem, table, written)
        report.tables.append((table, f"tables/{stem}.md", f"tables/{stem}.csv"))
    return report


def _extra_tables(
    logs: loading.Logs,
    price: costs.Price | None,
    sections: Sequence[tuple[str, Table, Figure | None]],
    out: Path,
    painter: _Painter,
    written: list[Path],
) -> list[tuple[str, Table]]:
    """The tables after the items (costs, runs, parts, then ``sections``), written with the sections' figures."""
    extra = [
        ("costs-by-run", costs.by_run(logs.runs, price)),
        ("costs-by-method", costs.by_method(logs.runs, price)),
        ("runs", runs_table(logs.runs)),
        ("parts", parts_table(logs.runs)),
    ]
    for stem, table, section_figure in sections:
        if section_figure is not None:
            path = out / "figures" / f"{stem}.png"
            painter.save(section_figure, [(path, "png")], styled=False)
            written.append(path)
        extra.append((stem, table))
    for stem, table in extra:
        _write_table(out, stem, table, written)
    return extra


def _write_table(out: Path, stem: str, table: Table, written: list[Path]) -> None:
    """``table`` as ``tables/<stem>.md`` and ``tables/<stem>.csv`` under ``out``."""
    _write(out / "tables" / f"{stem}.md", to_markdown(table), written)
    _write(out / "tables" / f"{stem}.csv", to_csv(table.data), written)


MANIFEST = ".lagrseq-report"
"""The files the last replay into a folder wrote, one a line: the SHA-256 of what was written, two
spaces and the relative path (``sha256sum``'s format). The next replay removes those it does not
write again, so a report never keeps figures or tables of items the latest run did not make; a
file is removed only while it still holds the bytes recorded (files replay never wrote, and
files changed since, are left alone, whatever the manifest lists)."""

_OWN = ("figures", "tables")


def _drop_stale(out: Path, written: list[Path]) -> None:
    """Remove what an earlier replay into ``out`` wrote and this one did not; write the manifest.

    The earlier replay's files are those its manifest lists with the SHA-256 the file still has;
    a folder without a manifest loses nothing."""
    now = {p.relative_to(out).as_posix(): outputs.file_digest(p) for p in written}
    for name, digest in sorted(_manifest(out / MANIFEST).items()):
        path = out / name
        # only plain files directly under the report's own folders, still as replay wrote them:
        # a hand-edited manifest cannot make replay delete anything else
        if (
            name not in now
            and ".." not in Path(name).parts
            and len(Path(name).parts) <= 2
            and (len(Path(name).parts) == 1 or Path(name).parts[0] in _OWN)
            and outputs.file_digest(path) == digest
        ):
            path.unlink()
    outputs.write_text(out / MANIFEST, "".join(f"{digest}  {name}\n" for name, digest in sorted(now.items()) if digest), "--out")


def _manifest(path: Path) -> dict[str, str]:
    """A manifest's entries (relative path -> SHA-256); none when it is missing, unreadable or
    not a regular file (never read through a link or from a FIFO)."""
    from lagrseq.paths import open_input

    try:
        with open_input(path, "manifest") as handle:
            lines = handle.read(1 << 22).decode("utf-8").splitlines()
    except (LagrseqError, OSError, UnicodeDecodeError):
        return {}
    entries = {}
    for line in lines:
        digest, _, name = line.partition("  ")
        if len(digest) == 64 and all(c in "0123456789abcdef" for c in digest) and name:
            entries[name] = digest
    return entries


_FIGURED = {"open-models", "open-models-temperature"}
"""Sections of ``replay(sections=...)`` drawn with a figure (the "open models" item)."""


def _arm_animation(report: ItemReport, out: Path, written: list[Path]) -> None:
    """Arm items: a GIF of the last solved episode of the last trial of the item's first arm run."""
    from lagrseq.analysis.arm_gif import episode_gif
    from lagrseq.registry import TASKS

    for m in report.matched:
        task = TASKS.find(str(m.run.config.get("task", {}).get("name"))) if m.run is not None else None
        if m.run is None or not m.run.paths or task is None or not task.renders:  # the arm's episodes
            continue
        path = out / "figures" / f"{report.item.id}-arm.gif"
        shown = episode_gif(m.run.paths[-1], path)
        if shown is not None:
            written.append(path)
            report.animation = f"figures/{report.item.id}-arm.gif"
            report.animation_note = f"The arm ({m.label}, trial {m.run.trials[-1]}): {shown}, from /view/arm."
            return


def with_logged_authors_runs(suite: Suite, runs: Sequence[loading.Run]) -> Suite:
    """The suite with a recorded-GPT line on every item the logged runs on the authors' answers
    cover (``reproduce --authors-caches``), found from the logs alone by their provider."""
    covers: dict[str, set[tuple[str, int]]] = {}
    for run in runs:
        if is_authors_provider(run.key.provider):
            task = run.config.get("task", {})
            size = task.get("stack_size", 0) if isinstance(task, Mapping) else 0
            covers.setdefault(run.key.provider, set()).add((run.key.task, int(size or 0)))
    if not covers:
        return suite
    provider = sorted(covers)[0]  # one store's runs (two output folders replayed together: the first)
    return with_recorded(suite, provider, covers[provider])


def _authors_hint(report: ItemReport) -> str:
    """The line saying how to add the recorded-GPT line, for a covered item that has none."""
    if not report.item.recorded or any(is_authors_provider(m.provider) for m in report.matched):
        return ""
    return AUTHORS_HINT


# ------------------------------------------------------------------------------------------
# index.html / index.md
# ------------------------------------------------------------------------------------------
_CSS = """
body { font-family: system-ui, sans-serif; max-width: 980px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 2em; border-bottom: 1px solid #ddd; }
img { max-width: 100%; height: auto; border: 1px solid #eee; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
caption { text-align: left; font-weight: 600; padding-bottom: 0.3em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }
th { background: #f4f4f4; }
.caption { color: #555; font-style: italic; } .how { color: #333; font-size: 0.92em; }
.missing, .warn { color: #a33; } .links { font-size: 0.85em; }
ul.how { font-size: 0.85em; color: #444; margin-top: 0; }
.status { font-size: 0.8em; padding: 0.1em 0.5em; border-radius: 0.6em; background: #eee; }
.status.failed { background: #a33; color: #fff; font-weight: 600; }
"""


def _shown_status(report: ItemReport) -> str:
    return "FAILED" if report.status == FAILED else report.status


def _failure_lines(reports: Sequence[ItemReport], problems: Mapping[str, ItemFailure]) -> list[str]:
    """One line per failed item and per other failure (a suite audit), for the page's top."""
    lines = [f"{r.item.id}: {r.not_run_line()}" for r in reports if r.failure is not None]
    return lines + [f"{key}: {failure.line()}" for key, failure in problems.items()]


def _summary_line(logs: loading.Logs) -> str:
    transitions = logs.messages.get("/transition", 0)
    queries = logs.messages.get("/query", 0)
    episodes = logs.messages.get("/episode", 0)
    line = (
        f"{logs.files} MCAP logs ({logs.bytes / 1e6:.1f} MB; {transitions} transitions, "
        f"{episodes} episodes, {queries} query records) in {len(logs.runs)} runs"
    )
    if logs.skipped:  # said only when there are some: the line is otherwise as it always was
        line += f", {logs.skipped} more skipped (see the warnings)"
    return line


def _how(report: ItemReport, produced_by: str) -> tuple[str, list[str]]:
    """How the item was made, and one line per run it was made from."""
    how = f"Made by `{produced_by}` from the MCAP logs alone. {report.method}"
    return how, [items.run_line(m) for m in report.matched if m.run is not None]


def _scoreboard_html(board: Table) -> list[str]:
    """The scoreboard at the top of the page: a table whose last column links the explanation."""
    e = html.escape
    parts = ['<section id="scoreboard">', f"<h2>{e(board.title)}</h2>"]
    if not board.rows:
        parts += ["<p>No run of these logs stands for a number the paper states.</p>", "</section>"]
        return parts
    parts.append("<table><thead><tr>" + "".join(f"<th>{e(c)}</th>" for c in board.columns) + "</tr></thead><tbody>")
    for row in board.rows:
        cells = [f"<td>{e(c)}</td>" for c in row[:-2]]
        outside = row[-2].startswith(("✗", "FAILED"))
        cells.append(f'<td class="{"missing" if outside else ""}">{e(row[-2])}</td>')
        link = row[-1].startswith("#")  # the audits' own text (scoreboard.Explain) is shown as it is
        cells.append(f'<td><a href="{e(row[-1])}">{e(row[-1].lstrip("#"))}</a></td>' if link else f"<td>{e(row[-1])}</td>")
        parts.append("<tr>" + "".join(cells) + "</tr>")
    parts += ["</tbody></table>", '<p class="links"><a href="scoreboard.md">Markdown</a> · <a href="tables/scoreboard.csv">CSV</a></p>', "</section>"]
    return parts


def _index_html(
    reports: Sequence[ItemReport],
    extra: Sequence[tuple[str, Table]],
    logs: loading.Logs,
    produced_by: str,
    board: Table | None = None,
    problems: Mapping[str, ItemFailure] | None = None,
    notes: Sequence[str] = (),
    title: str = PAPER_TITLE,
    answer: Sequence[str] = (),
) -> str:
    e = html.escape
    failures = _failure_lines(reports, problems or {})
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        f"<head><meta charset=\"utf-8\"><title>{'lagrseq: LaGR-SEQ results' if title == PAPER_TITLE else e(title)}</title>",
        f"<style>{_CSS}</style></head>",
        "<body>",
        f"<h1>{e(title)}</h1>",
        f"<p>{e(_summary_line(logs))}; lagrseq {e(__version__)}. Every number below was "
        f"computed offline from these logs by <code>{e(produced_by)}</code>.</p>",
        *(['<section id="answer">', *(f"<p>{findings.to_html(line)}</p>" for line in answer), "</section>"] if answer else []),
        *(f'<p class="missing">{e(note)}</p>' for note in notes),
        *(_scoreboard_html(board) if board is not None else []),
    ]
    if failures:
        parts += ['<section id="failures"><h2>Failed</h2><ul>', *(f'<li class="missing">{e(line)}</li>' for line in failures), "</ul></section>"]
    parts += _contents_html(reports, logs)
    for r in reports:
        parts += _item_html(r, produced_by)
    parts += _extra_html(extra)
    if logs.warnings:
        parts.append('<section id="warnings"><h2>Warnings</h2><ul>')
        parts += [f'<li class="warn">{e(w)}</li>' for w in logs.warnings]
        parts.append("</ul></section>")
    parts += ["</body>", "</html>"]
    return "\n".join(parts) + "\n"


def _contents_html(reports: Sequence[ItemReport], logs: loading.Logs) -> list[str]:
    """The index page's list of contents: each item with its status, then the tables after the items."""
    e = html.escape
    parts = ["<ul>"]
    for r in reports:
        status = f'<span class="status{" failed" if r.status == FAILED else ""}">{e(_shown_status(r))}</span>'
        parts.append(f'<li><a href="#{e(r.item.id)}">{e(r.item.title)}</a> {status}</li>')
    parts += ['<li><a href="#costs">LLM costs</a></li>', '<li><a href="#runs">Runs</a></li>', '<li><a href="#parts">Parts</a></li>']
    if logs.warnings:
        parts.append('<li><a href="#warnings">Warnings</a></li>')
    parts.append("</ul>")
    return parts


def _item_html(r: ItemReport, produced_by: str) -> list[str]:
    """The index page's section of one item: its figure, tables, how it was made and what is missing."""
    e = html.escape
    parts = [f'<section id="{e(r.item.id)}">']
    status = f'<span class="status{" failed" if r.status == FAILED else ""}">{e(_shown_status(r))}</span>'
    parts.append(f"<h2>{e(r.item.title)} {status}</h2>")
    if r.item.caption:
        parts.append(f'<p class="caption">Paper: {e(r.item.caption)}</p>')
    if not r.made:
        parts.append(f'<p class="missing">{e(r.not_run_line())}</p>')
        parts.append("</section>")
        return parts
    if r.figure:
        width, height = r.figure_size
        parts.append(
            f'<img src="{e(r.figure)}" alt="{e(r.item.title)}" width="{width}" height="{height}">'
        )
        links = [(f.rsplit(".", 1)[1].upper(), f) for f in r.figure_files]
        if r.figure_data:
            links.append(("data (CSV)", r.figure_data))
        parts.append(
            '<p class="links">'
            + " · ".join(f'<a href="{e(h)}">{e(t)}</a>' for t, h in links)
            + "</p>"
        )
    if r.animation:
        parts.append(f'<p><img src="{e(r.animation)}" alt="{e(r.animation_note)}"></p>')
        parts.append(f'<p class="how">{e(r.animation_note)}</p>')
    for table, md, csv in r.tables:
        parts.append(to_html(table, [("Markdown", md), ("CSV", csv)]))
    how, run_lines = _how(r, produced_by)
    parts.append(f'<p class="how">{e(how)} Runs:</p>')
    parts.append(
        '<ul class="how">' + "".join(f"<li>{e(line)}</li>" for line in run_lines) + "</ul>"
    )
    if r.item.note:
        parts.append(f'<p class="how">Note: {e(r.item.note)}</p>')
    if _authors_hint(r):
        parts.append(f'<p class="how">{e(_authors_hint(r))}</p>')
    for line in r.missing():
        parts.append(f'<p class="missing">Missing — {e(line)}</p>')
    parts.append("</section>")
    return parts


def _extra_html(extra: Sequence[tuple[str, Table]]) -> list[str]:
    """The index page's sections of the tables after the items (costs, runs, parts, audits, ...)."""
    e = html.escape
    parts = []
    for stem, table in extra:
        anchor = "costs" if stem == "costs-by-run" else ("runs" if stem == "runs" else stem)
        parts.append(f'<section id="{e(anchor)}">')
        if stem.startswith("audit-") or stem in _FIGURED:
            parts.append(f'<h2>{e(table.title)}</h2><img src="figures/{e(stem)}.png" alt="{e(table.title)}">')
        parts.append(
            to_html(table, [("Markdown", f"tables/{stem}.md"), ("CSV", f"tables/{stem}.csv")])
        )
        parts.append("</section>")
    return parts


def _index_markdown(
    reports: Sequence[ItemReport],
    extra: Sequence[tuple[str, Table]],
    logs: loading.Logs,
    produced_by: str,
    board: Table | None = None,
    problems: Mapping[str, ItemFailure] | None = None,
    notes: Sequence[str] = (),
    title: str = PAPER_TITLE,
    answer: Sequence[str] = (),
) -> str:
    failures = _failure_lines(reports, problems or {})
    lines = [
        f"# {title}",
        "",
        f"{_summary_line(logs)}; lagrseq {__version__}. Made offline from these logs by `{produced_by}`.",
        "",
        *([*(f"{line}  " for line in answer), ""] if answer else []),
        *(line for note in notes for line in (note, "")),
    ]
    if board is not None:
        lines += [to_markdown(board)]
    if failures:
        lines += ["## Failed", "", *(f"- {markdown_text(line)}" for line in failures), ""]
    for r in reports:
        lines += [f"## {markdown_text(r.item.title)} ({_shown_status(r)})", ""]
        if r.item.caption:
            lines += [f"*Paper: {markdown_text(r.item.caption)}*", ""]
        if not r.made:
            lines += [r.not_run_line(), ""]
            continue
        if r.figure:
            lines += [f"![{markdown_text(r.item.title)}]({r.figure})", ""]
        if r.animation:
            lines += [f"![{r.animation_note}]({r.animation})", "", r.animation_note, ""]
        for table, _md, _csv in r.tables:
            lines += [to_markdown(table)]
        how, run_lines = _how(r, produced_by)
        lines += [f"{how} Runs:", "", *(f"- {line}" for line in run_lines), ""]
        if r.item.note:
            lines += [f"Note: {markdown_text(r.item.note)}", ""]
        if _authors_hint(r):
            lines += [_authors_hint(r), ""]
        lines += [f"Missing — {line}  " for line in r.missing()]
        lines.append("")
    for stem, table in extra:
        if stem in _FIGURED:
            lines += [f"![{table.title}](figures/{stem}.png)", ""]
        lines += [to_markdown(table)]
    if logs.warnings:
        lines += ["## Warnings", "", *(f"- {markdown_text(w)}" for w in logs.warnings), ""]
    return "\n".join(lines).rstrip("\n") + "\n"
