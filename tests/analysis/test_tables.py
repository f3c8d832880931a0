"""Table text: fixed formats, escaping, stable bytes."""

from __future__ import annotations

import math

import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.analysis.tables import (
    Table,
    interval,
    number,
    plus_minus,
    to_csv,
    to_html,
    to_markdown,
)


def test_numbers_have_fixed_formats() -> None:
    assert number(126.0) == "126.00"
    assert number(3, 1) == "3"
    assert number(float("nan")) == "n/a" and number(None) == "n/a"
    assert plus_minus(126.0, 2.94) == "126.00 ± 2.94"
    assert plus_minus(5.0, math.nan) == "5.00"
    assert interval(1.0, 2.5) == "[1.00, 2.50]" and interval(math.nan, 1.0) == "n/a"


def test_markdown_and_html_escape_cells() -> None:
    table = Table("T <1>", ("a|b", "c"), (("x|y", "<b>"),), pd.DataFrame())
    md = to_markdown(table)
    assert md.splitlines()[2] == "| a\\|b | c |"
    assert "| x\\|y | &lt;b&gt; |" in md  # HTML in a cell is shown, never run
    assert md.startswith("### T &lt;1&gt;\n")
    page = to_html(table, [("CSV", "t.csv")])
    assert "&lt;b&gt;" in page and "<caption>T &lt;1&gt;</caption>" in page
    assert '<a href="t.csv">CSV</a>' in page


def test_markdown_cells_show_control_characters_and_line_breaks() -> None:
    table = Table("t", ("a",), (("x\x1b]0;owned\x07\ny",),), pd.DataFrame())
    row = to_markdown(table).splitlines()[-1]
    assert "\x1b" not in row and "\x07" not in row and row == "| x\\x1b]0;owned\\x07\\ny |"


def test_csv_cells_that_a_spreadsheet_would_run_are_neutralised() -> None:
    frame = pd.DataFrame({"title": ["=HYPERLINK(\"x\")", "+1+cmd", "@SUM(A1)", "-2+3", "\tx", "-", "-0.5", "ok"], "n": range(8)})
    cells = [row.split(",")[0] for row in to_csv(frame).splitlines()[1:]]
    assert cells == ['"\'=HYPERLINK(""x"")"', "'+1+cmd", "'@SUM(A1)", "'-2+3", "'\tx", "-", "-0.5", "ok"]


def test_csv_is_stable_text() -> None:
    frame = pd.DataFrame({"label": ["a", "b"], "mean": [1 / 3, 2.0], "n": [10, 10]})
    text = to_csv(frame)
    assert text == "label,mean,n\na,0.333333,10\nb,2,10\n"
    assert to_csv(frame.copy()) == text


def test_interval_bounds_are_rounded_outward() -> None:
    """0/56 has the exact upper bound 6.38%: at 0 decimals it prints 7, never 6; a lower bound
    rounds down; bounds already at the precision stay."""
    from lagrseq.analysis.tables import interval, outward

    assert interval(0.0, 6.38, 0) == "[0, 7]"
    assert interval(-24.21, 224.2, 1) == "[-24.3, 224.2]"
    assert interval(284.0, 290.0, 2) == "[284.00, 290.00]"
    assert outward(0.012345, 1234.5, significant=3) == ("0.0123", "1235")


@settings(max_examples=200, deadline=None)
@given(low=st.floats(-1e6, 1e6), width=st.floats(0, 1e6), digits=st.integers(0, 4))
def test_a_printed_interval_always_holds_the_computed_one(low: float, width: float, digits: int) -> None:
    from lagrseq.analysis.tables import outward

    high = low + width
    a, b = outward(low, high, digits)
    assert float(a) <= low + 1e-9 * max(1.0, abs(low)) and float(b) >= high - 1e-9 * max(1.0, abs(high))
    c, d = outward(low, high, significant=3)
    assert float(c) <= low + 1e-9 * max(1.0, abs(low)) and float(d) >= high - 1e-9 * max(1.0, abs(high))
