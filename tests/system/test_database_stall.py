"""A database that does not answer, with real processes: the therapist's HOLD still reaches
the device at once, and a K/B change asked just before it, which waits for its audit row, is
refused and never applied.

The live link handled one command at a time, so the HOLD waited behind the K/B change's row:
with SQLite's file held by another writer the device held 4.85 s late, and with PostgreSQL
stalled it did not hold until the database answered (12 s), then took the K change asked
12 s before. Here another client holds the audit log (SQLite: the file's write lock;
PostgreSQL: ``LOCK TABLE``, so that every write of it waits, as on a stalled server).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import httpx
import pytest
from pydantic import BaseModel
from sqlalchemy import text
from sqlalchemy.ext.asyncio import create_async_engine

from server.hub import AUDIT_WAIT_S
from sessions import wire
from sessions.prescription import AXIS_INDEX
from tests.server.live_server import sqlite_write_locked
from tests.system.harness import (
    System,
    active,
    next_of,
    short_strength,
    start_exercise,
    status_until,
    until,
)

WAIT_S = 20.0
"""Deadline for what the system does on its own (a shared 2-core machine)."""


@asynccontextmanager
async def audit_log_held(system: System) -> AsyncIterator[None]:
    url = system.server_env.get("ANKLE_DATABASE_URL")
    if url is None:
        async with sqlite_write_locked(system.data_dir / "server" / "ankle.db"):
            yield
        return
    engine = create_async_engine(url)
    try:
        async with engine.connect() as conn:
            await conn.execute(text("LOCK TABLE audit_log IN ACCESS EXCLUSIVE MODE"))
            try:
                yield
            finally:
                await conn.rollback()
    finally:
        await engine.dispose()


@pytest.mark.asyncio
async def test_a_hold_reaches_the_device_while_a_kb_change_waits_for_the_database(
    system: System, therapist: httpx.AsyncClient
) -> None:
    pitch = AXIS_INDEX["pitch"]
    body = short_strength("Held database", repetitions=8)
    _, ws, _ = await start_exercise(system, therapist, body)
    try:
        await active(ws, 30)
        async with audit_log_held(system):
            t0 = time.monotonic()
            kb = wire.Command(request_id="kb", action="set_impedance", stiffness={"pitch": 55.0})
            await ws.send(kb.model_dump_json())
            await asyncio.sleep(0.2)
            await ws.send(wire.Command(request_id="hold", action="hold").model_dump_json())
            held_at = answered_at = None
            answer: wire.CommandResult | None = None
            while held_at is None or answer is None:
                message = await next_of(ws, BaseModel, WAIT_S - (time.monotonic() - t0))
                now = time.monotonic() - t0
                if isinstance(message, wire.StatusMsg) and message.device_mode == "HOLD":
                    assert message.hold is not None and message.hold.code == "therapist"
                    held_at = held_at or now
                if isinstance(message, wire.CommandResult) and message.request_id == "kb":
                    answer, answered_at = message, now
            # The device held before the K/B change was answered, and that within its bound.
            assert answered_at is not None and held_at < answered_at, (held_at, answered_at)
            assert (answer.ok, answer.code) == (False, "AUDIT"), answer
            assert f"within {AUDIT_WAIT_S:g} s" in answer.text, answer
        # The database answers again: the change was never sent, so Resume renders the
        # prescription's K, not the 55 asked while the database was held.
        await ws.send(wire.Command(request_id="resume", action="resume").model_dump_json())
        await status_until(ws, lambda s: s.hold is None and s.phase == "running", WAIT_S)
        moving = await until(ws, wire.TelemetryMsg, lambda t: t.mode == "ACTIVE", WAIT_S)
        assert moving.stiffness[pitch] == pytest.approx(40.0), moving.stiffness
        await ws.send(wire.Command(request_id="stop", action="stop").model_dump_json())
    finally:
        await ws.close()
    # Its audit: refused (after its request row, if the database took that late), no change.
    deadline = time.monotonic() + WAIT_S
    while not (rows := (await therapist.get("/api/v1/audit", params={"request_id": "kb"})).json()):
        assert time.monotonic() < deadline, "the K/B change's refusal was never audited"
        await asyncio.sleep(0.2)
    assert [row["action"] for row in rows[::-1]] in (
        ["impedance.refused"],
        ["impedance.request", "impedance.refused"],
    ), rows
    r = await therapist.get("/api/v1/audit", params={"action": "impedance.change"})
    assert r.json() == [], r.json()
