"""A database that goes away under a running server: every route answers 503 with a
sentence and ``Retry-After`` (never a 500), ``/health`` says so, and the first request once
it is back works (pooled connections are pinged before use)."""

from __future__ import annotations

import asyncio
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import asyncpg
import httpx
import pytest
from sqlalchemy import select
from websockets.exceptions import InvalidStatus

from server.audit import AuditWriter
from server.db import DATABASE_WAIT_S
from server.errors import AWAY_CODE, DATABASE_AWAY
from server.models import AuditEntry
from server.routes.health import HEALTH_WAIT_S
from tests.server.live_server import Live, Seeds, World, bearer, on_store, running
from tests.server.postgres import Cluster
from tests.server.ws_client import station_ws, viewer_ws


async def _answers_while_away(live: Live, world: World) -> list[httpx.Response]:
    c, t1 = live.client, bearer(world.t1)
    return [
        await c.get("/patients", headers=t1),
        await c.get(f"/patients/{world.p1}", headers=t1),
        await c.post("/patients", json={"display_name": "Nobody"}, headers=t1),
        await c.post("/auth/login", json={"email": "t1@clinic.test", "password": "x" * 12}),
        await c.get("/station/prescriptions", headers=bearer(world.s1)),
    ]


async def _handshakes_while_away(live: Live, world: World) -> list[int]:
    """The HTTP status of each live link's handshake (a station's, a therapist's view)."""
    statuses = []
    for link in (station_ws(live, world.s1), viewer_ws(live, world.t1, world.s1_id)):
        with pytest.raises(InvalidStatus) as refused:
            async with link:
                pass  # pragma: no cover
        statuses.append(refused.value.response.status_code)
    return statuses


def _assert_away(answers: list[httpx.Response]) -> None:
    for r in answers:
        assert r.status_code == 503, (r.request.url, r.text)
        assert r.json() == {"detail": DATABASE_AWAY, "code": AWAY_CODE}
        assert int(r.headers["Retry-After"]) > 0


async def _health_says_away(live: Live) -> None:
    r = await live.client.get("/health")
    assert r.status_code == 503
    assert r.json()["database"] is False and r.json()["status"] == "degraded"
    assert "Retry-After" in r.headers


async def _works_again(live: Live, world: World) -> None:
    """The very first request after the database is back is answered normally."""
    r = await live.client.get("/patients", headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    assert {p["id"] for p in r.json()} == {world.p1}
    r = await live.client.get("/health")
    assert r.status_code == 200 and r.json()["database"] is True


async def _run_off_loop(f: Callable[[], None]) -> None:
    await asyncio.to_thread(f)


@pytest.mark.asyncio
async def test_postgresql_stopped_and_started_under_a_running_server(
    seeds: Seeds, tmp_path: Path
) -> None:
    template, world = seeds.get("postgres")
    cluster: Cluster = seeds.cluster
    with on_store(seeds, "postgres", tmp_path, template) as settings:
        async with running(settings) as live:
            await _works_again(live, world)  # the pool now holds live connections
            await _run_off_loop(cluster.stop)
            try:
                _assert_away(await _answers_while_away(live, world))
                await _health_says_away(live)
                assert await _handshakes_while_away(live, world) == [503, 503]
            finally:
                await _run_off_loop(cluster.start)
            await _works_again(live, world)
            # A restart the server never saw (its pooled connections all dropped).
            await _run_off_loop(cluster.restart)
            await _works_again(live, world)


@pytest.mark.asyncio
async def test_sqlite_locked_past_its_busy_timeout(live: Live, world: World) -> None:
    """Another process holding SQLite's write lock (a backup, a stuck writer) is a 503 for
    the writes that wait on it past the busy timeout, and reads go on."""
    db_file = live.settings.data_dir / "ankle.db"
    holder = sqlite3.connect(db_file, isolation_level=None)
    try:
        holder.execute("BEGIN EXCLUSIVE")
        started = time.monotonic()
        r = await live.client.post(
            "/patients", json={"display_name": "Waits"}, headers=bearer(world.t1), timeout=60
        )
        assert time.monotonic() - started >= 4.0  # it did wait for the lock first
        _assert_away([r])
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    r = await live.client.post("/patients", json={"display_name": "Now"}, headers=bearer(world.t1))
    assert r.status_code == 201, r.text


@pytest.mark.asyncio
async def test_the_live_audit_writer_outlives_a_postgresql_restart(
    seeds: Seeds, tmp_path: Path
) -> None:
    """The live links' audit writer keeps one connection; PostgreSQL restarting under it (the
    connection dropped) costs no row: the next batch goes through on a new connection."""
    template, _ = seeds.get("postgres")
    cluster: Cluster = seeds.cluster
    with on_store(seeds, "postgres", tmp_path, template) as settings:
        async with running(settings) as live:
            writer = AuditWriter(live.sessionmaker)

            def row(action: str) -> dict[str, Any]:
                return {
                    "actor": "system",
                    "action": action,
                    "entity": "station",
                    "entity_id": 1,
                    "patient_id": None,
                    "old": None,
                    "new": {"n": 1},
                }

            await writer.write(**row("test.before"))
            # A clean stop drops the connection as a restart does; the test cluster runs
            # without synchronous commit, so a crash could lose the committed row itself.
            await _run_off_loop(cluster.stop)
            await _run_off_loop(cluster.start)
            await writer.write(**row("test.after"))
            await writer.close(flush_s=10.0)
            async with live.sessionmaker() as db:
                actions = (
                    await db.execute(
                        select(AuditEntry.action).where(AuditEntry.action.like("test.%"))
                    )
                ).scalars()
                assert sorted(actions) == ["test.after", "test.before"]


@pytest.mark.asyncio
async def test_postgresql_that_stops_answering_is_a_503_within_the_wait(
    seeds: Seeds, tmp_path: Path
) -> None:
    """A PostgreSQL server that accepts connections and answers nothing (stopped, swapping,
    stuck on its disk) holds no request past the database wait: the routes answer 503 with
    the sentence, ``/health`` says ``database: false``. Before, every route and ``/health``
    waited until the database answered again (150 s)."""
    template, world = seeds.get("postgres")
    cluster: Cluster = seeds.cluster
    with on_store(seeds, "postgres", tmp_path, template) as settings:
        async with running(settings) as live:
            await _works_again(live, world)  # pooled connections to a server that will hang
            with cluster.frozen():
                started = time.monotonic()
                await _health_says_away(live)
                health_s = time.monotonic() - started
                started = time.monotonic()
                answers = await _answers_while_away(live, world)
                routes_s = time.monotonic() - started
            print(f"health {health_s:.1f} s, {len(answers)} routes {routes_s:.1f} s")
            _assert_away(answers)
            # Within its wait and a margin for a busy machine: the check past the wait was
            # cancelled, and the cancel waited on the frozen server (4.0 s).
            assert health_s < HEALTH_WAIT_S + 1.5
            await _works_again(live, world)


@pytest.mark.asyncio
async def test_a_postgresql_table_locked_elsewhere_is_a_503_after_the_lock_timeout(
    seeds: Seeds, tmp_path: Path
) -> None:
    """Another client holding a table's lock (a long migration, a DBA's LOCK TABLE) is a 503
    for the requests that wait on it past the lock timeout, as SQLite's busy timeout; before,
    they waited as long as the lock was held."""
    template, world = seeds.get("postgres")
    with on_store(seeds, "postgres", tmp_path, template) as settings:
        async with running(settings) as live:
            dsn = settings.database_url.replace("postgresql+asyncpg", "postgresql")
            holder = await asyncpg.connect(dsn)
            try:
                locked = holder.transaction()
                await locked.start()
                await holder.execute("LOCK TABLE patients IN ACCESS EXCLUSIVE MODE")
                started = time.monotonic()
                r = await live.client.get("/patients", headers=bearer(world.t1))
                waited = time.monotonic() - started
                await locked.rollback()
            finally:
                await holder.close()
            print(f"answered {r.status_code} after {waited:.1f} s")
            assert waited >= DATABASE_WAIT_S * 0.8  # it did wait for the lock first
            _assert_away([r])
            await _works_again(live, world)
