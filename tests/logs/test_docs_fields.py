"""docs/logs.md describes every field of every topic schema and every metadata record a log holds."""

from __future__ import annotations

import re
from pathlib import Path

import msgspec
import pytest

from lagrseq import config as cfg
from lagrseq.logs import schemas
from lagrseq.logs.events import ProbeQueryEvent
from lagrseq.logs.reader import read_info
from lagrseq.logs.sink import RECORDS_METADATA, RUN_METADATA, STATUS_METADATA
from lagrseq.running import runner

PAGE = Path(__file__).resolve().parents[2] / "docs" / "logs.md"
HEADING = re.compile(r"^(#+) (.*)$")
FIRST_CELL = re.compile(r"^\| `([^`]+)` \|")


def _sections() -> dict[str, list[str]]:
    """Each heading's table rows: the backticked first cells, up to the next heading."""
    sections: dict[str, list[str]] = {}
    current = ""
    for line in PAGE.read_text(encoding="utf-8").splitlines():
        if heading := HEADING.match(line):
            current = heading.group(2)
            sections[current] = []
        elif cell := FIRST_CELL.match(line):
            sections[current].append(cell.group(1))
    return sections


def _topic(title: str) -> list[str]:
    (found,) = [rows for heading, rows in _sections().items() if heading.startswith(f"`{title}`")]
    return found


QUERY_FIELDS = [*schemas.QUERY["properties"], *(f.encode_name for f in msgspec.structs.fields(ProbeQueryEvent)[len(schemas.QUERY["properties"]):])]


@pytest.mark.parametrize(
    ("topic", "fields"),
    [
        ("/transition", list(schemas.TRANSITION["properties"])),
        ("/query", QUERY_FIELDS),
        ("/episode", list(schemas.EPISODE["properties"])),
        ("/transitions", list(schemas.TRANSITIONS["properties"])),
        ("/no_query", list(schemas.NO_QUERIES["properties"])),
    ],
)
def test_the_page_lists_every_field_of_every_topic_schema(topic: str, fields: list[str]) -> None:
    assert _topic(topic) == fields, f"docs/logs.md's table of {topic} differs from its schema"


def test_every_schema_property_has_a_description() -> None:
    for schema in (*schemas.TOPICS.values(), *schemas.TOPICS_3.values()):
        undescribed = [name for name, item in schema["properties"].items() if not item.get("description")]
        assert not undescribed, f"{schema['title']}: {undescribed}"


def _metadata_rows() -> dict[str, set[str]]:
    """``record -> keys`` of the page's metadata table (a row with an empty first cell continues
    the record above)."""
    text = PAGE.read_text(encoding="utf-8")
    table = text[text.index("## Metadata records"):]
    table = table[: table.index("\n## ", 1)] if "\n## " in table[1:] else table
    found: dict[str, set[str]] = {}
    record = ""
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) < 3 or not line.startswith("|") or set(cells[0]) <= {"-"} and cells[0]:
            continue
        if cells[0].startswith("`"):
            record = cells[0].strip("`")
        if record:
            found.setdefault(record, set()).update(re.findall(r"`([^`]+)`", cells[1]))
    return found


def test_every_metadata_record_and_key_of_a_log_is_on_the_page(tmp_path: Path) -> None:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=2"])
    directory = runner.run_directory(tmp_path, config, "mock", 0)
    runner.run_trials(config, 1, 0, "mock", directory)
    info = read_info(next(directory.glob("trial-*.mcap")))
    page = _metadata_rows()
    assert {RUN_METADATA, RECORDS_METADATA, STATUS_METADATA} <= set(page)
    assert set(info.run) <= page[RUN_METADATA], sorted(set(info.run) - page[RUN_METADATA])
    assert set(info.status) <= page[STATUS_METADATA]
    assert {"/transition", "/query", "/episode"} <= page[RECORDS_METADATA]
