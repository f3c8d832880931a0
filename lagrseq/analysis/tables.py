"""Tables: a display form (strings, for Markdown and HTML) and a data form (a pandas frame, for
CSV), both with fixed formatting so that the same numbers always give the same bytes."""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass

import pandas as pd

from lagrseq.text import csv_cell, markdown_cell

CSV_FLOAT = "%.6g"


@dataclass(frozen=True)
class Table:
    """A table to show (``columns``/``rows`` of text) and the numbers behind it (``data``)."""

    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    data: pd.DataFrame


def number(value: float | int | None, digits: int = 2) -> str:
    """A number for display: fixed decimals, ``n/a`` for a missing value."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}f}"


def plus_minus(mean: float, se: float, digits: int = 2) -> str:
    """``mean ± se`` as the paper writes it; just the mean when the error is unknown."""
    if math.isnan(se):
        return number(mean, digits)
    return f"{number(mean, digits)} ± {number(se, digits)}"


def round_down(value: float, digits: int) -> float:
    """``value`` rounded down at ``digits`` decimals (a lower bound printed so never moves inward);
    a value already at that precision stays as it is."""
    scaled = value * 10**digits
    return math.floor(scaled + 1e-9 * max(1.0, abs(scaled))) / 10**digits


def round_up(value: float, digits: int) -> float:
    """``value`` rounded up at ``digits`` decimals (an upper bound: 6.38% at 0 decimals is 7)."""
    scaled = value * 10**digits
    return math.ceil(scaled - 1e-9 * max(1.0, abs(scaled))) / 10**digits


def _decimals(value: float, significant: int) -> int:
    """The decimals that show ``value`` with ``significant`` significant digits (0 to 12)."""
    if value == 0 or not math.isfinite(value):
        return max(0, significant - 1)
    return min(12, max(0, significant - 1 - math.floor(math.log10(abs(value)))))


def outward(low: float, high: float, digits: int | None = None, significant: int | None = None) -> tuple[str, str]:
    """The bounds of an interval as text, rounded outward (the low one down, the high one up) at
    ``digits`` decimals or, with ``significant``, at that many significant digits of each bound:
    a printed interval never holds less than the computed one."""
    if significant is not None:
        lo_digits, hi_digits = _decimals(low, significant), _decimals(high, significant)
    else:
        lo_digits = hi_digits = 2 if digits is None else digits
    return f"{round_down(low, lo_digits):.{lo_digits}f}", f"{round_up(high, hi_digits):.{hi_digits}f}"


def interval(low: float, high: float, digits: int = 2) -> str:
    """``[low, high]`` rounded outward at ``digits`` decimals; ``n/a`` without bounds."""
    if math.isnan(low) or math.isnan(high):
        return "n/a"
    a, b = outward(low, high, digits)
    return f"[{a}, {b}]"


def _cell(text: str) -> str:
    return markdown_cell(text)


def to_markdown(table: Table) -> str:
    """A GitHub-flavoured Markdown table under a heading (every cell escaped:
    :func:`lagrseq.text.markdown_cell`)."""
    lines = [f"### {_cell(table.title)}", "", "| " + " | ".join(_cell(c) for c in table.columns) + " |"]
    lines.append("|" + "|".join(" --- " for _ in table.columns) + "|")
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in table.rows]
    return "\n".join(lines) + "\n"


def to_csv(frame: pd.DataFrame) -> str:
    """CSV with ``\\n`` line ends and floats written with 6 significant digits; a text cell a
    spreadsheet would run as a formula is neutralised (:func:`lagrseq.text.csv_cell`)."""
    text_columns = [c for c in frame.columns if pd.api.types.is_object_dtype(frame[c]) or pd.api.types.is_string_dtype(frame[c])]
    if text_columns:
        frame = frame.copy()
        for column in text_columns:
            frame[column] = frame[column].map(csv_cell)
    return frame.to_csv(index=False, float_format=CSV_FLOAT, lineterminator="\n")


def to_html(table: Table, links: Sequence[tuple[str, str]] = ()) -> str:
    """An HTML table (escaped), with optional links (text, href) under it."""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in table.columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in table.rows
    )
    out = f"<table>\n<caption>{html.escape(table.title)}</caption>\n<thead><tr>{head}</tr></thead>\n<tbody>{body}</tbody>\n</table>\n"
    if links:
        anchors = " · ".join(f'<a href="{html.escape(h)}">{html.escape(t)}</a>' for t, h in links)
        out += f'<p class="links">{anchors}</p>\n'
    return out
