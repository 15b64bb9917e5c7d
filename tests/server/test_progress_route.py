"""GET /patients/{id}/progress over real uploads, and the metrics of sessions stored before
they existed."""

from __future__ import annotations

import hashlib
import time
import uuid
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from sqlalchemy import update

from server.models import Session
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import (
    MAGIC,
    DeviceInfo,
    End,
    Header,
    RecordType,
    encode_json,
    encode_samples,
)
from station.uploader import CHUNK
from tests.server.live_server import Live, World, bearer
from tests.sessions.test_exercise_metrics import lopsided, samples

pytestmark = pytest.mark.both_stores

DAY = 86_400.0


def assessment_rows(trials: list[tuple[float, float]]) -> NDArray[np.void]:
    """A ROM assessment of pitch whose trials reach (plantarflexion, dorsiflexion) degrees."""
    return samples([{"pitch": lopsided(up, down)} for up, down in trials], 2.0)


def recording_data(
    station_id: int,
    patient_id: int,
    rx: int,
    kind: ExerciseKind,
    rows: NDArray[np.void],
    started_at: float,
    reason: str = "completed",
) -> tuple[str, bytes]:
    """A whole recording of ``kind`` as a station writes it, and its session id."""
    sid = str(uuid.uuid4())
    head = Header(
        session_id=sid,
        station_id=station_id,
        patient_id=patient_id,
        prescription_id=rx,
        prescription=EXERCISE_LIBRARY[kind].defaults.model_dump(mode="json"),
        device=DeviceInfo(firmware="sim", hardware="sim", telemetry_hz=100, home_pose=[0.0] * 6),
        software="test",
        started_at=started_at,
    )
    end = End(
        ended_at=started_at + 60,
        reason=reason,  # type: ignore[arg-type]
        sets_completed=1,
        repetitions_completed=1,
    )
    data = (
        MAGIC
        + encode_json(RecordType.HEADER, head)
        + encode_samples(rows)
        + encode_json(RecordType.END, end)
    )
    return sid, data


async def upload(
    live: Live,
    world: World,
    rows: NDArray[np.void],
    rx: int,
    kind: ExerciseKind,
    started_at: float,
    reason: str = "completed",
) -> int:
    """File a session as a station does: append its bytes, then complete."""
    sid, data = recording_data(world.s1_id, world.p1, rx, kind, rows, started_at, reason)
    station = bearer(world.s1)
    for offset in range(0, len(data), CHUNK):
        r = await live.client.patch(
            f"/uploads/{sid}",
            content=data[offset : offset + CHUNK],
            headers={**station, "Upload-Offset": str(offset)},
        )
        assert r.status_code == 204, r.text
    body = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    r = await live.client.post(f"/uploads/{sid}/complete", json=body, headers=station)
    assert r.status_code == 201, r.text
    session_id: int = r.json()["id"]
    return session_id


async def prescribe(live: Live, world: World, kind: ExerciseKind) -> int:
    body = EXERCISE_LIBRARY[kind].defaults.model_dump(mode="json")
    r = await live.client.post(
        f"/patients/{world.p1}/prescriptions", json=body, headers=bearer(world.t1)
    )
    assert r.status_code == 201, r.text
    rx: int = r.json()["id"]
    return rx


@pytest.mark.asyncio
async def test_progress_over_uploaded_assessments(live: Live, world: World) -> None:
    rx = await prescribe(live, world, ExerciseKind.ROM_ASSESSMENT)
    now = time.time()
    history = [
        (now - 20 * DAY, [(20.0, 10.0), (22.0, 12.0)]),  # baseline 21, 11
        (now - 13 * DAY, [(21.0, 11.0), (23.0, 13.0)]),
        (now - 6 * DAY, [(25.0, 10.0), (27.0, 12.0)]),  # plantarflexion +5, beyond 3.92
    ]
    ids = [
        await upload(live, world, assessment_rows(t), rx, ExerciseKind.ROM_ASSESSMENT, at)
        for at, t in history
    ]
    strength = await upload(
        live,
        world,
        samples([{"pitch": lopsided(8, 4)}], 2.0),
        world.rx1,
        ExerciseKind.STRENGTH,
        time.time(),  # after the seeded prescription was made
        reason="stopped",
    )
    t1 = bearer(world.t1)
    r = await live.client.get(f"/patients/{world.p1}/progress", headers=t1)
    assert r.status_code == 200, r.text
    p = r.json()
    assert p["affected_side"] == "left"
    assert p["directions"]["pitch"]["positive"] == "plantarflexion"
    assert p["directions"]["roll"]["positive"] == "eversion"  # a left foot
    assert p["baseline"]["session_id"] == ids[0]
    up = next(m for m in p["mdc"] if (m["axis"], m["sign"]) == ("pitch", 1))
    assert up["mdc95_deg"] == pytest.approx(3.92, abs=1e-3)
    assert (up["trials"], up["assessments"]) == (6, 3)
    kinds = [e["exercise"] for e in p["exercises"]]
    assert kinds == ["strength", "rom_assessment"]
    rom = p["exercises"][1]["measures"]
    plantar = next(m for m in rom if (m["axis"], m["sign"]) == ("pitch", 1))
    assert [pt["value"] for pt in plantar["points"]] == pytest.approx([21, 22, 26], abs=1e-3)
    assert [pt["real_change"] for pt in plantar["points"]] == [False, False, True]
    torque = p["exercises"][0]["measures"]
    assert [pt["session_id"] for pt in torque[0]["points"]] == [strength]

    by_rx = {a["prescription_id"]: a for a in p["adherence"]}
    assert by_rx[world.rx1]["weeks"][-1]["ended_early"] == 1
    # Prescribed just now: one week, in progress, the three older uploads before it.
    assert [w["completed"] for w in by_rx[rx]["weeks"]] == [0]

    # One type, and a date range: points only inside it, the baseline still the first.
    day = time.strftime("%Y-%m-%d", time.gmtime(now - 10 * DAY))
    r = await live.client.get(
        f"/patients/{world.p1}/progress",
        params={"since": day, "kind": "rom_assessment"},
        headers=t1,
    )
    assert r.status_code == 200, r.text
    q = r.json()
    assert [e["exercise"] for e in q["exercises"]] == ["rom_assessment"]
    assert [pt["session_id"] for pt in q["exercises"][0]["measures"][0]["points"]] == [ids[2]]
    assert q["baseline"]["session_id"] == ids[0]

    # Another therapist's patient is not found.
    r = await live.client.get(f"/patients/{world.p1}/progress", headers=bearer(world.t2))
    assert r.status_code == 404


BAD: list[tuple[dict[str, Any], str]] = [
    ({"since": "2026-13-01"}, "since '2026-13-01' is not a date"),
    ({"until": "yesterday"}, "until 'yesterday' is not a date"),
    ({"since": "2026-03-10", "until": "2026-03-01"}, "since (2026-03-10) must be before until"),
    ({"kind": "yoga"}, "kind 'yoga' is not an exercise type"),
]


@pytest.mark.asyncio
async def test_bad_dates_and_kinds_are_a_sentence(live: Live, world: World) -> None:
    for params, words in BAD:
        r = await live.client.get(
            f"/patients/{world.p1}/progress", params=params, headers=bearer(world.t1)
        )
        assert r.status_code == 422, params
        assert words in r.json()["detail"], r.text


@pytest.mark.asyncio
async def test_a_session_stored_before_metrics_gets_them_from_its_recording(
    live: Live, world: World
) -> None:
    sid = await upload(
        live,
        world,
        samples([{"pitch": lopsided(9, 3)}], 2.0),
        world.rx1,
        ExerciseKind.STRENGTH,
        time.time() - DAY,
    )
    t1 = bearer(world.t1)
    fresh = (await live.client.get(f"/sessions/{sid}", headers=t1)).json()["summary"]
    # As an older server stored it: no metrics, and time in target on a strength hold.
    old = {k: v for k, v in fresh.items() if k != "metrics"}
    async with live.sessionmaker() as db:
        await db.execute(update(Session).where(Session.id == sid).values(summary=old))
        await db.commit()
    r = await live.client.get(f"/sessions/{sid}", headers=t1)
    assert r.status_code == 200
    again = r.json()["summary"]
    assert again["metrics"] == fresh["metrics"]
    pitch = again["metrics"]["axes"]["pitch"]
    assert pitch["positive"]["peak_angle_deg"] == pytest.approx(9, abs=1e-3)
    assert pitch["negative"]["peak_angle_deg"] == pytest.approx(3, abs=1e-3)
    async with live.sessionmaker() as db:
        stored = await db.get(Session, sid)
        assert stored is not None and stored.summary is not None
        assert stored.summary["metrics"] == fresh["metrics"]  # computed once, then kept
