"""GET /patients/{id}/progress over real uploads, and the metrics of sessions stored before
they existed."""

from __future__ import annotations

import time
from datetime import UTC, date, datetime, timedelta
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from sqlalchemy import update

from server.models import Session
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import EndReason
from tests.server import test_series as series
from tests.server.live_server import Live, World, bearer
from tests.sessions.test_exercise_metrics import lopsided, samples

pytestmark = pytest.mark.both_stores

DAY = 86_400.0


def assessment_rows(trials: list[tuple[float, float]]) -> NDArray[np.void]:
    """A ROM assessment of pitch whose trials reach (plantarflexion, dorsiflexion) degrees."""
    return samples([{"pitch": lopsided(up, down)} for up, down in trials], 2.0)


async def upload(
    live: Live,
    world: World,
    rows: NDArray[np.void],
    rx: int,
    kind: ExerciseKind,
    started_at: float,
    reason: EndReason = "completed",
) -> int:
    """File a session of ``kind`` started at ``started_at`` as a station does."""
    return await series.upload(
        live, world, rows, rx=rx, kind=kind, started_at=started_at, reason=reason, repetitions=1
    )


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


BAD: list[tuple[dict[str, Any], str, str]] = [
    ({"since": "2026-13-01"}, "since", "since '2026-13-01' is not a day or time"),
    ({"until": "yesterday"}, "until", "until 'yesterday' is not a day or time"),
    # Python reads these as days (ISO week, basic format); the refusal offers YYYY-MM-DD.
    ({"since": "2025-W50"}, "since", "since '2025-W50' is not a day or time"),
    ({"since": "20251207"}, "since", "since '20251207' is not a day or time"),
    ({"until": "20251207T090000Z"}, "until", "until '20251207T090000Z' is not a day"),
    ({"until": "9999-12-31"}, "until", "from 1900-01-01 to 9998-12-31"),
    ({"since": "0001-01-01T00:00:00+01:00"}, "since", "from 1900-01-01 to 9998-12-31"),
    ({"since": "2026-03-10", "until": "2026-03-01"}, "since", "since (2026-03-10) must be before"),
    ({"kind": "yoga"}, "kind", "kind 'yoga' is not an exercise type"),
]
BAD_ZONES: list[tuple[dict[str, Any], str, str]] = [
    # The report's sentence, word for word (server.routes.dates.zone): one rule, one refusal.
    (
        {"tz": "Mars/Olympus_Mons", "since": "2026-12-01"},
        "tz",
        "the time zone (tz) must be an IANA time zone name such as Europe/Berlin or UTC; "
        "got 'Mars/Olympus_Mons'",
    ),
    ({"tz": "localtime"}, "tz", "got 'localtime'"),
    ({"tz": "Europe/" + "x" * 300}, "tz", "such as Europe/Berlin or UTC; got 'Europe/xxx"),
]


@pytest.mark.asyncio
async def test_bad_dates_and_kinds_are_a_sentence_naming_the_parameter(
    live: Live, world: World
) -> None:
    """In the list shape of every 422 (the report's and FHIR's period too); a day past the
    range the server counts is one of them, not an overflow."""
    for params, field, words in BAD + BAD_ZONES:
        r = await live.client.get(
            f"/patients/{world.p1}/progress", params=params, headers=bearer(world.t1)
        )
        assert r.status_code == 422, params
        (error,) = r.json()["detail"]
        assert error["loc"] == ["query", field], r.text
        assert words in error["msg"], r.text
    for params, field, words in BAD_ZONES:  # the session list refuses them alike
        r = await live.client.get("/sessions", params=params, headers=bearer(world.t1))
        assert r.status_code == 422, params
        (error,) = r.json()["detail"]
        assert error["loc"] == ["query", field], r.text
        assert words in error["msg"], r.text


@pytest.mark.asyncio
async def test_the_last_day_the_server_counts_is_a_period_end(live: Live, world: World) -> None:
    for params in (
        {"until": "9998-12-31"},
        {"since": "1900-01-01", "until": "9998-12-31T12:00"},
        # The first day begins on 31 December 1899 in UTC east of Greenwich, the last ends
        # on 1 January 9999 west of it: days of the range all the same.
        {"since": "1900-01-01", "tz": "Pacific/Kiritimati"},
        {"until": "9998-12-31", "tz": "Etc/GMT+12"},
        {"until": "9998-12-31T23:59", "tz": "Etc/GMT+12"},
    ):
        r = await live.client.get(
            f"/patients/{world.p1}/progress", params=params, headers=bearer(world.t1)
        )
        assert r.status_code == 200, r.text


@pytest.mark.asyncio
async def test_the_session_list_takes_times_without_an_offset_and_refuses_past_the_range(
    live: Live, world: World
) -> None:
    """A time that names no offset is UTC (it used to reach the store naive: a 500), and one
    outside the days the server counts is a 422 naming the parameter, as for progress."""
    rx = await prescribe(live, world, ExerciseKind.ROM_ASSESSMENT)
    sid = await upload(
        live,
        world,
        assessment_rows([(20.0, 10.0)]),
        rx,
        ExerciseKind.ROM_ASSESSMENT,
        time.time() - DAY,
    )
    t1 = bearer(world.t1)
    day = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(time.time() - 2 * DAY))
    r = await live.client.get("/sessions", params={"since": day}, headers=t1)
    assert r.status_code == 200, r.text
    assert [s["id"] for s in r.json()] == [sid]
    r = await live.client.get("/sessions", params={"until": day}, headers=t1)
    assert r.status_code == 200 and r.json() == [], r.text
    for field, value in (("until", "9999-12-31T00:00:00"), ("since", "0001-01-01T00:00:00+05:00")):
        r = await live.client.get("/sessions", params={field: value}, headers=t1)
        assert r.status_code == 422, r.text
        (error,) = r.json()["detail"]
        assert error["loc"] == ["query", field]
        assert "from 1900-01-01 to 9998-12-31" in error["msg"]


@pytest.mark.asyncio
async def test_the_session_list_reads_a_day_as_progress_and_the_report_do(
    live: Live, world: World
) -> None:
    """``until=<day>`` left that day's sessions out of the list while progress, the report
    and FHIR included them; ``since=0000-01-01`` was refused without the range."""
    rx = await prescribe(live, world, ExerciseKind.ROM_ASSESSMENT)
    sid = await upload(
        live,
        world,
        assessment_rows([(20.0, 10.0)]),
        rx,
        ExerciseKind.ROM_ASSESSMENT,
        time.time() - DAY,
    )
    t1 = bearer(world.t1)
    r = await live.client.get(f"/sessions/{sid}", headers=t1)
    day = date.fromisoformat(r.json()["started_at"][:10])
    before, after = str(day - timedelta(days=1)), str(day + timedelta(days=1))
    for params, listed in [
        ({"since": str(day), "until": str(day)}, [sid]),
        ({"until": str(day)}, [sid]),
        ({"since": str(day)}, [sid]),
        ({"until": before}, []),
        ({"since": after}, []),
    ]:
        r = await live.client.get("/sessions", params=params, headers=t1)
        assert r.status_code == 200, r.text
        assert [s["id"] for s in r.json()] == listed, params
    progress = await live.client.get(
        f"/patients/{world.p1}/progress", params={"since": str(day), "until": str(day)}, headers=t1
    )
    assert progress.status_code == 200, progress.text
    (exercise,) = progress.json()["exercises"]  # the same day, the same session
    assert (exercise["exercise"], exercise["sessions"]) == ("rom_assessment", 1)
    for field in ("since", "until"):
        r = await live.client.get("/sessions", params={field: "0000-01-01"}, headers=t1)
        assert r.status_code == 422, r.text
        (error,) = r.json()["detail"]
        assert error["loc"] == ["query", field]
        assert "from 1900-01-01 to 9998-12-31" in error["msg"], error["msg"]
    r = await live.client.get("/sessions", params={"since": after, "until": before}, headers=t1)
    assert r.status_code == 422, r.text


LA = "America/Los_Angeles"
EVENING_BEFORE = datetime(2026, 12, 1, 6, 0, tzinfo=UTC)
"""22:00 on 30 November in Los Angeles (UTC-08:00), on 1 December in UTC."""
LAST_EVENING = datetime(2026, 12, 2, 5, 30, tzinfo=UTC)
"""21:30 on 1 December in Los Angeles, on 2 December in UTC."""


async def assess_at(live: Live, world: World, rx: int, at: datetime) -> int:
    rows = assessment_rows([(20.0, 10.0)])
    return await upload(live, world, rows, rx, ExerciseKind.ROM_ASSESSMENT, at.timestamp())


async def listed(live: Live, world: World, params: dict[str, str]) -> list[int]:
    r = await live.client.get("/sessions", params=params, headers=bearer(world.t1))
    assert r.status_code == 200, (params, r.text)
    return [s["id"] for s in r.json()]


@pytest.mark.asyncio
async def test_a_day_is_the_therapists_own_with_tz_and_utcs_without(
    live: Live, world: World
) -> None:
    """A therapist in Los Angeles asking for 1 December got the sessions from 16:00 on 30
    November and missed the evening of the 1st (the days were UTC's); with ``tz`` the days
    are theirs, as in the report. Without it the list and progress read UTC days, as
    before; a time that names its offset is its own instant either way."""
    rx = await prescribe(live, world, ExerciseKind.ROM_ASSESSMENT)
    before = await assess_at(live, world, rx, EVENING_BEFORE)
    last = await assess_at(live, world, rx, LAST_EVENING)
    day = {"since": "2026-12-01", "until": "2026-12-01"}
    for params, ids in [
        ({**day, "tz": LA}, [last]),
        (day, [before]),
        ({**day, "tz": "UTC"}, [before]),
        ({"since": "2026-12-01", "tz": LA}, [last]),
        ({"since": "2026-12-01"}, [last, before]),
        ({"until": "2026-11-30", "tz": LA}, [before]),
        ({"until": "2026-11-30"}, []),
        # A time that names no offset is on the zone's clock; one that does, its own.
        ({"until": "2026-11-30T23:00", "tz": LA}, [before]),
        ({"until": "2026-11-30T23:00"}, []),
        ({"since": "2026-12-02T05:00:00Z", "tz": LA}, [last]),
        ({"since": "2026-12-01T21:00:00-08:00", "tz": "Asia/Tokyo"}, [last]),
    ]:
        assert await listed(live, world, params) == ids, params
    for params, session in [({**day, "tz": LA}, last), (day, before)]:
        r = await live.client.get(
            f"/patients/{world.p1}/progress", params=params, headers=bearer(world.t1)
        )
        assert r.status_code == 200, r.text
        (exercise,) = r.json()["exercises"]
        assert exercise["sessions"] == 1, params
        points = exercise["measures"][0]["points"]
        assert [p["session_id"] for p in points] == [session], params


@pytest.mark.asyncio
async def test_a_day_that_changes_the_clock_is_23_or_25_hours_of_its_zone(
    live: Live, world: World
) -> None:
    """Los Angeles's 1 November 2026 runs from 07:00 UTC (UTC-07:00) to 08:00 UTC the next
    day (UTC-08:00), its 8 March from 08:00 UTC to 07:00 UTC the next day: a fixed offset,
    the day's first or its last, would miss an evening or take a night of the next day."""
    rx = await prescribe(live, world, ExerciseKind.ROM_ASSESSMENT)
    ids = {
        at: await assess_at(live, world, rx, datetime.fromisoformat(at))
        for at in (
            "2026-11-01T06:30:00Z",  # 23:30 on 31 October
            "2026-11-02T07:30:00Z",  # 23:30 on 1 November, an hour after UTC-07:00's day
            "2026-03-08T08:30:00Z",  # 00:30 on 8 March
            "2026-03-09T07:30:00Z",  # 00:30 on 9 March, before UTC-08:00's day ends
        )
    }
    fall = await listed(live, world, {"since": "2026-11-01", "until": "2026-11-01", "tz": LA})
    assert fall == [ids["2026-11-02T07:30:00Z"]]
    spring = await listed(live, world, {"since": "2026-03-08", "until": "2026-03-08", "tz": LA})
    assert spring == [ids["2026-03-08T08:30:00Z"]]


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
