"""One budget for every trial and worker of a run: a ledger of reservations in an SQLite file.

``--max-cost-usd`` and ``--max-queries`` of ``lagrseq run`` hold for the whole run, whichever
process or Dask worker sends a request. Before a live request, a worker *reserves* its worst case
(every completion uses ``max_tokens``, the prompt one token per byte: what
:meth:`~lagrseq.llm.pricing.PriceTable.worst_case` bounds) in one ``BEGIN IMMEDIATE`` transaction
that first checks ``settled spending + held reservations + this request <= limit``; after the
answer it *settles* the reservation at the answer's real cost. Two workers can therefore never
both pass the check on the same remaining money.

What a failure costs:

- the server refuses or never answers (a ``ProviderError`` after the live provider's retries): the
  reservation is released, as the per-trial guard charged nothing for a failed request;
- Ctrl-C during a request: the reservation is kept at its worst case (the request may have been
  billed);
- a worker that dies during a request (killed, lost node): its reservation stays *held* at the
  worst case for ever, so the run can never spend more than its limit; it may stop early by that
  amount. ``lagrseq run`` says how much is held by unfinished requests when it stops.

So the sweep overspends its limit by nothing that the price table knows of. What it cannot see: a
request that the server billed although the client saw it fail (a timeout after the server had
computed the answer, then a retry) is released; each such lost answer costs at most one more
worst-case request, and the live provider retries at most ``max_retries`` (5) times.

Supported file systems: a local disk (all workers on one machine: a local Dask cluster or the
process pool). SQLite's locking is unsafe over NFS, SMB/CIFS and sshfs; a ledger there is refused.
On a cluster whose run directory is on such a file system, give the run no budget or run the live
queries on one machine (record them with ``lagrseq record`` and run the sweep on the store).
"""

from __future__ import annotations

import contextlib
import os
import socket
import sqlite3
import time
from pathlib import Path
from typing import Any

from lagrseq.errors import BudgetExceeded, StoreError
from lagrseq.llm.base import Answer, Query

NETWORK_FILE_SYSTEMS = ("nfs", "nfs4", "cifs", "smb", "smb2", "smb3", "smbfs", "fuse.sshfs", "afs", "9p")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS reservations (
    id INTEGER PRIMARY KEY,
    state TEXT NOT NULL,              -- held | settled
    reserved_usd REAL NOT NULL,       -- worst case, counted while held
    reserved_answers INTEGER NOT NULL,
    spent_usd REAL NOT NULL DEFAULT 0, -- priced cost of the answers, once settled
    answers INTEGER NOT NULL DEFAULT 0,
    unpriced INTEGER NOT NULL DEFAULT 0,
    host TEXT NOT NULL,
    pid INTEGER NOT NULL,
    created REAL NOT NULL
)
"""


def file_system_of(path: Path) -> str:
    """The type of the file system holding ``path`` (Linux: from /proc/mounts; "" elsewhere)."""
    try:
        mounts = Path("/proc/mounts").read_text().splitlines()
    except OSError:
        return ""
    target = str(path.resolve())
    best, kind = "", ""
    for line in mounts:
        fields = line.split()
        if len(fields) < 3:
            continue
        point = fields[1].replace("\\040", " ")
        inside = target == point or target.startswith(point.rstrip("/") + "/")
        if inside and len(point) >= len(best):
            best, kind = point, fields[2]
    return kind


class SharedBudget:
    """The budget of a run, shared by processes through the SQLite file ``path``. Offers what
    :class:`~lagrseq.llm.budget.BudgetedProvider` needs: ``reserve``, ``settle``, ``release``,
    ``keep``, and the totals ``spent_usd``, ``answers``, ``unpriced``."""

    def __init__(self, path: str | Path, max_cost_usd: float | None, max_queries: int | None, timeout_s: float = 60.0) -> None:
        self.path = Path(path)
        self.max_cost_usd = max_cost_usd
        self.max_queries = max_queries
        kind = file_system_of(self.path.parent)
        if kind.startswith(NETWORK_FILE_SYSTEMS):
            raise StoreError(
                f"the run's budget ledger {self.path} would be on a {kind} file system, where SQLite's "
                "locks are unsafe; put --out on a local disk, or run without --max-cost-usd/--max-queries"
            )
        try:
            self._db = sqlite3.connect(str(self.path), timeout=timeout_s, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=DELETE")  # no WAL: it needs shared memory
            self._db.execute(_SCHEMA)
        except sqlite3.Error as exc:
            raise StoreError(f"cannot open the run's budget ledger {self.path} ({exc}); check the directory") from None

    # ---------------------------------------------------------------- totals
    def _totals(self) -> tuple[float, int, float, int]:
        """(settled USD, settled answers, held USD, held answers)."""
        row = self._db.execute(
            "SELECT COALESCE(SUM(CASE WHEN state = 'settled' THEN spent_usd END), 0),"
            " COALESCE(SUM(CASE WHEN state = 'settled' THEN answers END), 0),"
            " COALESCE(SUM(CASE WHEN state = 'held' THEN reserved_usd END), 0),"
            " COALESCE(SUM(CASE WHEN state = 'held' THEN reserved_answers END), 0) FROM reservations"
        ).fetchone()
        return float(row[0]), int(row[1]), float(row[2]), int(row[3])

    @property
    def spent_usd(self) -> float:
        return self._totals()[0]

    @property
    def answers(self) -> int:
        return self._totals()[1]

    @property
    def held_usd(self) -> float:
        return self._totals()[2]

    @property
    def unpriced(self) -> int:
        return int(self._db.execute("SELECT COALESCE(SUM(unpriced), 0) FROM reservations").fetchone()[0])

    # ---------------------------------------------------------------- the protocol
    def reserve(self, query: Query, n: int, worst_cost: float | None) -> int:
        """Hold ``worst_cost`` and ``n`` answers for one request, or raise BudgetExceeded (nothing
        is held then). Returns the reservation's id."""
        from lagrseq.llm.budget import Budget

        with self._transaction():
            spent, answers, held_usd, held_answers = self._totals()
            committed = Budget(self.max_cost_usd, self.max_queries, spent_usd=spent + held_usd, answers=answers + held_answers)
            try:
                committed.check(query, n, worst_cost)
            except BudgetExceeded as exc:
                held = f"; ${held_usd:.4f} and {held_answers} answers held by requests in flight" if held_answers else ""
                raise BudgetExceeded(f"{exc} (one budget for every trial of the run: {self.path.name}{held})") from None
            cursor = self._db.execute(
                "INSERT INTO reservations (state, reserved_usd, reserved_answers, host, pid, created)"
                " VALUES ('held', ?, ?, ?, ?, ?)",
                (worst_cost or 0.0, n, socket.gethostname(), os.getpid(), time.time()),
            )
            return int(cursor.lastrowid or 0)

    def settle(self, ticket: int, answers: list[Answer]) -> None:
        """The request came back: replace the reservation by what it cost."""
        priced = [a.cost_usd for a in answers if a.cost_usd is not None]
        with self._transaction():
            self._db.execute(
                "UPDATE reservations SET state = 'settled', spent_usd = ?, answers = ?, unpriced = ? WHERE id = ?",
                (float(sum(priced)), len(answers), len(answers) - len(priced), ticket),
            )

    def release(self, ticket: int) -> None:
        """The request failed without an answer: nothing is charged."""
        with self._transaction():
            self._db.execute("DELETE FROM reservations WHERE id = ? AND state = 'held'", (ticket,))

    def keep(self, ticket: int) -> None:
        """Interrupted during the request: charge the worst case (it may have been billed)."""
        with self._transaction():
            self._db.execute(
                "UPDATE reservations SET state = 'settled', spent_usd = reserved_usd, answers = reserved_answers"
                " WHERE id = ? AND state = 'held'",
                (ticket,),
            )

    @contextlib.contextmanager
    def _transaction(self) -> Any:
        try:
            self._db.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise StoreError(f"the run's budget ledger {self.path} cannot be locked ({exc})") from None
        try:
            yield
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    def close(self) -> None:
        with contextlib.suppress(sqlite3.Error):
            self._db.close()

    def __repr__(self) -> str:
        return f"SharedBudget({str(self.path)!r}, max_cost_usd={self.max_cost_usd}, max_queries={self.max_queries})"
