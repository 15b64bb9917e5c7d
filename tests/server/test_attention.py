"""What needs attention: found from real uploads, scoped to the therapist's own patients, each
item linking to where it happened, in a number of queries that does not grow with sessions."""

from __future__ import annotations

import asyncio
import collections
import time
import uuid
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
import pytest
from sqlalchemy import event, update

from server.attention import OFFLINE_DAYS
from server.models import Prescription, Session, Station
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import (
    SAMPLE_DTYPE,
    End,
    EndReason,
    SessionEvent,
)
from tests.server.live_server import Live, World, bearer
from tests.server.test_series import recording_bytes, upload_bytes

pytestmark = pytest.mark.both_stores

STRENGTH = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults.model_dump(mode="json")


def recording(
    sid: str,
    station: int,
    patient: int,
    rx: int,
    started: float,
    end: End,
    events: list[SessionEvent],
) -> bytes:
    """A short recording as a station writes it (``test_series.recording_bytes``): 2 s of
    samples from ``started``, ending as ``end`` says."""
    rows = np.zeros(20, SAMPLE_DTYPE)
    rows["t"] = np.arange(20) / 10
    rows["wall"] = started + np.arange(20) / 10
    return recording_bytes(
        sid,
        rows,
        station,
        patient,
        rx,
        events=events,
        reason=end.reason,
        end_text=end.text,
        repetitions=end.repetitions_completed,
    )


async def session(
    live: Live,
    world: World,
    mine: bool,
    reason: EndReason,
    reps: int,
    events: list[tuple[str, str]],
    text: str = "",
) -> int:
    sid = str(uuid.uuid4())
    started = time.time() - 3600
    end = End(
        ended_at=started + 2, reason=reason, sets_completed=1, repetitions_completed=reps, text=text
    )
    evs = [
        SessionEvent(wall=started + 1, kind=k, by=by, detail={"text": text or k})
        for k, by in events
    ]
    station, patient, rx, token = (
        (world.s1_id, world.p1, world.rx1, world.s1)
        if mine
        else (world.s2_id, world.p2, world.rx2, world.s2)
    )
    return await upload_bytes(
        live, token, sid, recording(sid, station, patient, rx, started, end, evs)
    )


@pytest.mark.asyncio
async def test_faults_holds_and_early_ends_of_own_patients_link_to_their_sessions(
    live: Live, world: World
) -> None:
    full = STRENGTH["sets"] * STRENGTH["repetitions"]
    faulted = await session(
        live, world, True, "fault", 2, [("fault", "device")], "supply pressure low"
    )
    held = await session(live, world, True, "stopped", 3, [("hold", "therapist:1")])
    fine = await session(live, world, True, "completed", full, [])
    others = await session(live, world, False, "fault", 1, [("fault", "device")])

    r = await live.client.get("/patients/attention", headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    items = r.json()
    by_session: dict[int, set[str]] = {}
    for item in items:
        if item["session_id"] is not None:
            by_session.setdefault(item["session_id"], set()).add(item["kind"])
            assert item["link"] == f"/app/sessions/{item['session_id']}"
            assert item["patient_id"] == world.p1 and item["patient_name"]
    assert by_session[faulted] == {"fault"}
    assert by_session[held] == {"held", "ended_early"}
    assert fine not in by_session and others not in by_session
    early = next(i for i in items if i["session_id"] == held and i["kind"] == "ended_early")
    assert f"3 of {full} repetitions" in early["text"]
    fault = next(i for i in items if i["session_id"] == faulted)
    assert fault["text"] == "Fault: supply pressure low.", fault  # the fault event's own words

    theirs = (await live.client.get("/patients/attention", headers=bearer(world.t2))).json()
    assert {i["session_id"] for i in theirs if i["session_id"]} == {others}
    admin = (await live.client.get("/patients/attention", headers=bearer(world.admin))).json()
    assert {faulted, held, others} <= {i["session_id"] for i in admin}


@pytest.mark.asyncio
async def test_a_station_quiet_for_days_links_to_the_patient(live: Live, world: World) -> None:
    ago = datetime.now(UTC) - timedelta(days=OFFLINE_DAYS + 1)
    async with live.app.state.sessionmaker() as db:
        await db.execute(update(Station).where(Station.id == world.s1_id).values(last_seen_at=ago))
        await db.execute(
            update(Station).where(Station.id == world.s1_spare_id).values(created_at=ago)
        )
        await db.commit()
    items = (await live.client.get("/patients/attention", headers=bearer(world.t1))).json()
    offline = {i["station_id"]: i for i in items if i["kind"] == "offline"}
    assert set(offline) == {world.s1_id, world.s1_spare_id}
    assert offline[world.s1_id]["link"] == f"/app/patients/{world.p1}"
    assert f"not been seen for {OFFLINE_DAYS + 1} days" in offline[world.s1_id]["text"]
    assert "never connected" in offline[world.s1_spare_id]["text"]


@pytest.mark.asyncio
async def test_the_queries_do_not_grow_with_the_sessions(live: Live, world: World) -> None:
    async def seed(n: int) -> None:
        now = datetime.now(UTC)
        summary = {"events": {"hold": 1}, "faults": [], "repetitions_completed": 1}
        async with live.app.state.sessionmaker() as db:
            db.add_all(
                Session(
                    session_uuid=str(uuid.uuid4()),
                    station_id=world.s1_id,
                    patient_id=world.p1,
                    prescription_id=world.rx1,
                    started_at=now - timedelta(minutes=i + 1),
                    ended_at=now - timedelta(minutes=i),
                    end_reason="stopped",
                    summary={**summary, "repetitions_prescribed": 30},
                    upload_complete=True,
                )
                for i in range(n)
            )
            await db.commit()

    async def statements() -> tuple[int, list[Any]]:
        """The statements the request made, and its answer. Counted by the task that made
        them: a background task of the server's (the upload expiry's pass at start-up)
        also queries the engine now and then, and on a busy machine once did so during the
        first request."""
        seen: collections.Counter[asyncio.Task[Any] | None] = collections.Counter()

        def count(*args: Any) -> None:
            seen[asyncio.current_task()] += 1

        engine = live.app.state.engine.sync_engine
        event.listen(engine, "before_cursor_execute", count)
        try:
            r = await live.client.get("/patients/attention", headers=bearer(world.t1))
        finally:
            event.remove(engine, "before_cursor_execute", count)
        assert r.status_code == 200
        return max(seen.values()), r.json()

    await seed(5)
    few, items = await statements()
    assert sum(i["kind"] == "held" for i in items) == 5
    await seed(300)
    many, items = await statements()
    assert sum(i["kind"] == "held" for i in items) == 305
    assert many == few


async def upload_at(live: Live, world: World, rx: int, started: float, reason: EndReason) -> int:
    """A session of ``rx`` (patient 1's) started at ``started`` (epoch seconds)."""
    sid = str(uuid.uuid4())
    reps = STRENGTH["sets"] * STRENGTH["repetitions"] if reason == "completed" else 2
    end = End(
        ended_at=started + 2, reason=reason, sets_completed=1, repetitions_completed=reps, text=""
    )
    data = recording(sid, world.s1_id, world.p1, rx, started, end, [])
    return await upload_bytes(live, world.s1, sid, data)


@pytest.mark.asyncio
async def test_missed_sessions_are_the_progress_pages_missed_sessions(
    live: Live, world: World
) -> None:
    """Missed means what the progress page's adherence says: per prescribed week from the day
    of the prescription, a week in progress missing nothing yet. The calendar week's share
    used before would have disagreed both ways here: five sessions this week hid a first week
    with three missed, and a prescription six days old would have been missed already."""
    now = datetime.now(UTC)
    body = {**STRENGTH, "title": "Heel raises"}
    r = await live.client.post(
        f"/patients/{world.p1}/prescriptions", json=body, headers=bearer(world.t1)
    )
    assert r.status_code == 201, r.text
    young = r.json()["id"]
    async with live.app.state.sessionmaker() as db:
        await db.execute(
            update(Prescription)
            .where(Prescription.id == world.rx1)
            .values(created_at=now - timedelta(days=7, hours=3))
        )
        await db.execute(
            update(Prescription)
            .where(Prescription.id == young)
            .values(created_at=now - timedelta(days=6))
        )
        await db.commit()
    first_week = (now - timedelta(days=7, hours=2)).timestamp()
    await upload_at(live, world, world.rx1, first_week, "completed")
    await upload_at(live, world, world.rx1, first_week + 3600, "stopped")
    for k in range(5):  # the second week, in progress: done already, but not the first's
        await upload_at(
            live, world, world.rx1, (now - timedelta(minutes=50 - 5 * k)).timestamp(), "completed"
        )

    items = (await live.client.get("/patients/attention", headers=bearer(world.t1))).json()
    missed = [i for i in items if i["kind"] == "missed"]
    assert [i["prescription_id"] for i in missed] == [world.rx1]
    (item,) = missed
    assert item["link"] == f"/app/patients/{world.p1}" and item["patient_id"] == world.p1
    assert "3 of 5 prescribed sessions missed in its week 1" in item["text"], item["text"]
    assert "1 done, 1 ended early" in item["text"], item["text"]

    r = await live.client.get(f"/patients/{world.p1}/progress", headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    (week1, week2) = next(
        a["weeks"] for a in r.json()["adherence"] if a["prescription_id"] == world.rx1
    )
    assert (week1["missed"], week1["completed"], week1["ended_early"]) == (3, 1, 1)
    assert week2["in_progress"] and week2["completed"] == 5
