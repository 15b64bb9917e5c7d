"""``GET /station/progress``: the patient's own progress, asked by their station."""

from __future__ import annotations

import uuid
from datetime import timedelta

import pytest

from server.models import Session, utcnow
from tests.server.live_server import Live, World, bearer


def _session(world: World, days_ago: float, low: float, high: float, done: bool = True) -> Session:
    return Session(
        session_uuid=str(uuid.uuid4()),
        station_id=world.s1_id,
        patient_id=world.p1,
        started_at=utcnow() - timedelta(days=days_ago),
        summary={"axes": {"pitch": {"rom_min_deg": low, "rom_max_deg": high}}},
        upload_complete=done,
    )


@pytest.mark.asyncio
async def test_the_station_gets_its_patients_progress_from_uploaded_sessions(
    live: Live, world: World
) -> None:
    r = await live.client.get("/station/progress", headers=bearer(world.s1))
    assert r.status_code == 200, r.text
    assert r.json() == {"sessions_last_7_days": 0, "sessions_total": 0, "directions": []}
    async with live.sessionmaker() as db:
        db.add_all(
            [
                _session(world, 15, -6.0, 10.0),
                _session(world, 2, -8.0, 14.0),
                _session(world, 1, -20.0, 30.0, done=False),  # still uploading: not counted
            ]
        )
        await db.commit()
    r = await live.client.get("/station/progress", headers=bearer(world.s1))
    assert r.status_code == 200, r.text
    body = r.json()
    assert (body["sessions_last_7_days"], body["sessions_total"]) == (1, 2)
    found = {d["direction"]: (d["first_week_deg"], d["latest_deg"]) for d in body["directions"]}
    assert found == {"plantarflexion": (10.0, 14.0), "dorsiflexion": (6.0, 8.0)}
    # Another station's patient has none of these; a therapist's token is not a station's.
    r = await live.client.get("/station/progress", headers=bearer(world.s2))
    assert r.json()["sessions_total"] == 0
    r = await live.client.get("/station/progress", headers=bearer(world.t1))
    assert r.status_code == 403  # a valid token, of the other kind of caller
