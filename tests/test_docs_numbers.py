"""Every number the README and the docs state as a result is in the committed reports.

**What counts as a result section.** Text between the HTML comments ``<!-- results -->`` and
``<!-- /results -->`` (each alone on its line) in ``README.md`` and in every Markdown page under
``docs/`` (the reference report itself, ``docs/reference-report/``, is the source, not a page
checked against it). A page may have several such sections; an opening without its closing (or
the reverse) fails. Prose outside the fences (methods, commands, limits) is not checked: a
measured number belongs inside a fence, and the fence says "generated, look it up".

**What counts as a number.** After dropping fenced code blocks, inline code spans, link and image
targets (the ``(...)`` after ``]``) and HTML comments: every run of digits with an optional
decimal part and optional thousands commas (``1,000`` reads as ``1000``) that is not part of a
word (``Qwen2.5`` and ``1.5B`` are names, not numbers) and not followed by a decimal point and
digit. A trailing full stop ends a sentence, not a decimal part.

**Where it must be.** In the text of some file of a committed report (``.md``, ``.csv``,
``.html`` under a folder of ``reports/`` that holds an ``index.md``: ``reports/reference/``, and a
full-suite report beside it where one is committed; never the hand-written ``reports/README.md``),
read when the test runs (so a regenerated report is what the docs are checked against), as the same digits not preceded by a digit or a decimal point and not followed by a
digit or a decimal part: ``443.7`` is found in ``443.7 [434.0, 453.6]``, ``43.7`` is not.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
REPORTS = ROOT / "reports"
REPORT = REPORTS / "reference"
OPEN, CLOSE = "<!-- results -->", "<!-- /results -->"

pytestmark = pytest.mark.skipif(not REPORT.is_dir(), reason="no committed reference report (installed package)")

_NUMBER = re.compile(r"(?<![\w.,])\d{1,3}(?:,\d{3})+(?:\.\d+)?(?!\.?\w)|(?<![\w.,])\d+(?:\.\d+)?(?!\.?\w)")
_DROP = (
    re.compile(r"^```.*?^```", re.S | re.M),  # fenced code
    re.compile(r"`[^`\n]*`"),  # inline code
    re.compile(r"\]\([^)\s]*\)"),  # link and image targets
    re.compile(r"<!--.*?-->", re.S),  # comments (the fences themselves)
)


def result_sections(text: str) -> list[str]:
    """The text between each results fence pair; an unbalanced fence raises ValueError."""
    sections, inside, current = [], False, []
    for line in text.splitlines():
        if line.strip() == OPEN:
            if inside:
                raise ValueError(f"{OPEN} inside a results section")
            inside, current = True, []
        elif line.strip() == CLOSE:
            if not inside:
                raise ValueError(f"{CLOSE} without {OPEN}")
            inside = False
            sections.append("\n".join(current))
        elif inside:
            current.append(line)
    if inside:
        raise ValueError(f"{OPEN} without {CLOSE}")
    return sections


def numbers(section: str) -> list[str]:
    """The numbers a results section states (see the module docstring)."""
    for pattern in _DROP:
        section = pattern.sub(" ", section)
    return [token.replace(",", "") for token in _NUMBER.findall(section)]


def report_text(reports: Path = REPORTS) -> str:
    """The text of every committed report (each folder under ``reports`` with an index.md)."""
    folders = sorted(index.parent for index in reports.glob("*/index.md"))
    return "\n".join(
        path.read_text(encoding="utf-8", errors="replace")
        for folder in folders
        for path in sorted(folder.rglob("*"))
        if path.is_file() and path.suffix in {".md", ".csv", ".html"}
    )


def in_report(number: str, text: str) -> bool:
    return re.search(rf"(?<![\d.]){re.escape(number)}(?!\d|\.\d)", text) is not None


def pages(root: Path = ROOT) -> list[Path]:
    docs = root / "docs"
    return [root / "README.md", *sorted(p for p in docs.rglob("*.md") if "reference-report" not in p.relative_to(docs).parts)]


def missing(page_texts: dict[str, str], text: str) -> list[str]:
    """``page: number`` for every number of a results section that the report text lacks."""
    return [
        f"{name}: {number}"
        for name, page in page_texts.items()
        for section in result_sections(page)
        for number in numbers(section)
        if not in_report(number, text)
    ]


def _texts() -> dict[str, str]:
    return {p.relative_to(ROOT).as_posix(): p.read_text(encoding="utf-8") for p in pages() if p.is_file()}


def test_every_number_of_a_results_section_is_in_the_committed_reports() -> None:
    texts = _texts()
    assert sum(len(numbers(s)) for s in result_sections(texts["README.md"])) >= 10  # the README states results
    gone = missing(texts, report_text())
    assert not gone, "numbers stated as results but absent from the committed reports (update the page from the report): " + ", ".join(gone)


def test_a_planted_stale_number_is_caught(tmp_path: Path) -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert OPEN in readme
    stale = readme.replace(OPEN, f"{OPEN}\nAn older run asked 1,234.5 questions, 7.25% fewer.", 1)
    copy = tmp_path / "README.md"
    copy.write_text(stale, encoding="utf-8")
    gone = missing({"README.md": copy.read_text(encoding="utf-8")}, report_text())
    assert gone == ["README.md: 1234.5", "README.md: 7.25"]
    # the same words outside a results section are prose, not checked
    outside = readme.replace("## One example each", "An older run asked 1,234.5 questions.\n\n## One example each", 1)
    assert missing({"README.md": outside}, report_text()) == []


def test_numbers_are_read_as_a_person_reads_them() -> None:
    text = (
        "Qwen2.5-Coder-1.5B asks 162.0 [155.8, 168.4] a trial, 63% fewer, at τ = 0.5, n = 10. "
        "`lagrseq run --trials 99` ![x](figures/fig5a.png) [t](tables/table2.md) 1,000 steps"
    )
    assert numbers(text) == ["162.0", "155.8", "168.4", "63", "0.5", "10", "1000"]
    assert in_report("443.7", "443.7 [434.0, 453.6]") and not in_report("43.7", "443.7 [434.0, 453.6]")
    assert not in_report("0.5", "0.55") and in_report("63", "-63%")


def test_an_unbalanced_results_fence_fails() -> None:
    with pytest.raises(ValueError, match="without"):
        result_sections(f"{OPEN}\n42\n")
    with pytest.raises(ValueError, match="without"):
        result_sections(f"42\n{CLOSE}\n")


def test_the_hand_written_reports_readme_is_not_a_source() -> None:
    assert (REPORTS / "README.md").read_text(encoding="utf-8") not in report_text()
    assert (REPORT / "scoreboard.md").read_text(encoding="utf-8") in report_text()
