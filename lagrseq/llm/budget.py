"""Budget guards: stop *before* a call that could take spending past a limit.

:class:`BudgetedProvider` wraps the provider that costs money (the live one) and checks every
request against a :class:`Budget` before sending it. The check is conservative: it assumes every
completion uses ``max_tokens`` and bounds the prompt by one token per byte
(:func:`~lagrseq.llm.pricing.prompt_token_bound`), so the limit is never passed; it may stop one
request early. ``--max-queries`` counts answers (samples), not HTTP requests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from lagrseq.errors import BudgetExceeded
from lagrseq.llm.base import Answer, Provider, Query, pinned, sample, samples_per_request
from lagrseq.llm.pricing import PriceTable


@dataclass
class Budget:
    """Limits and what has been spent against them (mutable: one budget per recording or trial)."""

    max_cost_usd: float | None = None
    """Stop before a request that could take the spending past this many US dollars."""
    max_queries: int | None = None
    """Stop before a request that would take the number of answers past this."""
    spent_usd: float = 0.0
    """Priced cost of the answers received so far."""
    answers: int = 0
    """Answers received so far."""
    unpriced: int = 0
    """Answers whose model has no price (their cost is not in ``spent_usd``)."""
    in_flight_answers: int = 0
    """Answers asked by requests sent and not yet answered (concurrent recording)."""
    in_flight_usd: float = 0.0
    """The worst-case cost of those requests."""

    def check(self, query: Query, n: int, worst_cost: float | None) -> None:
        """Raise :class:`BudgetExceeded` if asking ``n`` more answers could pass a limit, counting
        the requests in flight at their worst case."""
        so_far = self.answers + self.in_flight_answers
        if self.max_queries is not None and so_far + n > self.max_queries:
            flight = f" ({self.in_flight_answers} of them in flight)" if self.in_flight_answers else ""
            raise BudgetExceeded(
                f"--max-queries {self.max_queries} reached: {so_far} answers so far{flight} and the next "
                f"request asks for {n} more (not sent); raise the limit to go on"
            )
        if self.max_cost_usd is None:
            return
        if worst_cost is None:
            raise BudgetExceeded(
                f"model {query.model!r} has no price in the price table, so --max-cost-usd cannot be "
                "enforced (nothing sent); add its price with --price-table FILE"
            )
        if self.spent_usd + self.in_flight_usd + worst_cost > self.max_cost_usd:
            flight = f" (and up to ${self.in_flight_usd:.4f} in flight)" if self.in_flight_answers else ""
            raise BudgetExceeded(
                f"--max-cost-usd {self.max_cost_usd:g} reached: ${self.spent_usd:.4f} spent{flight} and the next "
                f"request could cost up to ${worst_cost:.4f} (not sent); raise the limit to go on"
            )

    # The reservation protocol, shared with lagrseq.llm.ledger.SharedBudget (one budget for the
    # workers of a run): reserve before a request, then settle, release or keep its ticket.
    def reserve(self, query: Query, n: int, worst_cost: float | None) -> tuple[int, float]:
        """:meth:`check`, then count the request as in flight (concurrent recording counts the
        requests in flight at their worst case); returns the ticket the other calls take back."""
        self.check(query, n, worst_cost)
        reserved = worst_cost or 0.0
        self.in_flight_answers += n
        self.in_flight_usd += reserved
        return n, reserved

    def _landed(self, ticket: tuple[int, float]) -> None:
        n, reserved = ticket
        self.in_flight_answers -= n
        self.in_flight_usd = max(self.in_flight_usd - reserved, 0.0)

    def settle(self, ticket: tuple[int, float], answers: list[Answer]) -> None:
        """A request in flight has ended (``answers`` empty when it failed): charge what came."""
        self._landed(ticket)
        self.charge(answers)

    def release(self, ticket: tuple[int, float]) -> None:
        """A request that failed without answers costs nothing."""
        self._landed(ticket)

    def keep(self, ticket: tuple[int, float]) -> None:
        """An interrupted request (it may have been billed) stays counted at its worst case."""

    def close(self) -> None:
        """Nothing to release."""

    def charge(self, answers: list[Answer]) -> None:
        for answer in answers:
            self.answers += 1
            if answer.cost_usd is None:
                self.unpriced += 1
            else:
                self.spent_usd += answer.cost_usd


class BudgetedProvider:
    """``inner`` behind a budget check (a wrapper: the inner provider knows nothing of it)."""

    def __init__(self, inner: Provider, budget: Any, prices: PriceTable) -> None:
        self.inner = inner
        self.budget = budget
        self.prices = prices
        self.name = inner.name

    @property
    def max_samples_per_request(self) -> int:
        return samples_per_request(self.inner)

    def pin(self, query: Query) -> Query:
        return pinned(self.inner, query)

    def complete(self, query: Query) -> Answer:
        return self.complete_n(query, 1)[0]

    def complete_n(self, query: Query, n: int) -> list[Answer]:
        requests = math.ceil(n / self.max_samples_per_request)
        ticket = self.budget.reserve(query, n, self.prices.worst_case(query, n, requests))
        try:
            answers = sample(self.inner, query, n)
        except Exception:
            self.budget.release(ticket)
            raise
        except BaseException:  # Ctrl-C mid-request: it may have been billed
            self.budget.keep(ticket)
            raise
        self.budget.settle(ticket, answers)
        return answers

    def close(self) -> None:
        self.inner.close()
        self.budget.close()

    def __enter__(self) -> BudgetedProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"BudgetedProvider({self.inner!r}, {self.budget!r})"
