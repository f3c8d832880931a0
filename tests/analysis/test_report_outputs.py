"""What replay writes under a canary API key and hostile suite text: no report file holds the key
in any form the key guard knows, and HTML, ``|`` and terminal escapes in a title are escaped in
the Markdown and HTML pages."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lagrseq.analysis.replay import replay
from lagrseq.suite import load_suite

KEY = "sk-canaryQ7x9Lm2Pz4Rt8Vw3Yb6Nc1Df5Gh0Jk"
BODY = KEY[3:]
SPACED = "\u200b".join(BODY[i : i + 3] for i in range(0, len(BODY), 3))


@pytest.mark.filterwarnings("ignore:Glyph")
def test_no_report_file_holds_the_key_and_titles_are_escaped(runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", KEY)
    paper = load_suite()
    hostile = f"<script>x()</script> | \x1b]0;owned\x07 {BODY} {BODY.upper()} {SPACED}"
    suite = dataclasses.replace(paper, items=tuple(dataclasses.replace(item, title=f"{item.title} {hostile}", note=BODY[-12:]) for item in paper.items))
    report = replay([runs_dir], tmp_path / "out", suite=suite)
    texts = {p: p.read_text(encoding="utf-8") for p in (tmp_path / "out").rglob("*") if p.suffix in (".md", ".html", ".csv")}
    assert len(texts) > 10 and report.written
    for path, text in texts.items():
        plain = text.replace("\u200b", "").lower()
        assert BODY[:12].lower() not in plain and BODY[-12:].lower() not in plain, path
        assert "\x1b" not in text and "<script>" not in text, path
    index_md = texts[tmp_path / "out" / "index.md"]
    assert "&lt;script&gt;" in index_md or "\\<script" in index_md
