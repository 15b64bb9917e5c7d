"""The audit log: a row for every change, with old and new values, and no way to rewrite it."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from sqlalchemy import Executable, delete, select, text, update
from sqlalchemy.exc import DBAPIError

from server.audit import AuditWriter
from server.models import AuditEntry
from tests.server.live_server import STRENGTH, Live, World, bearer

pytestmark = pytest.mark.both_stores


async def newest(live: Live, world: World, n: int = 1, **filters: Any) -> list[dict[str, Any]]:
    r = await live.client.get("/audit", params={"limit": n, **filters}, headers=bearer(world.admin))
    assert r.status_code == 200
    rows: list[dict[str, Any]] = r.json()
    return rows


@pytest.mark.asyncio
async def test_every_mutation_leaves_a_row_with_old_and_new(live: Live, world: World) -> None:
    c, t1, admin = live.client, bearer(world.t1), bearer(world.admin)
    actor = f"user:{world.t1_id}"

    async def check(action: str, entity_id: int, old: Any, new: Any, who: str = actor) -> None:
        (row,) = await newest(live, world)
        assert (row["action"], row["actor"], row["entity_id"]) == (action, who, str(entity_id))
        assert (row["old"], row["new"]) == (old, new)

    r = await c.post("/patients", json={"display_name": "Neu", "birth_year": 1960}, headers=t1)
    p = r.json()["id"]
    await check(
        "patient.create",
        p,
        None,
        {
            "therapist_id": world.t1_id,
            "display_name": "Neu",
            "reference": None,
            "birth_year": 1960,
            "affected_side": None,
            "weight_kg": None,
            "notes": "",
        },
    )

    await c.patch(f"/patients/{p}", json={"notes": "knee too", "birth_year": 1960}, headers=t1)
    await check("patient.update", p, {"notes": ""}, {"notes": "knee too"})

    r = await c.post(f"/patients/{p}/prescriptions", json=STRENGTH, headers=t1)
    rx = r.json()["id"]
    await check(
        "prescription.create", rx, None, {"status": "active", "version": 1, "body": STRENGTH}
    )

    await c.patch(f"/prescriptions/{rx}", json={**STRENGTH, "sets": 1}, headers=t1)
    await check(
        "prescription.update",
        rx,
        {"version": 1, "body": {"sets": 3}},
        {"version": 2, "body": {"sets": 1}},
    )

    await c.post(f"/prescriptions/{rx}/cancel", headers=t1)
    await check("prescription.cancel", rx, {"status": "active"}, {"status": "cancelled"})

    r = await c.post(f"/patients/{p}/stations", json={"name": "Kitchen"}, headers=t1)
    s = r.json()["id"]
    await check("station.provision", s, None, {"name": "Kitchen", "patient_id": p})

    await c.post(f"/stations/{s}/revoke", headers=admin)
    admin_id = (await c.get("/auth/me", headers=admin)).json()["id"]
    await check("station.revoke", s, {"revoked": False}, {"revoked": True}, f"user:{admin_id}")
    await c.post(f"/stations/{s}/revoke", headers=admin)  # again: nothing changes, no row
    assert (await newest(live, world))[0]["action"] == "station.revoke"
    assert len(await newest(live, world, 10, action="station.revoke")) == 1

    secret = "a tall oak by the river"
    user = {"email": "u@clinic.test", "name": "U", "role": "therapist", "password": secret}
    r = await c.post("/users", json=user, headers=admin)
    (row,) = await newest(live, world)
    assert (row["action"], row["new"]) == (
        "user.create",
        {"email": "u@clinic.test", "name": "U", "role": "therapist"},
    )
    assert secret not in str(row)


@pytest.mark.asyncio
async def test_reads_and_refusals_leave_no_row(live: Live, world: World) -> None:
    before = await newest(live, world, 500)
    c = live.client
    await c.get(f"/patients/{world.p1}", headers=bearer(world.t1))
    await c.patch(f"/patients/{world.p1}", json={"notes": "x"}, headers=bearer(world.t2))
    await c.patch(f"/patients/{world.p1}", json={"notes": "x"}, headers=bearer(world.admin))
    await c.patch(f"/patients/{world.p1}", json={"display_name": None}, headers=bearer(world.t1))
    assert await newest(live, world, 500) == before


@pytest.mark.asyncio
async def test_a_therapist_reads_only_their_patients_rows(live: Live, world: World) -> None:
    async def rows(who: str, **params: Any) -> list[dict[str, Any]]:
        r = await live.client.get("/audit", params=params, headers=bearer(who))
        out: list[dict[str, Any]] = r.json()
        return out

    mine = await rows(world.t1)
    assert mine and {r["patient_id"] for r in mine} == {world.p1}
    assert await rows(world.t1, patient_id=world.p2) == []
    everything = await rows(world.admin)
    assert {r["action"] for r in everything} >= {"user.create", "patient.create"}
    assert [r["id"] for r in everything] == sorted((r["id"] for r in everything), reverse=True)
    page = await rows(world.admin, limit=2, offset=1)
    assert [r["id"] for r in page] == [r["id"] for r in everything[1:3]]
    created = await rows(world.admin, action="patient.create")
    assert {r["patient_id"] for r in created} == {world.p1, world.p2}
    r = await live.client.get("/audit", params={"limit": 0}, headers=bearer(world.admin))
    assert r.status_code == 422


@pytest.mark.asyncio
async def test_the_database_refuses_to_change_or_delete_audit_rows(live: Live, store: str) -> None:
    async with live.sessionmaker() as db:
        first = (await db.execute(select(AuditEntry).order_by(AuditEntry.id))).scalars().first()
        assert first is not None
        first_id, first_action = first.id, first.action
        statements: list[Executable] = [
            update(AuditEntry).where(AuditEntry.id == first_id).values(action="forged"),
            delete(AuditEntry).where(AuditEntry.id == first_id),
            text("DELETE FROM audit_log"),
            # SQLite has no TRUNCATE; its DELETE without WHERE is refused above.
            *([text("TRUNCATE audit_log")] if store == "postgres" else []),
        ]
        for statement in statements:
            with pytest.raises(DBAPIError, match="audit log is append-only"):
                await db.execute(statement)
            await db.rollback()
        again = await db.get(AuditEntry, first_id, populate_existing=True)
        assert again is not None and again.action == first_action
        # Appending still works.
        db.add(AuditEntry(actor="system", action="test.append", entity="test", entity_id="1"))
        await db.commit()


def _row(action: str, entity_id: int, patient_id: int | None, old: Any) -> dict[str, Any]:
    return {
        "actor": "system",
        "action": action,
        "entity": "station",
        "entity_id": entity_id,
        "patient_id": patient_id,
        "old": old,
        "new": {"ok": True},
    }


@pytest.mark.asyncio
async def test_the_live_writer_commits_a_burst_and_a_refused_row_alone(live: Live) -> None:
    """The live links' writer: a burst of rows lands, every row with its time and JSON
    values; a row the database refuses (a patient that does not exist) fails for its waiter
    only."""
    writer = AuditWriter(live.sessionmaker)
    actions = [f"test.burst{i}" for i in range(30)]
    waits = []
    for i, action in enumerate(actions):
        values = _row(action, i, None, {"k": [i, 1.5]})
        if i % 2:
            writer.write_soon(values)
        else:
            waits.append(asyncio.ensure_future(writer.write(**values)))
    bad = _row("test.orphan", 1, 2**31 - 1, None)
    refused = asyncio.ensure_future(writer.write(**bad))
    await asyncio.gather(*waits)
    with pytest.raises(DBAPIError):
        await refused
    await writer.close(flush_s=10.0)
    async with live.sessionmaker() as db:
        rows = (
            (
                await db.execute(
                    select(AuditEntry)
                    .where(AuditEntry.action.like("test.%"))
                    .order_by(AuditEntry.id)
                )
            )
            .scalars()
            .all()
        )
    assert sorted(r.action for r in rows) == sorted(actions)  # the refused one not among them
    assert all(r.at is not None for r in rows)
    third = next(r for r in rows if r.action == "test.burst3")
    assert (third.old, third.new, third.entity_id) == ({"k": [3, 1.5]}, {"ok": True}, "3")
