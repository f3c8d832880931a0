"""Two reports side by side: do they agree by their verdicts?

Bytes are identical only on one machine with one build of torch and its BLAS; across machines a
DQN run's numbers differ and a report agrees with another by its verdicts (DESIGN section 12).
:func:`read_report` reads what ``lagrseq replay --out`` and ``lagrseq reproduce`` write to a
report folder (``tables/scoreboard.csv`` and ``tables/frontier-*.csv``) and :func:`compare` pairs
their rows:

- each scoreboard row (paper item, quantity, lagrseq source): lagrseq's mean with its 95%
  t-interval and n in each report, and its verdict against the paper;
- each frontier point (panel, policy, knobs), four rows: steps to the first solve against always
  (non-inferiority), the same against random at the point's matched query rate, episodes solved
  against always, and queries per trial with whether the point is credited.

A pair *agrees* when both verdicts are the same text and *flips* when they differ (any change,
``reproduced`` to ``inconclusive`` included); a row in one report only is listed as such and is
no flip. Intervals *overlap* when they share a point; an interval missing from either side is
``n/a``. A random policy's knobs are its query rate, which follows the point it is matched to and
so differs between machines: points of one policy that share no knobs are paired in their order.

Files in, dataclasses out: nothing here writes a file (the command line writes ``--csv`` and
``--markdown``).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lagrseq.errors import UsageError
from lagrseq.paths import open_input
from lagrseq.text import csv_cell, cut, markdown_cell, shown

MAX_CSV_BYTES = 16 * 2**20
"""The largest table read (a reference report's largest is about 20 KB)."""
MAX_ROWS = 100_000

AGREES = "agrees"
FLIPS = "flips"
ONLY_A = "only in A"
ONLY_B = "only in B"

SCOREBOARD = "scoreboard"
SCOREBOARD_COLUMNS = ("item", "title", "what", "source", "mean", "ci_low", "ci_high", "trials", "verdict")
FRONTIER_COLUMNS = ("policy", "knobs", "trials", "vs_always", "vs_matched_random", "credited", "vs_always_episodes_solved",
                    "steps_to_solve_mean", "steps_to_solve_low", "steps_to_solve_high",
                    "episodes_solved_mean", "episodes_solved_low", "episodes_solved_high",
                    "queries_mean", "queries_low", "queries_high")
FRONTIER_QUANTITIES = (
    # (quantity shown, the value's columns, the verdict's column)
    ("steps to first solve vs always", "steps_to_solve", "vs_always"),
    ("steps to first solve vs random at the matched rate", "steps_to_solve", "vs_matched_random"),
    ("episodes solved vs always", "episodes_solved", "vs_always_episodes_solved"),
    ("queries per trial: credited", "queries", "credited"),
)


@dataclass(frozen=True)
class Value:
    """One report's number: mean, 95% interval (NaN: none), n, and its verdict."""

    mean: float
    low: float
    high: float
    n: int
    verdict: str

    def text(self) -> str:
        if math.isnan(self.mean):
            return f"n/a (n={self.n})"
        if math.isnan(self.low) or math.isnan(self.high):
            return f"{self.mean:.4g} (n={self.n}; no interval)"
        return f"{self.mean:.4g} [{self.low:.4g}, {self.high:.4g}] (n={self.n})"


@dataclass(frozen=True)
class Entry:
    """One comparable row of a report: which table, which row, which quantity, its value."""

    table: str
    """``scoreboard`` or the frontier table's name (``frontier-cube``)."""
    row: str
    quantity: str
    value: Value
    key: tuple[str, ...]


@dataclass(frozen=True)
class Report:
    """A report folder's comparable rows, in the order its tables hold them."""

    path: Path
    entries: tuple[Entry, ...]
    tables: tuple[str, ...]
    """The tables read: ``scoreboard``, ``frontier-...``."""


@dataclass(frozen=True)
class Row:
    """One row of the comparison; ``a`` or ``b`` is None for a row in one report only."""

    table: str
    row: str
    quantity: str
    a: Value | None
    b: Value | None

    @property
    def overlap(self) -> bool | None:
        """Whether the two 95% intervals share a point (None: a side or an interval is missing)."""
        if self.a is None or self.b is None:
            return None
        bounds = (self.a.low, self.a.high, self.b.low, self.b.high)
        if any(math.isnan(x) for x in bounds):
            return None
        return max(self.a.low, self.b.low) <= min(self.a.high, self.b.high)

    @property
    def status(self) -> str:
        if self.a is None:
            return ONLY_B
        if self.b is None:
            return ONLY_A
        return AGREES if self.a.verdict == self.b.verdict else FLIPS


@dataclass(frozen=True)
class Comparison:
    a: Report
    b: Report
    rows: tuple[Row, ...]

    def count(self, status: str) -> int:
        return sum(1 for r in self.rows if r.status == status)

    @property
    def flips(self) -> int:
        return self.count(FLIPS)

    def summary(self) -> str:
        paired = [r for r in self.rows if r.a is not None and r.b is not None]
        judged = [r for r in paired if r.overlap is not None]
        overlapping = sum(1 for r in judged if r.overlap)
        return (
            f"{len(self.rows)} rows: {self.count(AGREES)} agree, {self.flips} flip, {self.count(ONLY_A)} only in A, "
            f"{self.count(ONLY_B)} only in B; 95% intervals overlap in {overlapping} of {len(judged)} pairs with both intervals"
        )


# ------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------
def report_folder(path: Path) -> Path:
    """The report folder ``path`` names: itself, or ``path/reports`` for the output folder of
    ``reproduce`` or ``audit``. A missing folder, one that holds no report, and one whose
    ``tables`` is not a folder are refused."""
    if not path.exists():
        raise UsageError(f"report folder {shown(path)} does not exist; give a folder written by lagrseq replay --out or reproduce (OUT/reports)")
    if not path.is_dir():
        raise UsageError(f"{shown(path)} is a file, not a report folder; give a folder written by lagrseq replay --out or reproduce (OUT/reports)")
    for candidate in (path, path / "reports"):
        tables = candidate / "tables"
        if (tables.exists() or tables.is_symlink()) and not tables.is_dir():
            raise UsageError(f"{shown(tables)} is not a folder; the report is damaged: rewrite it (lagrseq replay RUNS --out DIR)")
        marks = [candidate / "index.md", candidate / "scoreboard.md", tables / "scoreboard.csv"]
        if any(m.exists() for m in marks) or any(tables.glob("frontier-*.csv")):
            return candidate
    raise UsageError(
        f"{shown(path)} is not a report folder: found no index.md, scoreboard.md, tables/scoreboard.csv or tables/frontier-*.csv in it or in "
        f"{shown(path / 'reports')}; give a folder written by lagrseq replay --out or reproduce (OUT/reports)"
    )


def _text(path: Path) -> str:
    """A table's text: a regular file (a FIFO, a device or a link to one is refused, never read),
    at most :data:`MAX_CSV_BYTES`, UTF-8 with or without a byte-order mark."""
    with open_input(path, "report table") as handle:
        data = handle.read(MAX_CSV_BYTES + 1)
    if len(data) > MAX_CSV_BYTES:
        raise UsageError(f"{shown(path)} is larger than any report table ({MAX_CSV_BYTES} bytes at most); is it a report's table?")
    return data.decode("utf-8-sig")


def _read_csv(path: Path, required: Sequence[str]) -> list[dict[str, str]]:
    """A table's rows, each a dict of its cells; any defect is one line naming the file."""
    try:
        reader = csv.DictReader(io.StringIO(_text(path), newline=""), strict=True)
        header = reader.fieldnames or []
        missing = [c for c in required if c not in header]
        if missing:
            raise UsageError(
                f"{shown(path)} is not a report table: its header lacks {', '.join(missing)}; "
                "rewrite the report with this version of lagrseq (lagrseq replay RUNS --out DIR)"
            )
        rows: list[dict[str, str]] = []
        for row in reader:
            if None in row or any(v is None for v in row.values()):
                raise UsageError(
                    f"{shown(path)} line {reader.line_num}: {len(header)} cells expected, found another count; "
                    "the table is damaged: rewrite the report (lagrseq replay RUNS --out DIR)"
                )
            rows.append(row)
            if len(rows) > MAX_ROWS:
                raise UsageError(f"{shown(path)} has more than {MAX_ROWS} rows; is it a report's table?")
        return rows
    except UnicodeDecodeError as exc:
        raise UsageError(f"{shown(path)} is not UTF-8 text (byte {exc.start}); the table is damaged: rewrite the report") from None
    except csv.Error as exc:
        raise UsageError(f"{shown(path)} is not a readable CSV table ({shown(exc)}); the table is damaged: rewrite the report") from None
    except OSError as exc:
        raise UsageError(f"{shown(path)} cannot be read ({exc.strerror or exc}); check the path and its permissions") from None


def _number(path: Path, row: dict[str, str], column: str) -> float:
    text = row[column].strip()
    if text == "" or text.lower() in ("nan", "n/a"):
        return math.nan
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    else:
        if math.isfinite(value):
            return value
    raise UsageError(
        f"{shown(path)}: column {column} holds {shown(text[:40])!r} where a finite number was expected; the table is damaged: rewrite the report"
    )


def _count(path: Path, row: dict[str, str], column: str) -> int:
    value = _number(path, row, column)
    if math.isnan(value) or value < 0 or value != int(value):
        raise UsageError(f"{shown(path)}: column {column} holds {shown(row[column][:40])!r} where a count was expected; the table is damaged: rewrite the report")
    return int(value)


def _verdict(text: str) -> str:
    """A verdict cell as compared: the CSV's booleans as yes/no, the rest as written."""
    text = text.strip()
    return {"True": "yes", "False": "no"}.get(text, text)


def _with_occurrence(keys: list[tuple[str, ...]]) -> list[tuple[str, ...]]:
    """Keys made unique by their occurrence (a second row with one key gets ``#2``)."""
    seen: dict[tuple[str, ...], int] = {}
    out = []
    for key in keys:
        seen[key] = seen.get(key, 0) + 1
        out.append(key if seen[key] == 1 else (*key, f"#{seen[key]}"))
    return out


def _scoreboard(path: Path) -> list[Entry]:
    rows = _read_csv(path, SCOREBOARD_COLUMNS)
    keys = _with_occurrence([(SCOREBOARD, r["item"], r["what"], r["source"]) for r in rows])
    return [
        Entry(
            SCOREBOARD, f"{r['title']}: {r['what']} [{r['source']}]", "mean vs the paper",
            Value(_number(path, r, "mean"), _number(path, r, "ci_low"), _number(path, r, "ci_high"), _count(path, r, "trials"), _verdict(r["verdict"])),
            key,
        )
        for r, key in zip(rows, keys, strict=True)
    ]


def _frontier(path: Path) -> list[Entry]:
    table = path.stem
    rows = _read_csv(path, FRONTIER_COLUMNS)
    points = _with_occurrence([(table, r["policy"], r["knobs"]) for r in rows])
    out: list[Entry] = []
    for r, point in zip(rows, points, strict=True):
        name = r["policy"] + (f" ({r['knobs']})" if r["knobs"] else "")
        n = _count(path, r, "trials")
        for quantity, value, verdict in FRONTIER_QUANTITIES:
            if verdict == "vs_matched_random" and not r[verdict].strip():
                continue  # a point without a matched random comparison (never, always, oracle)
            out.append(Entry(
                table, name, quantity,
                Value(_number(path, r, f"{value}_mean"), _number(path, r, f"{value}_low"), _number(path, r, f"{value}_high"), n, _verdict(r[verdict])),
                (*point, quantity),
            ))
    return out


def read_report(path: Path) -> Report:
    """The comparable rows of the report folder ``path`` (or of ``path/reports``)."""
    folder = report_folder(Path(path))
    entries: list[Entry] = []
    tables: list[str] = []
    scoreboard = folder / "tables" / "scoreboard.csv"
    if scoreboard.exists() or scoreboard.is_symlink():  # not a file: refused in one line, never read
        entries += _scoreboard(scoreboard)
        tables.append(SCOREBOARD)
    for frontier in sorted((folder / "tables").glob("frontier-*.csv")):
        entries += _frontier(frontier)
        tables.append(frontier.stem)
    return Report(folder, tuple(entries), tuple(tables))


# ------------------------------------------------------------------------------------------
# Pairing
# ------------------------------------------------------------------------------------------
def _point(entry: Entry) -> tuple[str, str]:
    """A frontier entry's table and policy."""
    return entry.key[0], entry.key[1]


def compare(a: Report, b: Report) -> Comparison:
    """Every row of ``a`` beside the same row of ``b``, in ``a``'s order, then ``b``'s rows that
    ``a`` lacks. Frontier points of one policy whose knobs differ (a random point matched to
    another query rate) are paired in their order within the policy."""
    in_b = {e.key: e for e in b.entries}
    used: set[tuple[str, ...]] = set()
    pairs: list[tuple[Entry | None, Entry | None]] = []
    for entry in a.entries:
        other = in_b.get(entry.key)
        if other is not None:
            used.add(other.key)
        pairs.append((entry, other))
    # frontier points left on both sides: pair by policy, in order
    left_b: dict[tuple[str, str, str], list[Entry]] = {}
    for rest in b.entries:
        if rest.key not in used and rest.table != SCOREBOARD:
            left_b.setdefault((*_point(rest), rest.quantity), []).append(rest)
    for i, (alone, other) in enumerate(pairs):
        if other is None and alone is not None and alone.table != SCOREBOARD:
            waiting = left_b.get((*_point(alone), alone.quantity))
            if waiting:
                match = waiting.pop(0)
                used.add(match.key)
                pairs[i] = (alone, match)
    pairs += [(None, e) for e in b.entries if e.key not in used]
    rows = []
    for x, y in pairs:
        first = x if x is not None else y
        assert first is not None
        name = first.row
        if x is not None and y is not None and x.row != y.row:
            name = f"{x.row} / {y.row}"
        rows.append(Row(first.table, name, first.quantity, x.value if x else None, y.value if y else None))
    return Comparison(a, b, tuple(rows))


# ------------------------------------------------------------------------------------------
# Showing
# ------------------------------------------------------------------------------------------
COLUMNS = ("table", "row", "quantity", "A", "B", "intervals overlap", "verdict A", "verdict B", "status")


def _cells(row: Row) -> tuple[str, ...]:
    overlap = "n/a" if row.overlap is None else ("yes" if row.overlap else "no")
    return (
        row.table, row.row, row.quantity,
        row.a.text() if row.a else "-", row.b.text() if row.b else "-", overlap,
        row.a.verdict if row.a else "-", row.b.verdict if row.b else "-",
        row.status.upper() if row.status == FLIPS else row.status,
    )


def _shown(rows: Sequence[Row], differences_only: bool) -> list[Row]:
    return [r for r in rows if not differences_only or r.status != AGREES]


CELL_WIDTH = 80
"""The widest cell of the terminal table: a longer one is cut with an ellipsis (one long title
must not pad every row)."""


def to_text(comparison: Comparison, differences_only: bool = False) -> str:
    """A header naming both reports, one aligned plain-text table per report table (scoreboard,
    each frontier panel) and a summary line. Every piece of report text is shown, never run
    (:func:`lagrseq.text.shown`: keys blanked, controls escaped), and cut to :data:`CELL_WIDTH`."""
    shown_rows = _shown(comparison.rows, differences_only)
    columns = COLUMNS[1:]
    lines = [
        f"A: {shown(comparison.a.path)} ({len(comparison.a.entries)} rows from {_names(comparison.a.tables)})",
        f"B: {shown(comparison.b.path)} ({len(comparison.b.entries)} rows from {_names(comparison.b.tables)})",
    ]
    for table in dict.fromkeys(r.table for r in shown_rows):
        cells = [tuple(cut(shown(c), CELL_WIDTH) for c in _cells(r)[1:]) for r in shown_rows if r.table == table]
        widths = [max([len(c), *(len(row[i]) for row in cells)]) for i, c in enumerate(columns)]
        lines += [
            "",
            f"{cut(shown(table), CELL_WIDTH)}:",
            "  ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)).rstrip(),
            "  ".join("-" * w for w in widths),
        ]
        lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in cells]
    if differences_only and not shown_rows:
        lines += ["", "(every row agrees)"]
    lines += ["", comparison.summary()]
    return "\n".join(lines) + "\n"


def _names(tables: Sequence[str]) -> str:
    return cut(shown(", ".join(tables)), 4 * CELL_WIDTH) if tables else "no table"


def to_markdown(comparison: Comparison, differences_only: bool = False) -> str:
    """The comparison as a Markdown table (every cell escaped: :func:`lagrseq.text.markdown_cell`)."""
    lines = [
        f"### Two reports compared: A = {markdown_cell(comparison.a.path)}, B = {markdown_cell(comparison.b.path)}",
        "",
        "| " + " | ".join(COLUMNS) + " |",
        "| " + " | ".join("---" for _ in COLUMNS) + " |",
    ]
    lines += ["| " + " | ".join(markdown_cell(c) for c in _cells(r)) + " |" for r in _shown(comparison.rows, differences_only)]
    lines += ["", comparison.summary()]
    return "\n".join(lines) + "\n"


def to_csv(comparison: Comparison, differences_only: bool = False) -> str:
    """One line per row, with the numbers as numbers (empty where missing); a text cell a
    spreadsheet would run as a formula is neutralised (:func:`lagrseq.text.csv_cell`)."""
    def numbers(v: Value | None) -> list[object]:
        if v is None:
            return ["", "", "", "", ""]
        return [*("" if math.isnan(x) else f"{x:.6g}" for x in (v.mean, v.low, v.high)), str(v.n), csv_cell(v.verdict)]

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["table", "row", "quantity", "a_mean", "a_low", "a_high", "a_n", "a_verdict",
                     "b_mean", "b_low", "b_high", "b_n", "b_verdict", "intervals_overlap", "status"])
    for r in _shown(comparison.rows, differences_only):
        overlap = "" if r.overlap is None else str(r.overlap).lower()
        writer.writerow([csv_cell(r.table), csv_cell(r.row), r.quantity, *numbers(r.a), *numbers(r.b), overlap, r.status])
    return buffer.getvalue()
