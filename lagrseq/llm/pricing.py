"""A small dated price table and the cost of an answer, computed from its usage.

Every entry says where its prices come from and on which date they applied, because prices
change: a cost is only meaningful together with the table it was computed from. Costs are
recomputed from recorded token counts, so re-pricing an old run is a matter of passing another
table (``--price-table FILE``).

The built-in entries are OpenAI's list prices for the Chat Completions models the paper and its
successors use, in US dollars per million tokens (standard tier, no Batch discount). They were
compiled without network access from copies of OpenAI's pricing page and announcements, so check
them against https://platform.openai.com/docs/pricing before relying on a figure; a TOML file
overrides or extends them::

    [models."gpt-4o-mini"]
    input_usd_per_mtok = 0.15          # prompt tokens
    output_usd_per_mtok = 0.60         # completion tokens
    cached_input_usd_per_mtok = 0.075  # prompt tokens served from the prompt cache (optional)
    source = "https://platform.openai.com/docs/pricing"
    date = "2024-07-18"

A model name is looked up exactly, then by its longest listed prefix followed by ``-`` (so the
dated snapshot ``gpt-4o-mini-2024-07-18`` is priced as ``gpt-4o-mini``); a snapshot whose price
differs from its family's has an entry of its own.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq.errors import ConfigError
from lagrseq.llm.base import Query, Usage
from lagrseq.tomlfile import read_toml, shown

MILLION = 1_000_000
OPENAI_PRICING = "https://platform.openai.com/docs/pricing"


@dataclass(frozen=True)
class Price:
    """The price of one model, in US dollars per million tokens."""

    model: str
    input_usd_per_mtok: float
    output_usd_per_mtok: float
    cached_input_usd_per_mtok: float | None
    """None: the model has no cached-input rate (cached tokens are billed as input)."""
    source: str
    date: str
    """ISO date from which the price applied (as far as the source says)."""

    @property
    def input_per_token(self) -> float:
        return self.input_usd_per_mtok / MILLION

    @property
    def output_per_token(self) -> float:
        return self.output_usd_per_mtok / MILLION

    @property
    def cached_input_per_token(self) -> float:
        rate = self.cached_input_usd_per_mtok
        return (self.input_usd_per_mtok if rate is None else rate) / MILLION

    def cost(self, usage: Usage) -> float:
        """USD for one answer's usage (cached prompt tokens at the cached rate)."""
        cached = min(max(usage.cached_tokens, 0), usage.prompt_tokens)
        return (
            (usage.prompt_tokens - cached) * self.input_per_token
            + cached * self.cached_input_per_token
            + usage.completion_tokens * self.output_per_token
        )


def _p(model: str, inp: float, out: float, cached: float | None, date: str, source: str = OPENAI_PRICING) -> Price:
    return Price(model, inp, out, cached, source, date)


# The built-in table. Dates: when the price took effect for that model (launch or price change).
BUILTIN: tuple[Price, ...] = (
    _p("gpt-3.5-turbo", 0.50, 1.50, None, "2024-01-25"),  # gpt-3.5-turbo-0125, the alias since Feb 2024
    _p("gpt-3.5-turbo-0125", 0.50, 1.50, None, "2024-01-25"),
    _p("gpt-3.5-turbo-1106", 1.00, 2.00, None, "2023-11-06"),
    _p("gpt-3.5-turbo-0613", 1.50, 2.00, None, "2023-06-13"),  # the 2023 snapshot behind the paper's caches
    _p("gpt-4", 30.00, 60.00, None, "2023-03-14"),
    _p("gpt-4-turbo", 10.00, 30.00, None, "2024-04-09"),
    _p("gpt-4o", 2.50, 10.00, 1.25, "2024-10-01"),
    _p("gpt-4o-2024-05-13", 5.00, 15.00, None, "2024-05-13"),
    _p("gpt-4o-mini", 0.15, 0.60, 0.075, "2024-07-18"),
    _p("gpt-4.1", 2.00, 8.00, 0.50, "2025-04-14"),
    _p("gpt-4.1-mini", 0.40, 1.60, 0.10, "2025-04-14"),
    _p("gpt-4.1-nano", 0.10, 0.40, 0.025, "2025-04-14"),
)


# Tokens a chat request adds around the messages (role markers, priming); an upper bound.
MESSAGE_OVERHEAD_TOKENS = 4
REQUEST_OVERHEAD_TOKENS = 3


def prompt_token_bound(query: Query) -> int:
    """An upper bound on the prompt tokens of ``query``: every byte a token (BPE tokens are never
    shorter than one byte), plus the per-message overhead."""
    return REQUEST_OVERHEAD_TOKENS + sum(
        MESSAGE_OVERHEAD_TOKENS + len(m.content.encode()) + len(m.role) for m in query.messages
    )


class PriceTable:
    """Prices by model name (exact, then the longest ``prefix-`` match)."""

    def __init__(self, prices: tuple[Price, ...] | list[Price] = BUILTIN) -> None:
        self.prices: dict[str, Price] = {p.model: p for p in prices}

    def lookup(self, model: str | None) -> Price | None:
        if not model:
            return None
        if model in self.prices:
            return self.prices[model]
        family = [name for name in self.prices if model.startswith(name + "-")]
        return self.prices[max(family, key=len)] if family else None

    def price(self, *models: str | None) -> Price | None:
        """The price of the first of ``models`` that the table knows."""
        for model in models:
            found = self.lookup(model)
            if found is not None:
                return found
        return None

    def cost(self, usage: Usage, *models: str | None) -> float | None:
        """USD for ``usage`` under the first known of ``models``; None if none is priced."""
        price = self.price(*models)
        return None if price is None else price.cost(usage)

    def worst_case(self, query: Query, n: int, requests: int = 1) -> float | None:
        """An upper bound on what asking ``n`` samples of ``query`` in ``requests`` requests can
        cost (None: no price). Every completion is assumed to use ``max_tokens``; the prompt, paid
        once per request, is bounded by :func:`prompt_token_bound`."""
        price = self.price(query.model)
        if price is None:
            return None
        completion = n * int(query.max_tokens)
        prompt = requests * prompt_token_bound(query)
        return prompt * price.input_per_token + completion * price.output_per_token

    def merged(self, other: PriceTable) -> PriceTable:
        """This table with ``other``'s entries added or replacing ours."""
        return PriceTable(tuple({**self.prices, **other.prices}.values()))

    def __len__(self) -> int:
        return len(self.prices)


def _field(where: str, entry: Mapping[str, Any], name: str, kind: type, required: bool = True) -> Any:
    if name not in entry:
        if required:
            raise ConfigError(f"{where}: missing field {name!r}")
        return None
    value: Any = entry[name]
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise ConfigError(f"{where}.{name} = {_clip(repr(value))}: expected a {kind.__name__}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{where}.{name} = {value!r}: expected a finite price >= 0")
    if isinstance(value, float) and value < 0:
        raise ConfigError(f"{where}.{name} = {value!r}: a price cannot be negative")
    return value


def _clip(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def read_price_table(path: str | Path, base: PriceTable | None = None) -> PriceTable:
    """Read a TOML price table (module docstring) over ``base`` (the built-in table by default)."""
    data = read_toml(path, "price table")
    models = data.get("models")
    if not isinstance(models, dict) or not models:
        raise ConfigError(f'price table file {shown(path)}: expected [models."NAME"] tables of prices')
    prices = []
    for name, entry in models.items():
        where = f"price table file {shown(path)}: models.{_clip(repr(name))}"
        if not isinstance(entry, dict):
            raise ConfigError(f"{where} must be a table of fields")
        known = {"input_usd_per_mtok", "output_usd_per_mtok", "cached_input_usd_per_mtok", "source", "date"}
        unknown = sorted(set(entry) - known)
        if unknown:
            field = ascii(unknown[0]) if len(unknown[0]) <= 40 else f"of {len(unknown[0])} characters"
            raise ConfigError(f"{where}: unknown field {field}; fields are {', '.join(sorted(known))}")
        date: Any = entry.get("date")
        if date is not None and hasattr(date, "isoformat"):  # TOML dates arrive as datetime.date
            date = date.isoformat()
        prices.append(
            Price(
                model=name,
                input_usd_per_mtok=_field(where, entry, "input_usd_per_mtok", float),
                output_usd_per_mtok=_field(where, entry, "output_usd_per_mtok", float),
                cached_input_usd_per_mtok=_field(where, entry, "cached_input_usd_per_mtok", float, required=False),
                source=_field(where, entry, "source", str),
                date=_field(where, {} if date is None else {"date": date}, "date", str),
            )
        )
    return (base or PriceTable()).merged(PriceTable(prices))
