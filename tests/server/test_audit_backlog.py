"""The live audit rows that no command waits for (a HOLD's and a Stop's request, every
outcome) outlive a database that is away: kept in order, tried again with backoff until it is
back, each stored exactly once; a row the database refuses does not hold the rows behind it;
past the backlog's cap and at shutdown, a row that is not kept is logged in full and counted.

PostgreSQL really stops (``pg_ctl stop``: every connection refused) and starts again.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from sqlalchemy.exc import DBAPIError

from server.audit import AuditBacklogFull, AuditWriter
from server.metrics import REGISTRY
from server.models import AuditEntry, utcnow
from sessions import wire
from tests.server.live_server import Live, Seeds, World, on_store, running
from tests.server.postgres import Cluster
from tests.server.test_live_audit import ack, rows_of, station, viewer

WAIT_S = 60.0
"""Deadline for what the writer does on its own (PostgreSQL starting on a shared machine)."""
ORPHAN = 2**31 - 1
"""A patient that does not exist: the database refuses a row naming it, whenever it is tried."""


def row(action: str, patient_id: int | None = None) -> dict[str, Any]:
    return {
        "actor": "system",
        "action": action,
        "entity": "station",
        "entity_id": 1,
        "patient_id": patient_id,
        "old": None,
        "new": {"action": action},
    }


async def until(done: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not done():
        assert time.monotonic() < deadline, f"not within {WAIT_S} s: {what}"
        await asyncio.sleep(0.02)


async def stored(live: Live) -> list[tuple[str, datetime]]:
    """The test rows in the audit log, in the order they were stored."""
    async with live.sessionmaker() as db:
        found = await db.execute(
            select(AuditEntry.action, AuditEntry.at)
            .where(AuditEntry.action.like("test.%"))
            .order_by(AuditEntry.id)
        )
        return [(action, at) for action, at in found]


def lost(reason: str) -> float:
    return REGISTRY.get_sample_value("ankle_audit_rows_lost_total", {"reason": reason}) or 0.0


def logged(caplog: pytest.LogCaptureFixture, *words: str) -> list[str]:
    """The ERROR lines of the audit writer holding every one of ``words``."""
    return [
        r.getMessage()
        for r in caplog.records
        if r.name == "ankle.server.audit"
        and r.levelno == logging.ERROR
        and all(w in r.getMessage() for w in words)
    ]


@asynccontextmanager
async def on_postgres(seeds: Seeds, tmp_path: Path) -> AsyncIterator[tuple[Live, World, Cluster]]:
    template, world = seeds.get("postgres")
    with on_store(seeds, "postgres", tmp_path, template) as settings:
        async with running(settings) as live:
            yield live, world, seeds.cluster


@asynccontextmanager
async def stopped(cluster: Cluster) -> AsyncIterator[None]:
    """PostgreSQL stopped for the block (connections refused), started again after it."""
    await asyncio.to_thread(cluster.stop)
    try:
        yield
    finally:
        await asyncio.to_thread(cluster.start)


@pytest.mark.asyncio
async def test_rows_queued_while_postgresql_is_stopped_arrive_in_order_exactly_once(
    seeds: Seeds, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "ankle.server.audit")
    refused_before = lost("refused")
    async with on_postgres(seeds, tmp_path) as (live, _, cluster):
        writer = AuditWriter(live.sessionmaker)
        writer.retry_max_s = 1.0
        await writer.write(**row("test.0"))  # the writer holds a connection the stop drops
        async with stopped(cluster):
            for action in ("test.1", "test.2"):
                writer.write_soon(row(action))
            # Rows the database refuses once it is back, each for a reason no retry changes:
            writer.write_soon(row("test.orphan", ORPHAN))  # a patient that does not exist
            writer.write_soon({**row("test.long"), "actor": "x" * 65})  # a column's length
            writer.write_soon(row("test.huge", 2**63))  # past 64 bits: the driver refuses it
            for action in ("test.3", "test.4"):
                writer.write_soon(row(action))
            # A command that waits for its row is told at once, not kept waiting.
            with pytest.raises((OSError, DBAPIError)):  # refused, or the connection lost
                await writer.write(**row("test.waited"))
            await until(lambda: writer.failed_tries >= 3, "three tries while it is stopped")
            assert writer.backlog == 7
            queued_by = utcnow()
        await until(lambda: writer.backlog == 0, "the backlog written once it is back")
        rows = await stored(live)
        await writer.close(flush_s=10.0)
    assert [action for action, _ in rows] == ["test.0", "test.1", "test.2", "test.3", "test.4"]
    assert all(at <= queued_by for _, at in rows), "each keeps the time it was queued"
    assert lost("refused") == refused_before + 3
    (said,) = logged(caplog, "test.orphan", "refused")
    assert str(ORPHAN) in said  # the whole row, so it can be entered by hand
    assert logged(caplog, "test.long", "refused") and logged(caplog, "test.huge", "refused")
    assert any("audit rows wait for the database" in r.getMessage() for r in caplog.records), (
        "the outage is in the log while it lasts"
    )


@pytest.mark.asyncio
async def test_a_hold_sent_while_postgresql_is_stopped_is_audited_once_it_is_back(
    seeds: Seeds, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The HOLD reached the device (and the session's event log) while the database was
    away: both its rows reach the audit log once it is back, once each."""
    caplog.set_level(logging.WARNING, "ankle.server.audit")
    async with on_postgres(seeds, tmp_path) as (live, world, cluster):
        async with (
            station(live, world, ack) as link,
            viewer(live, world.t1, world.s1_id) as v,
            stopped(cluster),
        ):
            await v.send("hold-pg-away", "hold")
            result = await v.next_of(wire.CommandResult, "hold-pg-away")
            assert result.ok, result  # HOLD never waits for the database
            assert (await link.next_command()).request_id == "hold-pg-away"
            await until(
                lambda: any(r.name == "ankle.server.audit" for r in caplog.records),
                "the writer has found the database away",
            )
            health = (await live.client.get("/health")).json()
            assert (health["database"], health["audit_backlog"]) == (False, 2), health
        rows = await rows_of(live, world, "hold-pg-away", 2)
        health = (await live.client.get("/health")).json()
        assert (health["database"], health["audit_backlog"]) == (True, 0), health
    assert [r["action"] for r in rows] == ["hold.request", "hold.accepted"]
    assert rows[0]["actor"] == f"user:{world.t1_id}"


@pytest.mark.asyncio
async def test_past_the_backlogs_cap_a_row_is_logged_in_full_and_counted(
    seeds: Seeds, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "ankle.server.audit")
    full_before = lost("backlog_full")
    async with on_postgres(seeds, tmp_path) as (live, _, cluster):
        writer = AuditWriter(live.sessionmaker, backlog_max=3)
        writer.retry_max_s = 1.0
        async with stopped(cluster):
            for i in range(5):
                writer.write_soon(row(f"test.{i}"))
            assert writer.backlog == 3
            assert lost("backlog_full") == full_before + 2
            assert len(logged(caplog, "audit backlog full")) == 1  # said once, then per row
            assert logged(caplog, "test.3", "backlog_full") and logged(caplog, "test.4")
            # A command that waits for its row is refused rather than queued past the cap.
            with pytest.raises(AuditBacklogFull):
                await writer.write(**row("test.waited"))
        await until(lambda: writer.backlog == 0, "the kept rows written once it is back")
        rows = await stored(live)
        await writer.close(flush_s=10.0)
    assert [action for action, _ in rows] == ["test.0", "test.1", "test.2"]
    assert logged(caplog, "has room again")


@pytest.mark.asyncio
async def test_shutdown_writes_what_the_database_takes_in_time_and_logs_the_rest(
    seeds: Seeds, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "ankle.server.audit")
    shutdown_before = lost("shutdown")
    async with on_postgres(seeds, tmp_path) as (live, _, cluster):
        starting: asyncio.Task[None] | None = None
        await asyncio.to_thread(cluster.stop)
        try:
            given_up = AuditWriter(live.sessionmaker)
            given_up.write_soon(row("test.given_up"))
            await until(lambda: given_up.failed_tries >= 1, "a try while it is stopped")
            await given_up.close(flush_s=0.5)
            assert given_up.backlog == 0
            assert lost("shutdown") == shutdown_before + 1
            assert logged(caplog, "1 audit rows were not written before shutdown")
            assert logged(caplog, "test.given_up", "shutdown")

            flushed = AuditWriter(live.sessionmaker)  # backs off up to 15 s between tries
            flushed.write_soon(row("test.flushed"))
            await until(lambda: flushed.failed_tries >= 1, "a try while it is stopped")
            starting = asyncio.create_task(asyncio.to_thread(cluster.start))
            # Shutdown tries every half second: the row is written once PostgreSQL is up.
            await flushed.close(flush_s=WAIT_S)
        finally:
            await (asyncio.to_thread(cluster.start) if starting is None else starting)
        assert [action for action, _ in await stored(live)] == ["test.flushed"]
