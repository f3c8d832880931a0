"""The dated price table: lookups, costs from usage, the TOML override."""

from __future__ import annotations

import datetime
from pathlib import Path

import pytest

from lagrseq.errors import ConfigError
from lagrseq.llm.base import Message, Query, Usage
from lagrseq.llm.pricing import BUILTIN, PriceTable, prompt_token_bound, read_price_table


def test_every_builtin_price_has_a_source_and_an_iso_date() -> None:
    for price in BUILTIN:
        assert price.source.startswith("https://"), price.model
        datetime.date.fromisoformat(price.date)
        assert price.input_usd_per_mtok > 0 and price.output_usd_per_mtok >= price.input_usd_per_mtok


def test_lookup_is_exact_then_longest_prefix() -> None:
    table = PriceTable()
    assert table.lookup("gpt-4o-mini-2024-07-18").model == "gpt-4o-mini"  # type: ignore[union-attr]
    assert table.lookup("gpt-4o-2024-08-06").model == "gpt-4o"  # type: ignore[union-attr]
    assert table.lookup("gpt-4o-2024-05-13").input_usd_per_mtok == 5.0  # type: ignore[union-attr]
    assert table.lookup("gpt-3.5-turbo-0613").output_usd_per_mtok == 2.0  # type: ignore[union-attr]
    assert table.lookup("gpt-4-0613").model == "gpt-4"  # type: ignore[union-attr]
    assert table.lookup("llama3") is None and table.lookup(None) is None
    assert table.price(None, "unknown", "gpt-4").model == "gpt-4"  # type: ignore[union-attr]


def test_cost_bills_cached_prompt_tokens_at_the_cached_rate() -> None:
    table = PriceTable()
    usage = Usage(prompt_tokens=1000, completion_tokens=100, cached_tokens=400)
    assert table.cost(usage, "gpt-4o-mini") == pytest.approx((600 * 0.15 + 400 * 0.075 + 100 * 0.60) / 1e6)
    # no cached rate: cached tokens are billed as input
    assert table.cost(usage, "gpt-4") == pytest.approx((1000 * 30 + 100 * 60) / 1e6)
    assert table.cost(usage, "nobody-knows") is None


def test_worst_case_bounds_every_possible_answer() -> None:
    query = Query("t", "gpt-4o-mini", (Message("user", "héllo " * 50),), max_tokens=64)
    bound = prompt_token_bound(query)
    assert bound >= len(query.prompt.encode())
    worst = PriceTable().worst_case(query, 3, requests=2)
    assert worst == pytest.approx((2 * bound * 0.15 + 3 * 64 * 0.60) / 1e6)
    assert PriceTable().worst_case(Query("t", "mystery", (Message("user", "x"),)), 1) is None


def test_a_toml_table_overrides_and_extends(tmp_path: Path) -> None:
    path = tmp_path / "prices.toml"
    path.write_text(
        '[models."gpt-4o-mini"]\ninput_usd_per_mtok = 1\noutput_usd_per_mtok = 2.5\n'
        'source = "https://example.org/prices"\ndate = 2030-01-01\n'
        '[models."llama3"]\ninput_usd_per_mtok = 0\noutput_usd_per_mtok = 0\n'
        'cached_input_usd_per_mtok = 0\nsource = "local"\ndate = "2025-01-01"\n'
    )
    table = read_price_table(path)
    mini = table.lookup("gpt-4o-mini")
    assert mini is not None and mini.input_usd_per_mtok == 1.0 and mini.date == "2030-01-01"
    assert mini.cached_input_usd_per_mtok is None
    assert table.cost(Usage(10, 10), "llama3:8b") is None  # 'llama3:8b' is not 'llama3-...'
    assert table.cost(Usage(10, 10), "llama3") == 0.0
    assert table.lookup("gpt-4") is not None  # built-in entries stay


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("not toml [", "not valid TOML"),
        ("x = 1", "expected \\[models"),
        ('[models."m"]\ninput_usd_per_mtok = 1\nsource = "s"\ndate = "d"', "missing field 'output_usd_per_mtok'"),
        ('[models."m"]\ninput_usd_per_mtok = -1\noutput_usd_per_mtok = 1\nsource = "s"\ndate = "d"', "cannot be negative"),
        ('[models."m"]\ninput_usd_per_mtok = "1"\noutput_usd_per_mtok = 1\nsource = "s"\ndate = "d"', "expected a float"),
        ('[models."m"]\ninput = 1', "unknown field 'input'"),
        ('[models."m"]\ninput_usd_per_mtok = nan\noutput_usd_per_mtok = 1\nsource = "s"\ndate = "d"', "input_usd_per_mtok = nan: expected a finite price >= 0"),
        ('[models."m"]\ninput_usd_per_mtok = 1\noutput_usd_per_mtok = inf\nsource = "s"\ndate = "d"', "output_usd_per_mtok = inf: expected a finite price"),
        ('[models."m"]\ninput_usd_per_mtok = 1\noutput_usd_per_mtok = 1\ncached_input_usd_per_mtok = -inf\nsource = "s"\ndate = "d"', "cached_input_usd_per_mtok = -inf: expected a finite"),
        ('[models."m"]\ninput_usd_per_mtok = 1\noutput_usd_per_mtok = 1\nsource = "s"\ndate = "d"\n[models."a\\nb"]\ninput_usd_per_mtok = true', "models.'a\\\\nb'.input_usd_per_mtok = True: expected a float"),
    ],
)
def test_a_bad_table_is_one_clear_error(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "prices.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as info:
        read_price_table(path)
    assert str(info.value).startswith(f"price table file {path}") and "\n" not in str(info.value)


def test_a_huge_unknown_field_name_is_not_repeated(tmp_path: Path) -> None:
    path = tmp_path / "prices.toml"
    path.write_text('[models."m"]\n' + "k" * 500_000 + " = 1\n")
    with pytest.raises(ConfigError, match="unknown field of 500000 characters") as info:
        read_price_table(path)
    assert len(str(info.value)) < 400


def test_a_missing_table_file() -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        read_price_table("/nonexistent/prices.toml")
