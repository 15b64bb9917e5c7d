"""The audit log: who changed what, from which value to which.

``record`` adds the row to the caller's session and does not commit: the row lands in the
same transaction as the change it describes, so there is never a change without its entry
or an entry for a change that was rolled back. Nothing in the API updates or deletes rows.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import json
import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sqlalchemy import insert
from sqlalchemy.exc import DataError, DBAPIError, IntegrityError, StatementError
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine, AsyncSession, async_sessionmaker
from tenacity import AsyncRetrying, RetryCallState, retry_if_exception_type, wait_random_exponential

from server import metrics
from server.models import AuditEntry, Station, User, utcnow

log = logging.getLogger("ankle.server.audit")

SYSTEM = "system"
EXPORT = "patient.export"
"""The action of every download of a patient's data out of the system: the report and the
FHIR bundle (entity ``patient``) and each recorded session's files (entity ``session``)."""


def user_actor(user: User) -> str:
    return f"user:{user.id}"


def station_actor(station: Station) -> str:
    return f"station:{station.id}"


def changes(
    before: Mapping[str, Any], after: Mapping[str, Any]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The fields that differ, as (old, new) dictionaries with the same keys."""
    keys = [k for k in after if before.get(k) != after[k]]
    return {k: before.get(k) for k in keys}, {k: after[k] for k in keys}


def record(
    db: AsyncSession,
    actor: str,
    action: str,
    entity: str,
    entity_id: int | str,
    patient_id: int | None,
    old: Mapping[str, Any] | None,
    new: Mapping[str, Any] | None,
) -> AuditEntry:
    """Add one audit row to ``db``'s current transaction.

    ``actor`` is ``"user:<id>"``, ``"station:<id>"`` or ``"system"``; ``action`` is
    ``"<entity>.<verb>"`` (``"prescription.update"``); ``old`` and ``new`` hold only the
    fields that changed, JSON-serialisable (no secrets: never a password or token hash).
    """
    entry = AuditEntry(**_values(actor, action, entity, entity_id, patient_id, old, new))
    db.add(entry)
    return entry


async def export(
    db: AsyncSession,
    actor: str,
    entity: str,
    entity_id: int | str,
    patient_id: int | None,
    what: Mapping[str, Any],
) -> None:
    """Audit data leaving the system as a file (:data:`EXPORT`) and commit it: the file goes
    out only once its row is stored."""
    record(db, actor, EXPORT, entity, entity_id, patient_id, None, what)
    await db.commit()


BACKLOG_MAX = 10_000
"""Rows the live writer keeps while the database is away (``Settings.audit_backlog_max``):
a few megabytes. Past it a row is not kept: it goes to the log in full, at ERROR."""
BATCH_MAX = 500
"""Rows committed in one transaction: a backlog is written in several."""
RETRY_FIRST_S = 0.5
"""The first wait before trying the database again; each wait is drawn from 0 up to twice
the one before (full jitter, so the processes of a site do not all come back at once)."""
RETRY_MAX_S = 15.0
"""The longest wait between tries: rows arrive at most this long after the database."""
CLOSING_RETRY_S = 0.5
"""The longest wait between tries while the server shuts down."""


class AuditBacklogFull(Exception):
    """``AuditWriter.write`` found ``backlog_max`` rows already waiting for the database."""


class _Away(Exception):
    """The database could not take the rows now (``error``); they are kept and tried again."""

    def __init__(self, error: Exception) -> None:
        super().__init__(error)
        self.error = error


REFUSED_SQLSTATES = ("22", "23")
"""SQLSTATE classes of a statement refused for its values: data exception (a value its
column cannot take), integrity constraint violation (a patient that does not exist)."""


def refused(exc: BaseException) -> bool:
    """Whether the database refused rows for what they hold, or the driver could not even
    send them (a number past 64 bits, not JSON): no retry can change that. Anything else (a
    connection refused or lost, a server starting or shutting down, a lock held past its
    timeout, a full disk) may pass, and the rows are kept.

    SQLAlchemy names only some of these: PostgreSQL's data exceptions reach it as a bare
    ``DBAPIError`` and asyncpg's values it cannot encode as an ``InterfaceError``, so the
    causes are read too."""
    if isinstance(exc, IntegrityError | DataError):
        return True
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, ValueError | TypeError | OverflowError):
            return True
        if str(getattr(e, "sqlstate", None) or "").startswith(REFUSED_SQLSTATES):
            return True
        e = e.orig if isinstance(e, DBAPIError) else e.__cause__  # raised from, not during
    return isinstance(exc, StatementError) and not isinstance(exc, DBAPIError)


@dataclass(eq=False)
class _Row:
    values: dict[str, Any]
    done: asyncio.Future[None] | None  # a waiter (``write``), or None (``write_soon``)


class AuditWriter:
    """Rows written outside a request's transaction (the live links'), in batches.

    One writer commits every row waiting at that moment in one transaction: with one
    database session per live change, a hundred therapists' changes contended for SQLite's
    write lock and their acknowledgements took seconds (``ankle bench server``).

    The writer keeps one connection of its own: a batch is one INSERT and one COMMIT. Taking
    a pooled session for each batch added the pool's ping, the session's begin and the
    rollback on its return, each a round trip to the driver's thread that waits its turn
    on a busy event loop: a K/B change, sent only once its row is committed, was answered
    in 8-37 ms at the median at 100 stations, a HOLD (not waiting for its row) in 2 ms.
    A kept connection that is found lost is replaced and the batch tried once more at once
    (the database restarted while the writer was idle).

    A HOLD or Stop is sent without waiting for its rows (``write_soon``), so the database
    may be away when they are written. Those rows are then kept, in order, and tried again
    with backoff (tenacity: ``RETRY_FIRST_S`` doubling up to ``RETRY_MAX_S``) until the
    database takes them; a row the database refuses for what it holds (:func:`refused`) is
    logged and skipped, so it does not hold the rows behind it. A row stored only in memory
    is lost if the process dies, so the writer says what it holds: a WARNING at each try,
    ``backlog`` (``ankle_audit_backlog_rows`` in ``/metrics``), and every row it could not
    keep (past ``backlog_max``, refused, or still waiting at shutdown) logged in full at
    ERROR and counted (``ankle_audit_rows_lost_total``). A waiter (``write``: a command that
    is sent only once its row is stored) is never kept waiting for the database: the try
    that fails tells it, and its command is refused.

    Each row's time is when it was queued, not when the database took it. A commit whose
    answer was lost with its connection may be stored and then tried again: a duplicate
    row rather than a missing one.
    """

    def __init__(
        self,
        sessionmaker: async_sessionmaker[AsyncSession] | None = None,
        backlog_max: int = BACKLOG_MAX,
    ) -> None:
        self.sessionmaker = sessionmaker
        self.backlog_max = backlog_max
        self.retry_max_s = RETRY_MAX_S
        self.failed_tries = 0
        """Tries in a row that found the database away (0: the last one worked)."""
        self._rows: collections.deque[_Row] = collections.deque()
        self._more = asyncio.Event()  # a row was queued
        self._wake = asyncio.Event()  # try now: a waiter arrived, or shutdown
        self._drained = asyncio.Event()  # nothing is waiting
        self._drained.set()
        self._closing = False
        self._full_since: float | None = None  # monotonic time the backlog filled up
        self._away_since: float | None = None
        self._try_began = 0.0
        """When the latest ``_commit`` began: a try that hangs 15 s before it fails counts."""
        self._task: asyncio.Task[None] | None = None
        self._conn: AsyncConnection | None = None
        self._engine: AsyncEngine | None = None

    @property
    def backlog(self) -> int:
        """Rows queued and not yet stored."""
        return len(self._rows)

    async def write(self, **row: Any) -> None:
        """Write one row (``record``'s arguments); returns once it is committed, raises if
        it could not be (the database is away or refused it, or ``AuditBacklogFull``)."""
        await self.submit(**row)

    def submit(self, **row: Any) -> asyncio.Future[None]:
        """Queue one row now and return what ``write`` waits for: done once it is committed,
        its exception if it could not be. Raises ``AuditBacklogFull`` at once.

        A caller that stops waiting cancels it: the row is then no longer waited for, and
        is dropped at the next try that fails; but a try under way may still commit it (a
        database that answers late), so such a caller writes what became of its command
        after it, in the same queue (``server.hub``)."""
        if len(self._rows) >= self.backlog_max:
            raise AuditBacklogFull(
                f"{len(self._rows)} audit rows already wait for the database to come back"
            )
        done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._put(_Row(_queued(row), done))
        self._wake.set()  # do not wait out a backoff: the command waits for this answer
        return done

    def write_soon(self, row: dict[str, Any]) -> None:
        """Queue one row without waiting for it: rows queued before it are written before it
        or in its transaction, however long the database is away. Past ``backlog_max`` rows
        the row is not kept: it is logged in full, at ERROR."""
        values = _queued(row)
        if len(self._rows) >= self.backlog_max:
            if self._full_since is None:
                self._full_since = time.monotonic()
                log.error(
                    "audit backlog full: %d rows wait for the database; the rows that follow "
                    "are not kept, each is logged here instead (ANKLE_AUDIT_BACKLOG_MAX)",
                    len(self._rows),
                )
            _lose(values, "backlog_full")
            return
        self._put(_Row(values, None))

    async def close(self, flush_s: float) -> None:
        """Write the queued rows, trying the database every ``CLOSING_RETRY_S`` for up to
        ``flush_s``, then stop; each row still not written is logged in full, at ERROR."""
        task = self._task
        if task is not None and not task.done():
            self._closing = True
            self._wake.set()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(flush_s):
                    await self._drained.wait()
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._closing = False
        left, self._rows = list(self._rows), collections.deque()
        if left:
            log.error(
                "%d audit rows were not written before shutdown (the database was away for "
                "%.0f s); each follows in full",
                len(left),
                0.0 if self._away_since is None else time.monotonic() - self._away_since,
            )
        for row in left:
            _lose(row.values, "shutdown")
            if row.done is not None and not row.done.done():
                row.done.set_exception(RuntimeError("the server shut down before it was written"))
        self._drained.set()
        self.failed_tries, self._away_since, self._full_since = 0, None, None
        await self._drop()

    def _put(self, row: _Row) -> None:
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._writer())
        self._rows.append(row)
        self._drained.clear()
        self._more.set()

    async def _writer(self) -> None:
        retrying = AsyncRetrying(
            retry=retry_if_exception_type(_Away),
            wait=self._wait,
            sleep=self._sleep,
            before_sleep=self._waiting,
        )
        while True:
            while not self._rows:
                self._drained.set()
                self._more.clear()
                await self._more.wait()
            await retrying(self._write_all)

    async def _write_all(self) -> None:
        """Write every queued row, oldest first; raise _Away (the rows kept) if the database
        cannot take them."""
        self._wake.clear()
        while self._rows:
            batch = list(itertools.islice(self._rows, BATCH_MAX))
            error = await self._commit(batch)
            if error is None:
                self._stored(len(batch))
                continue
            if not refused(error):
                raise self._away(error)
            for row in batch:  # one row the database refuses must not take the others
                error = await self._commit([row])
                if error is None:
                    self._stored(1)
                elif refused(error):
                    self._rows.popleft()
                    if row.done is None:
                        _lose(row.values, "refused", error)
                    elif not row.done.done():
                        row.done.set_exception(error)
                else:
                    raise self._away(error)
        if self.failed_tries:
            assert self._away_since is not None
            log.warning(
                "audit rows written again: the database was away for %.0f s (%d tries)",
                time.monotonic() - self._away_since,
                self.failed_tries,
            )
            self.failed_tries, self._away_since = 0, None

    def _stored(self, count: int) -> None:
        for _ in range(count):
            row = self._rows.popleft()
            if row.done is not None and not row.done.done():
                row.done.set_result(None)
        if self._full_since is not None and len(self._rows) < self.backlog_max:
            log.error(
                "audit backlog has room again after %.0f s; the rows logged as not kept in "
                "that time are not in the audit log",
                time.monotonic() - self._full_since,
            )
            self._full_since = None

    def _away(self, error: Exception) -> _Away:
        """The database cannot take rows now: every waiter is told at once (its command is
        refused, rather than kept waiting out the backoff); the other rows stay, in order."""
        if any(row.done is not None for row in self._rows):
            for row in self._rows:
                if row.done is not None and not row.done.done():
                    row.done.set_exception(error)
            self._rows = collections.deque(r for r in self._rows if r.done is None)
        self.failed_tries += 1
        if self._away_since is None:  # from when the try that found it away began
            self._away_since = self._try_began
        return _Away(error)

    def _wait(self, state: RetryCallState) -> float:
        wait = wait_random_exponential(multiplier=RETRY_FIRST_S, max=self.retry_max_s)
        return float(wait(state))

    async def _sleep(self, seconds: float) -> None:
        """Wait ``seconds``, or less if a waiter or shutdown wakes the writer."""
        if self._closing:
            seconds = min(seconds, CLOSING_RETRY_S)
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(seconds):
                await self._wake.wait()

    def _waiting(self, state: RetryCallState) -> None:
        away = state.outcome.exception() if state.outcome is not None else None
        error = away.error if isinstance(away, _Away) else away
        log.warning(
            "%d audit rows wait for the database (%s); trying again within %.1f s",
            len(self._rows),
            _short(error),
            state.upcoming_sleep,
        )

    async def _connection(self) -> AsyncConnection:
        assert self.sessionmaker is not None
        engine = self.sessionmaker.kw["bind"]
        if self._conn is None or self._engine is not engine:
            await self._drop()
            self._conn = await engine.connect()
            self._engine = engine
        return self._conn

    async def _drop(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(Exception):
                await conn.close()

    async def _commit(self, batch: list[_Row]) -> Exception | None:
        """Write ``batch`` in one transaction; the error if it failed."""
        self._try_began = time.monotonic()
        rows = [row.values for row in batch]
        error: Exception | None = None
        for _ in range(2):  # a second time on a new connection if this one was lost
            reused = self._conn is not None
            try:
                conn = await self._connection()
                await conn.execute(insert(AuditEntry), rows)
                await conn.commit()
                return None
            except Exception as exc:
                error = exc
                if refused(exc):  # the rows, not the connection
                    if self._conn is not None:
                        with contextlib.suppress(Exception):
                            await self._conn.rollback()
                    break
                await self._drop()  # whatever else went wrong, the next try starts afresh
                lost = not isinstance(exc, DBAPIError) or exc.connection_invalidated
                if not (lost and reused):
                    break
        return error


def _queued(row: Mapping[str, Any]) -> dict[str, Any]:
    """``row``'s columns (``record``'s arguments), timed now: a row written late keeps the
    time it happened."""
    return {**_values(**row), "at": utcnow()}


def _short(error: BaseException | None) -> str:
    """The first line of ``error``: SQLAlchemy's add the statement and a link."""
    if error is None:
        return "no error"
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0][:200] if text else ''}"


def _lose(values: Mapping[str, Any], reason: str, error: Exception | None = None) -> None:
    """Say, in full, that a row will not be in the audit log, and count it."""
    metrics.audit_row_lost(reason)
    log.error(
        "audit row NOT WRITTEN (%s%s): %s",
        reason,
        f": {_short(error)}" if error is not None else "",
        json.dumps(values, default=str, sort_keys=True),
    )


def _values(
    actor: str,
    action: str,
    entity: str,
    entity_id: int | str,
    patient_id: int | None,
    old: Mapping[str, Any] | None,
    new: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """One row's columns, as :func:`record` stores them."""
    return {
        "actor": actor,
        "action": action,
        "entity": entity,
        "entity_id": str(entity_id),
        "patient_id": patient_id,
        "old": None if old is None else dict(old),
        "new": None if new is None else dict(new),
    }
