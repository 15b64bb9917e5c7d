"""Creates that are safe to send again: ``Idempotency-Key`` (``server.idempotency``), a
patient's reference naming one patient, and a 503 that tells a failure before the commit
from one whose outcome is unknown."""

from __future__ import annotations

import asyncio
from datetime import timedelta
from pathlib import Path

import httpx
import pytest
from sqlalchemy import func, make_url, select, update

from server.errors import DATABASE_AWAY, OUTCOME_UNKNOWN, UNKNOWN_CODE
from server.idempotency import KEY_RULE, OTHER_REQUEST, REPLAYED
from server.models import AuditEntry, IdempotencyKey, Patient, Prescription, Station, utcnow
from tests.server.live_server import (
    STRENGTH,
    Live,
    Seeds,
    World,
    bearer,
    on_store,
    running,
)

pytestmark = pytest.mark.both_stores


def _said(r: httpx.Response) -> str:
    """The sentence of a 422 on the Idempotency-Key header (the shape of every 422)."""
    (error,) = r.json()["detail"]
    assert error["loc"] == ["header", "Idempotency-Key"]
    return str(error["msg"])


def keyed(token: str, key: str) -> dict[str, str]:
    return {**bearer(token), "Idempotency-Key": key}


async def _count(live: Live, model: type[Prescription | Patient | Station]) -> int:
    async with live.sessionmaker() as db:
        return int((await db.scalar(select(func.count()).select_from(model))) or 0)


async def _audited(live: Live, action: str) -> int:
    async with live.sessionmaker() as db:
        query = select(func.count()).where(AuditEntry.action == action)
        return int((await db.scalar(query)) or 0)


@pytest.mark.asyncio
async def test_a_prescription_sent_again_with_its_key_is_made_once(
    live: Live, world: World
) -> None:
    path = f"/patients/{world.p1}/prescriptions"
    before = await _count(live, Prescription)
    first = await live.client.post(path, json=STRENGTH, headers=keyed(world.t1, "rx-0001"))
    again = await live.client.post(path, json=STRENGTH, headers=keyed(world.t1, "rx-0001"))
    assert first.status_code == again.status_code == 201, again.text
    assert again.json() == first.json()
    assert again.headers[REPLAYED] == "true" and REPLAYED not in first.headers
    assert await _count(live, Prescription) == before + 1
    assert await _audited(live, "prescription.create") == before + 1
    # Another request with the same key is refused and makes nothing.
    other = {**STRENGTH, "sets": STRENGTH["sets"] + 1}
    r = await live.client.post(path, json=other, headers=keyed(world.t1, "rx-0001"))
    assert (r.status_code, _said(r)) == (422, OTHER_REQUEST[0].upper() + OTHER_REQUEST[1:] + ".")
    # So is the same key on another route.
    r = await live.client.post(
        "/patients", json={"display_name": "P"}, headers=keyed(world.t1, "rx-0001")
    )
    assert (r.status_code, _said(r)) == (422, OTHER_REQUEST[0].upper() + OTHER_REQUEST[1:] + ".")
    # Another therapist's same key is theirs: it replays nothing of t1's.
    r = await live.client.post(
        f"/patients/{world.p2}/prescriptions", json=STRENGTH, headers=keyed(world.t2, "rx-0001")
    )
    assert r.status_code == 201 and REPLAYED not in r.headers
    assert await _count(live, Prescription) == before + 2


@pytest.mark.asyncio
async def test_two_requests_with_one_key_at_once_make_one_record(live: Live, world: World) -> None:
    before = (await _count(live, Prescription), await _count(live, Patient))
    rx = [
        live.client.post(
            f"/patients/{world.p1}/prescriptions", json=STRENGTH, headers=keyed(world.t1, "k-rx")
        )
        for _ in range(4)
    ]
    patients = [
        live.client.post(
            "/patients", json={"display_name": "Twice"}, headers=keyed(world.t1, "k-p")
        )
        for _ in range(4)
    ]
    answers = await asyncio.gather(*rx, *patients)
    assert [r.status_code for r in answers] == [201] * 8, [r.text for r in answers]
    assert len({r.json()["id"] for r in answers[:4]}) == 1
    assert len({r.json()["id"] for r in answers[4:]}) == 1
    assert (await _count(live, Prescription), await _count(live, Patient)) == (
        before[0] + 1,
        before[1] + 1,
    )


@pytest.mark.asyncio
async def test_a_key_is_kept_for_a_day(live: Live, world: World) -> None:
    body = {"display_name": "Daily"}
    first = await live.client.post("/patients", json=body, headers=keyed(world.t1, "day-key"))
    async with live.sessionmaker() as db:
        await db.execute(
            update(IdempotencyKey).values(created_at=utcnow() - timedelta(hours=24, seconds=1))
        )
        await db.commit()
    later = await live.client.post("/patients", json=body, headers=keyed(world.t1, "day-key"))
    assert first.status_code == later.status_code == 201
    assert later.json()["id"] != first.json()["id"] and REPLAYED not in later.headers
    async with live.sessionmaker() as db:
        rows = (await db.execute(select(IdempotencyKey))).scalars().all()
    assert [(r.key, r.answer["id"]) for r in rows] == [("day-key", later.json()["id"])]


@pytest.mark.asyncio
@pytest.mark.parametrize("key", ["", "a b", "ключ", "x" * 129, "tab\tkey"])
async def test_a_malformed_key_is_refused(live: Live, world: World, key: str) -> None:
    before = await _count(live, Patient)
    headers = [(k.encode(), v.encode()) for k, v in keyed(world.t1, key).items()]
    r = await live.client.post("/patients", json={"display_name": "P"}, headers=headers)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["msg"] == KEY_RULE[0].upper() + KEY_RULE[1:] + "."
    assert r.json()["detail"][0]["loc"] == ["header", "Idempotency-Key"]
    assert await _count(live, Patient) == before


@pytest.mark.asyncio
async def test_a_secret_shown_once_is_not_kept_for_a_repeat(live: Live, world: World) -> None:
    path = f"/patients/{world.p1}/stations"
    before = await _count(live, Station)
    first = await live.client.post(path, json={"name": "Hall"}, headers=keyed(world.t1, "st-1"))
    assert first.status_code == 201 and first.json()["token"]
    again = await live.client.post(path, json={"name": "Hall"}, headers=keyed(world.t1, "st-1"))
    station = first.json()["id"]
    assert again.status_code == 409, again.text
    assert again.json()["detail"] == (
        f"this request was done already (id {station}) by an earlier one with the same "
        "Idempotency-Key; its token was shown only in that answer and is not kept: revoke "
        f"station {station} and provision another"
    )
    assert await _count(live, Station) == before + 1
    async with live.sessionmaker() as db:
        kept = (await db.execute(select(IdempotencyKey.answer))).scalars().all()
    assert first.json()["token"] not in str(kept)


@pytest.mark.asyncio
async def test_a_reference_names_one_of_a_therapists_patients(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    body = {"display_name": "Ref", "reference": "MRN-7"}
    answers = await asyncio.gather(
        *(live.client.post("/patients", json=body, headers=t1) for _ in range(3))
    )
    assert sorted(r.status_code for r in answers) == [201, 409, 409], [r.text for r in answers]
    made = next(r.json() for r in answers if r.status_code == 201)
    refused = next(r.json()["detail"] for r in answers if r.status_code == 409)
    assert refused == (
        f"your patient Ref (id {made['id']}) already has the reference MRN-7: a reference "
        "names one patient; open that patient instead, or correct the reference"
    )
    # Another therapist may use it: their patients are not t1's to know of.
    r = await live.client.post("/patients", json=body, headers=bearer(world.t2))
    assert r.status_code == 201, r.text
    # Changing another patient to it is refused too; archived, the sentence says so.
    r = await live.client.patch(f"/patients/{world.p1}", json={"reference": "MRN-7"}, headers=t1)
    assert r.status_code == 409 and "your patient Ref" in r.json()["detail"]
    assert (await live.client.post(f"/patients/{made['id']}/archive", headers=t1)).is_success
    r = await live.client.post("/patients", json=body, headers=t1)
    assert r.status_code == 409
    assert "your archived patient Ref" in r.json()["detail"]
    assert "unarchive and open that patient" in r.json()["detail"]
    # A patient keeps its own reference when saved again.
    await live.client.post(f"/patients/{made['id']}/unarchive", headers=t1)
    r = await live.client.patch(
        f"/patients/{made['id']}", json={"reference": "MRN-7", "notes": "x"}, headers=t1
    )
    assert r.status_code == 200, r.text


@pytest.mark.asyncio
async def test_a_commit_left_unanswered_says_it_may_have_been_saved(
    seeds: Seeds, tmp_path: Path
) -> None:
    """PostgreSQL commits locally, then waits for a synchronous standby that never answers:
    the driver gives up after 5 s. The request was stored: its 503 must not say that
    nothing was done; sent again with its key, it is answered as stored. (PostgreSQL
    only: SQLite commits in the server's process, and its commit either happens or
    fails.)"""
    template, world = seeds.get("postgres")
    cluster = seeds.cluster
    path = f"/patients/{world.p1}/prescriptions"
    with on_store(seeds, "postgres", tmp_path, template) as settings:
        # The test cluster runs with synchronous_commit off (speed); this database waits.
        database = make_url(settings.database_url).database
        cluster.psql(f'ALTER DATABASE "{database}" SET synchronous_commit = on')
        async with running(settings) as live:
            c = live.client
            # Connected before the standby is required, so that only the commit waits.
            r = await c.get(path, headers=bearer(world.t1))
            assert r.status_code == 200
            before = len(r.json())
            cluster.psql("ALTER SYSTEM SET synchronous_standby_names = 'ghost'")
            cluster.psql("SELECT pg_reload_conf()")
            try:
                answers: list[httpx.Response] = [
                    await c.post(path, json=STRENGTH, headers=keyed(world.t1, "ghost-1")),
                    await c.post(path, json=STRENGTH, headers=bearer(world.t1)),
                ]
            finally:
                cluster.psql("ALTER SYSTEM RESET synchronous_standby_names")
                cluster.psql("SELECT pg_reload_conf()")
            for r in answers:
                assert r.status_code == 503, r.text
                assert r.json() == {"detail": OUTCOME_UNKNOWN, "code": UNKNOWN_CODE}
                assert "Retry-After" not in r.headers
                assert r.json()["detail"] != DATABASE_AWAY
            stored = await c.get(path, headers=bearer(world.t1))
            assert len(stored.json()) == before + 2  # both were stored, as said they may be
            again = await c.post(path, json=STRENGTH, headers=keyed(world.t1, "ghost-1"))
            assert again.status_code == 201 and again.headers[REPLAYED] == "true"
            assert again.json()["id"] in {p["id"] for p in stored.json()}
            assert len((await c.get(path, headers=bearer(world.t1))).json()) == before + 2
