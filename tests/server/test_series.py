"""The whole session for charts: columns in the clinic's units, decimated without losing a peak."""

from __future__ import annotations

import hashlib
import math
import time
import uuid
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from device.protocol.messages import DeviceMode
from server.routes.sessions import SERIES_POINTS, minmax_buckets, session_time
from sessions.prescription import AXIS_INDEX, EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import (
    MAGIC,
    SAMPLE_DTYPE,
    DeviceInfo,
    End,
    EndReason,
    Header,
    RecordType,
    SessionEvent,
    encode_json,
    encode_samples,
)
from station.uploader import CHUNK
from tests.server.live_server import Live, World, bearer

pytestmark = pytest.mark.both_stores

HZ = 100.0
N = 18_000  # 3 min at 100 Hz
PITCH = AXIS_INDEX["pitch"]
PEAK_DEG, TROUGH_DEG = 25.0, -17.0
PEAK_AT, TROUGH_AT = 12_345, 4_321
TORQUE_PEAK_NM, TORQUE_PEAK_AT = -31.5, 9_999
GAP = slice(6_000, 6_200)  # chamber 3 unreadable for 2 s
ACTIVE = slice(500, 17_500)
STARTED_AT = 1_700_000_000.0


def samples() -> NDArray[np.void]:
    s = np.zeros(N, SAMPLE_DTYPE)
    s["t"] = 42.0 + np.arange(N) / HZ
    s["wall"] = STARTED_AT + np.arange(N) / HZ
    s["mode"] = int(DeviceMode.READY)
    s["mode"][ACTIVE] = int(DeviceMode.ACTIVE)
    q = np.radians(10.0) * np.sin(2 * np.pi * 0.5 * np.arange(N) / HZ)
    s["pose"][:, PITCH] = q
    s["pose_cmd"][:, PITCH] = 1.1 * q
    s["pose"][PEAK_AT, PITCH] = math.radians(PEAK_DEG)
    s["pose"][TROUGH_AT, PITCH] = math.radians(TROUGH_DEG)
    s["wrench"][:, PITCH] = 40.0 * q
    s["wrench"][TORQUE_PEAK_AT, PITCH] = TORQUE_PEAK_NM
    s["wrench"][:, 2] = -300.0
    s["pressures"] = 3e5
    s["pressures"][:, 0] = 3e5 + 1e5 * np.sin(np.arange(N) / 50.0)
    s["pressures"][GAP, 2] = np.nan
    s["supply"] = 6e5
    s["stiffness"][:, PITCH] = 40.0
    s["stiffness"][9_000:, PITCH] = 80.0  # a live change halfway
    s["damping"][:, PITCH] = 2.0
    return s


def recording_bytes(
    sid: str,
    rows: NDArray[np.void],
    station_id: int = 1,
    patient_id: int = 1,
    rx: int = 1,
    *,
    events: Sequence[SessionEvent] = (),
    reason: EndReason = "completed",
    end_text: str = "",
    repetitions: int = 3,
    kind: ExerciseKind = ExerciseKind.STRENGTH,
    started_at: float | None = None,
) -> bytes:
    """A whole recording (header, samples, events, end record) of the library's ``kind`` as
    the station writes it; it starts at ``started_at`` (the samples' ``wall`` moved with
    it), by default at ``rows["wall"]``'s."""
    body = EXERCISE_LIBRARY[kind].defaults.model_dump(mode="json")
    start = float(rows["wall"][0]) if started_at is None else started_at
    if started_at is not None and len(rows):
        # A station receives its samples during the session it starts: move their clock.
        rows = rows.copy()
        rows["wall"] += started_at - rows["wall"][0]
    header = Header(
        session_id=sid,
        station_id=station_id,
        patient_id=patient_id,
        prescription_id=rx,
        prescription=body,
        device=DeviceInfo(firmware="sim", hardware="sim", telemetry_hz=100, home_pose=[0.0] * 6),
        software="test",
        started_at=start,
    )
    end = End(
        ended_at=start + N / HZ,  # as the whole 3 min session would
        reason=reason,
        text=end_text,
        sets_completed=1,
        repetitions_completed=repetitions,
    )
    blocks = [encode_samples(rows[i : i + 1000]) for i in range(0, len(rows), 1000)]
    return (
        MAGIC
        + encode_json(RecordType.HEADER, header)
        + b"".join(blocks)
        + b"".join(encode_json(RecordType.EVENT, e) for e in events)
        + encode_json(RecordType.END, end)
    )


async def upload(live: Live, world: World, rows: NDArray[np.void], **end: Any) -> int:
    """File a session of the first station's patient the way a station does. ``end``:
    ``recording_bytes``' keywords (events, reason, end_text, kind...)."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, rows, world.s1_id, world.p1, end.pop("rx", world.rx1), **end)
    return await upload_bytes(live, world.s1, sid, data)


async def upload_bytes(live: Live, token: str, sid: str, data: bytes) -> int:
    """Append ``data`` in the station's chunks (one is at most ~1 MiB), then complete: the
    new session's id."""
    c, station = live.client, bearer(token)
    for offset in range(0, len(data), CHUNK):
        r = await c.patch(
            f"/uploads/{sid}",
            content=data[offset : offset + CHUNK],
            headers={**station, "Upload-Offset": str(offset)},
        )
        assert r.status_code == 204, r.text
    body = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    r = await c.post(f"/uploads/{sid}/complete", json=body, headers=station)
    assert r.status_code == 201, r.text
    session_id: int = r.json()["id"]
    return session_id


def full_resolution(rows: NDArray[np.void]) -> dict[str, NDArray[np.float64]]:
    deg = np.degrees
    return {
        "pitch": deg(rows["pose"][:, PITCH].astype(np.float64)),
        "pitch_cmd": deg(rows["pose_cmd"][:, PITCH].astype(np.float64)),
        "torque": rows["wrench"][:, PITCH].astype(np.float64),
        "p1": rows["pressures"][:, 0].astype(np.float64) / 1e5,
        "p3": rows["pressures"][:, 2].astype(np.float64) / 1e5,
        "k": rows["stiffness"][:, PITCH].astype(np.float64),
    }


def decimated_columns(body: dict[str, Any]) -> dict[str, list[float | None]]:
    return {
        "pitch": body["pose_deg"]["pitch"],
        "pitch_cmd": body["pose_cmd_deg"]["pitch"],
        "torque": body["torque_nm"]["pitch"],
        "p1": body["pressures_bar"][0],
        "p3": body["pressures_bar"][2],
        "k": body["stiffness_nm_per_rad"]["pitch"],
    }


@pytest.mark.asyncio
async def test_series_keeps_every_minimum_and_maximum_in_clinic_units(
    live: Live, world: World
) -> None:
    rows = samples()
    sid = await upload(live, world, rows)
    t0 = time.perf_counter()
    r = await live.client.get(f"/sessions/{sid}/series", headers=bearer(world.t1))
    elapsed = time.perf_counter() - t0
    assert r.status_code == 200, r.text
    body = r.json()
    # 3 min at 100 Hz answers in tens of milliseconds on an idle machine of this kind; a
    # busy one may take a second. A decimation gone quadratic takes minutes.
    assert elapsed < 5.0, elapsed

    assert body["samples"] == N
    assert body["decimated"] is True
    assert body["rows"] == SERIES_POINTS == len(body["time_s"])
    assert body["bucket_s"] == pytest.approx((N - 1) / HZ / (SERIES_POINTS // 2))
    t = np.asarray(body["time_s"])
    assert t[0] == 0.0 and t[-1] == pytest.approx((N - 1) / HZ)
    assert (np.diff(t) >= 0).all()
    assert body["axes"] == ["pitch"]

    full = full_resolution(rows)
    for name, column in decimated_columns(body).items():
        assert len(column) == SERIES_POINTS, name
        values = np.array([np.nan if v is None else v for v in column])
        assert np.nanmax(values) == pytest.approx(np.nanmax(full[name]), abs=1e-3), name
        assert np.nanmin(values) == pytest.approx(np.nanmin(full[name]), abs=1e-3), name

    # The single-sample spikes survive, at most one bucket from where they happened.
    pitch = np.array(body["pose_deg"]["pitch"])
    for value, at in ((PEAK_DEG, PEAK_AT), (TROUGH_DEG, TROUGH_AT)):
        (where,) = np.flatnonzero(np.isclose(pitch, value, atol=1e-3))
        assert abs(t[where] - at / HZ) <= body["bucket_s"] + 1e-9
    assert min(body["torque_nm"]["pitch"]) == pytest.approx(TORQUE_PEAK_NM, abs=1e-3)

    # Units: degrees, N·m, N, bar, N·m/rad.
    assert max(body["pose_cmd_deg"]["pitch"]) == pytest.approx(11.0, abs=0.01)
    assert set(body["force_z_n"]) == {-300.0}
    assert set(body["supply_bar"]) == {6.0}
    assert len(body["pressures_bar"]) == 12
    assert set(body["pressures_bar"][5]) == {3.0}
    assert set(body["stiffness_nm_per_rad"]["pitch"]) == {40.0, 80.0}
    assert set(body["damping_nms_per_rad"]["pitch"]) == {2.0}
    assert set(body["pose_deg"]) == {"roll", "pitch", "yaw"}

    # An unreadable chamber is null where a whole bucket had no reading, never NaN.
    p3 = body["pressures_bar"][2]
    assert None in p3
    missing = t[[i for i, v in enumerate(p3) if v is None]]
    assert missing.min() >= GAP.start / HZ and missing.max() <= GAP.stop / HZ

    # Modes at full resolution.
    assert [(m["mode"], m["start_s"], m["end_s"]) for m in body["modes"]] == [
        ("READY", 0.0, ACTIVE.start / HZ),
        ("ACTIVE", ACTIVE.start / HZ, ACTIVE.stop / HZ),
        ("READY", ACTIVE.stop / HZ, (N - 1) / HZ),
    ]


@pytest.mark.asyncio
async def test_a_session_shorter_than_points_comes_whole(live: Live, world: World) -> None:
    rows = samples()
    sid = await upload(live, world, rows)
    r = await live.client.get(
        f"/sessions/{sid}/series", params={"points": 20_000}, headers=bearer(world.t1)
    )
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["decimated"] is False and body["bucket_s"] is None
    assert body["rows"] == N == len(body["time_s"])
    full = full_resolution(rows)
    for name, column in decimated_columns(body).items():
        values = np.array([np.nan if v is None else v for v in column])
        assert np.allclose(values, full[name], atol=1e-3, equal_nan=True), name


@pytest.mark.asyncio
async def test_another_therapists_session_is_not_found(live: Live, world: World) -> None:
    sid = await upload(live, world, samples()[:500])
    c = live.client
    assert (await c.get(f"/sessions/{sid}/series", headers=bearer(world.t2))).status_code == 404
    assert (await c.get(f"/sessions/{sid}/series")).status_code == 401
    assert (await c.get("/sessions/999999/series", headers=bearer(world.t1))).status_code == 404
    r = await c.get(f"/sessions/{sid}/series", headers=bearer(world.admin))
    assert r.status_code == 200 and r.json()["rows"] == 500


@pytest.mark.asyncio
@pytest.mark.parametrize("points", ["9", "20001", "-5", "many"])
async def test_points_out_of_bounds_are_refused(live: Live, world: World, points: str) -> None:
    sid = await upload(live, world, samples()[:100])
    r = await live.client.get(
        f"/sessions/{sid}/series", params={"points": points}, headers=bearer(world.t1)
    )
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["query", "points"]


def test_minmax_buckets_agrees_with_a_plain_loop() -> None:
    rng = np.random.default_rng(7)
    values = rng.normal(size=(1003, 3))
    values[100:140, 1] = np.nan  # a bucket with no finite value in column 1
    values[500, 2] = np.inf
    buckets = 25
    starts, ends, out = minmax_buckets(values, buckets)
    assert starts[0] == 0 and ends[-1] == len(values) - 1
    assert (starts[1:] == ends[:-1] + 1).all()  # the buckets tile the samples
    for b, (s, e) in enumerate(zip(starts, ends, strict=True)):
        for c in range(values.shape[1]):
            chunk = values[s : e + 1, c]
            ok = np.flatnonzero(np.isfinite(chunk))
            if not len(ok):
                assert np.isnan(out[2 * b : 2 * b + 2, c]).all()
                continue
            lo, hi = ok[np.argmin(chunk[ok])], ok[np.argmax(chunk[ok])]
            first, second = (lo, hi) if lo <= hi else (hi, lo)
            assert out[2 * b, c] == chunk[first] and out[2 * b + 1, c] == chunk[second]


def test_session_time_never_runs_backwards() -> None:
    t = np.array([5.0, 5.01, 5.02, 0.5, 0.51, np.nan, 0.53])
    assert np.allclose(session_time(t), [0.0, 0.01, 0.02, 0.02, 0.03, 0.03, 0.03])
