"""The audit log: who changed what, from which value to which.

``record`` adds the row to the caller's session and does not commit: the row lands in the
same transaction as the change it describes, so there is never a change without its entry
or an entry for a change that was rolled back. Nothing in the API updates or deletes rows.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Mapping
from typing import Any

from sqlalchemy import insert
from sqlalchemy.exc import DBAPIError
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine, AsyncSession, async_sessionmaker

from server.models import AuditEntry, Station, User

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


_Queued = tuple[dict[str, Any], "asyncio.Future[None] | None"]


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
    A connection that is lost is dropped and the batch tried once more on a new one (the
    database restarted; a commit whose answer was lost on the way may then be stored
    twice: a duplicate row rather than a missing one).
    """

    def __init__(self, sessionmaker: async_sessionmaker[AsyncSession] | None = None) -> None:
        self.sessionmaker = sessionmaker
        self._queue: asyncio.Queue[_Queued] = asyncio.Queue()
        self._task: asyncio.Task[None] | None = None
        self._conn: AsyncConnection | None = None
        self._engine: AsyncEngine | None = None

    async def write(self, **row: Any) -> None:
        """Write one row (``record``'s arguments); returns once it is committed."""
        done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._put(row, done)
        await done

    def write_soon(self, row: dict[str, Any]) -> None:
        """Queue one row without waiting for it: rows queued before it are written before it
        or in its transaction. A row that cannot be written is logged."""
        self._put(row, None)

    async def close(self, flush_s: float) -> None:
        """Wait up to ``flush_s`` for the queued rows to be written, then stop."""
        task = self._task
        if task is not None and not task.done():
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(flush_s):
                    await self._queue.join()
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        await self._drop()

    def _put(self, row: dict[str, Any], done: asyncio.Future[None] | None) -> None:
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._writer())
        self._queue.put_nowait((row, done))

    async def _writer(self) -> None:
        while True:
            batch = [await self._queue.get()]
            while not self._queue.empty():
                batch.append(self._queue.get_nowait())
            try:
                error = await self._commit(batch)
                failed = [] if error is None else [(batch[0], error)]
                if error is not None and len(batch) > 1:
                    # One row the database refuses must not take the others: one at a time.
                    failed = [(one, e) for one in batch if (e := await self._commit([one]))]
                for (row, done), exc in failed:  # its waiter hears of it; the writer goes on
                    if done is None:
                        log.error("audit row %s %s not written: %s", row["action"], row["new"], exc)
                    elif not done.done():
                        done.set_exception(exc)
            finally:
                for _ in batch:
                    self._queue.task_done()

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

    async def _commit(self, batch: list[_Queued]) -> Exception | None:
        """Write ``batch`` in one transaction and tell its waiters; the error if it failed."""
        rows = [_values(**row) for row, _ in batch]
        error: Exception | None = None
        for _ in range(2):  # a second time on a new connection if this one was lost
            reused = self._conn is not None
            try:
                conn = await self._connection()
                await conn.execute(insert(AuditEntry), rows)
                await conn.commit()
                error = None
                break
            except Exception as exc:
                error = exc
                lost = not isinstance(exc, DBAPIError) or exc.connection_invalidated
                if lost:
                    await self._drop()
                elif self._conn is not None:  # the rows were refused; the connection is good
                    with contextlib.suppress(Exception):
                        await self._conn.rollback()
                if not (lost and reused):
                    break
        if error is not None:
            return error
        for _, done in batch:
            if done is not None and not done.done():
                done.set_result(None)
        return None


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
