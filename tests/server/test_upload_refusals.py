"""Uploads that are wrong, or that meet a full disk: a 4xx or 507 with a sentence, nothing
acknowledged lost, and the upload completes once the station sends what is right."""

from __future__ import annotations

import asyncio
import errno
import hashlib
import json
import logging
import math
import os
import struct
import time
import uuid
import zlib
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sqlalchemy import event, text, update

from device.protocol.messages import DeviceMode
from server.errors import DISK_FULL
from server.models import Upload, utcnow
from sessions.prescription import ExerciseKind
from station.spool import Spool
from station.uploader import CHUNK, Uploader
from tests.server.live_server import Live, Seeds, Store, World, bearer, on_store, running
from tests.server.test_series import PITCH, STARTED_AT, N, recording_bytes, samples

pytestmark = pytest.mark.both_stores


def record(kind: int, payload: bytes) -> bytes:
    """One record as ``sessions.recording`` documents it: type, length, payload, CRC-32."""
    head = struct.pack("<BI", kind, len(payload))
    return head + payload + struct.pack("<I", zlib.crc32(payload, zlib.crc32(head)))


def recording_with(sid: str, world: World, header: dict[str, Any], end: dict[str, Any]) -> bytes:
    """A recording whose header and end records are exactly this JSON (CRCs valid)."""
    good = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    first = _records(good)
    base_header, base_end = json.loads(first[0][1]), json.loads(first[-1][1])
    out = good[:8] + record(1, json.dumps({**base_header, **header}).encode())
    for kind, payload in first[1:-1]:
        out += record(kind, payload)
    return out + record(4, json.dumps({**base_end, **end}).encode())


def _records(data: bytes) -> list[tuple[int, bytes]]:
    out, pos = [], 8
    while pos < len(data):
        kind, length = struct.unpack_from("<BI", data, pos)
        out.append((kind, data[pos + 5 : pos + 5 + length]))
        pos += 5 + length + 4
    return out


async def put(live: Live, world: World, sid: str, data: bytes) -> int:
    """Send ``data`` the way the station does; the status of the first refusal, or 204."""
    for offset in range(0, len(data), CHUNK):
        r = await live.client.patch(
            f"/uploads/{sid}",
            content=data[offset : offset + CHUNK],
            headers={**bearer(world.s1), "Upload-Offset": str(offset)},
        )
        if r.status_code != 204:
            return r.status_code
    return 204


async def complete(live: Live, world: World, sid: str, data: bytes) -> Any:
    body = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    return await live.client.post(f"/uploads/{sid}/complete", json=body, headers=bearer(world.s1))


async def held(live: Live, world: World, sid: str) -> int | None:
    r = await live.client.head(f"/uploads/{sid}", headers=bearer(world.s1))
    return None if r.status_code == 404 else int(r.headers["Upload-Offset"])


@pytest.mark.asyncio
@pytest.mark.parametrize(
    "payload", [b"{not json", b'{"session_id": "\\ud800"}', b"[]", b'{"started_at": NaN}']
)
async def test_a_header_record_with_a_valid_crc_and_bad_json_is_a_422(
    live: Live, world: World, payload: bytes
) -> None:
    sid = str(uuid.uuid4())
    data = b"ANKLREC1" + record(1, payload)
    r = await live.client.patch(
        f"/uploads/{sid}", content=data, headers={**bearer(world.s1), "Upload-Offset": "0"}
    )
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith("the header record is not valid: ")
    assert await held(live, world, sid) is None


BAD_TIMES = [math.nan, -1.0, 1e300, math.inf]


@pytest.mark.asyncio
@pytest.mark.parametrize("value", BAD_TIMES, ids=str)
async def test_a_bad_start_time_is_refused_with_the_first_chunk(
    live: Live, world: World, value: float
) -> None:
    sid = str(uuid.uuid4())
    bad = recording_with(sid, world, {"started_at": value}, {})
    assert await put(live, world, sid, bad) == 422
    assert await held(live, world, sid) is None
    good = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, good) == 204
    assert (await complete(live, world, sid, good)).status_code == 201


@pytest.mark.asyncio
@pytest.mark.parametrize("value", BAD_TIMES, ids=str)
async def test_a_bad_end_time_is_a_422_and_the_upload_can_be_sent_again(
    live: Live, world: World, value: float
) -> None:
    sid = str(uuid.uuid4())
    bad = recording_with(sid, world, {}, {"ended_at": value})
    assert await put(live, world, sid, bad) == 204
    r = await complete(live, world, sid, bad)
    assert r.status_code == 422, r.text
    assert "ended_at" in r.json()["detail"] and "upload the session again" in r.json()["detail"]
    # Nothing was filed, the bytes are gone, and the server keeps no half-moved file.
    assert await held(live, world, sid) is None
    assert not list((live.settings.data_dir / "sessions").glob("*.rec"))
    good = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, good) == 204
    r = await complete(live, world, sid, good)
    assert r.status_code == 201, r.text
    assert r.json()["started_at"].startswith("2023-11-14")


async def refused_and_discarded(live: Live, world: World, sid: str, bad: bytes) -> str:
    """Send ``bad`` whole, expect ``complete`` to refuse it; check that nothing of it is
    kept and that the right recording then goes through. Returns the refusal's detail."""
    assert await put(live, world, sid, bad) == 204
    r = await complete(live, world, sid, bad)
    assert r.status_code == 422, r.text
    detail: str = r.json()["detail"]
    assert detail.endswith("upload the session again"), detail
    assert await held(live, world, sid) is None
    assert not part_file(live, sid).exists()
    assert not list((live.settings.data_dir / "sessions").glob("*.rec"))
    good = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, good) == 204
    assert (await complete(live, world, sid, good)).status_code == 201
    return detail


def part_file(live: Live, sid: str) -> Path:
    return live.settings.data_dir / "uploads" / f"{sid}.part"


def _ages_long() -> np.ndarray:
    """Every value finite, but the device clock runs 1e308 s, the pitch torque at float32's
    floor: a time-weighted mean torque past what a float holds."""
    s = samples()
    s["t"] = np.linspace(0.0, 1e308, len(s))
    s["wrench"][:, PITCH] = -3.4e38
    return s


def _received_in_year_5138() -> np.ndarray:
    s = samples()[:200]
    s["wall"][100] = 1e11
    return s


def _sways_at_no_speed() -> np.ndarray:
    """Plausible times (a device clock that hardly moves), but swings from float32's floor to
    its ceiling in no time: a sway speed no float holds."""
    s = samples()[:200]
    s["mode"] = int(DeviceMode.ACTIVE)
    s["t"] = np.arange(len(s)) * 1e-300
    s["pose"][::2, PITCH], s["pose"][1::2, PITCH] = 3.4e38, -3.4e38
    return s


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("rows", "kind", "named"),
    [
        (_ages_long, ExerciseKind.STRENGTH, "device time t covers 1e+308 s"),
        (_received_in_year_5138, ExerciseKind.STRENGTH, "a sample's wall time (1e+11)"),
        (_sways_at_no_speed, ExerciseKind.BALANCE, "mean_speed_deg_s"),
    ],
    ids=["device-time-1e308", "wall-in-5138", "sway-speed-infinite"],
)
async def test_a_recording_of_no_plausible_session_is_a_422_and_discarded(
    live: Live, world: World, rows: Any, kind: ExerciseKind, named: str
) -> None:
    """A clinician is never shown a session of 1e308 s or an infinite number: the recording
    is refused, naming what is wrong, not filed, and dropped like any refused upload."""
    sid = str(uuid.uuid4())
    bad = recording_bytes(sid, rows(), world.s1_id, world.p1, world.rx1, kind=kind)
    detail = await refused_and_discarded(live, world, sid, bad)
    assert detail.startswith("not a valid recording: ") and named in detail, detail


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("end", "named"),
    [
        ({"sets_completed": -5}, "sets_completed"),
        ({"repetitions_completed": -(2**62)}, "repetitions_completed"),
        ({"repetitions_completed": 10**30}, "repetitions_completed"),
        ({"sets_completed": 21}, "sets_completed"),
        ({"ended_at": STARTED_AT - 86400 * 365}, "ended_at"),
    ],
    ids=["sets-negative", "reps-negative", "reps-huge", "sets-past-prescribable", "end-first"],
)
async def test_impossible_end_counts_or_an_end_before_the_start_are_a_422(
    live: Live, world: World, end: dict[str, Any], named: str
) -> None:
    """What the therapist reads ("-4611686018427387904 of 3 repetitions") never gets in."""
    sid = str(uuid.uuid4())
    detail = await refused_and_discarded(live, world, sid, recording_with(sid, world, {}, end))
    assert named in detail, detail
    attention = await live.client.get("/patients/attention", headers=bearer(world.t1))
    assert attention.status_code == 200 and "-" + "4611686018427387904" not in attention.text


@pytest.mark.asyncio
async def test_a_session_filed_before_the_count_bounds_still_reads(
    live: Live, world: World
) -> None:
    """The counts are bounded where an upload is checked, not where a recording is read: a
    session already filed with such counts still opens (its download, its charts), and
    only a new upload of it is refused."""
    from sessions.recording import RecordingError, check_session, decode

    sid = str(uuid.uuid4())
    rec = decode(recording_with(sid, world, {}, {"repetitions_completed": -(2**62)}))
    assert rec.end is not None and rec.end.repetitions_completed == -(2**62)
    with pytest.raises(RecordingError, match="repetitions_completed"):
        check_session(rec)


@pytest.mark.asyncio
@pytest.mark.parametrize("field", ["prescription_id", "patient_id", "station_id"])
async def test_an_id_past_what_the_store_holds_is_refused_with_the_first_chunk(
    live: Live, world: World, field: str
) -> None:
    sid = str(uuid.uuid4())
    bad = recording_with(sid, world, {field: 2**80}, {})
    r = await live.client.patch(
        f"/uploads/{sid}", content=bad, headers={**bearer(world.s1), "Upload-Offset": "0"}
    )
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith(f"the header record is not valid: {field}: ")
    assert await held(live, world, sid) is None and not part_file(live, sid).exists()


@pytest.mark.asyncio
async def test_an_upload_no_chunk_reached_for_upload_expire_s_is_removed(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> None:
    """The periodic pass: an upload left half-done goes, row and bytes, within a pass of
    its expiry; one still being sent stays."""
    world = seeded_store[1]
    with on_store(seeds, store, tmp_path, seeded_store[0]) as base:
        settings = base.model_copy(update={"upload_expire_s": 2.0})
        async with running(settings) as live:
            left, sent = str(uuid.uuid4()), str(uuid.uuid4())
            data = {
                sid: recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
                for sid in (left, sent)
            }
            for sid in (left, sent):
                r = await live.client.patch(
                    f"/uploads/{sid}",
                    content=data[sid][:CHUNK],
                    headers={**bearer(world.s1), "Upload-Offset": "0"},
                )
                assert r.status_code == 204
            assert part_file(live, left).exists()
            offset = CHUNK
            for i in range(80):  # 4 s: the expiry, a pass every 0.5 s, and a margin
                await asyncio.sleep(0.05)
                if i % 10 == 9:  # a chunk every 0.5 s
                    r = await live.client.patch(
                        f"/uploads/{sent}",
                        content=data[sent][offset : offset + CHUNK // 4],
                        headers={**bearer(world.s1), "Upload-Offset": str(offset)},
                    )
                    assert r.status_code == 204, r.text
                    offset += CHUNK // 4
            assert await held(live, world, left) is None
            assert not part_file(live, left).exists()
            assert await held(live, world, sent) == offset and part_file(live, sent).exists()
            # The station sends the abandoned one again from the start; it is filed.
            assert await put(live, world, left, data[left]) == 204
            assert (await complete(live, world, left, data[left])).status_code == 201


@pytest.mark.asyncio
async def test_abandoned_uploads_are_removed_when_the_server_starts(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> None:
    """With the default expiry (a day): an upload untouched for two days, and a .part file
    no upload names, are gone once the server is up; an upload from an hour ago stays."""
    world = seeded_store[1]
    with on_store(seeds, store, tmp_path, seeded_store[0]) as settings:
        assert settings.upload_expire_s == 86400.0
        old, recent = str(uuid.uuid4()), str(uuid.uuid4())
        async with running(settings) as live:
            for sid in (old, recent):
                data = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
                assert await put(live, world, sid, data) == 204
            async with live.sessionmaker() as db:
                for sid, age in ((old, timedelta(days=2)), (recent, timedelta(hours=1))):
                    await db.execute(
                        update(Upload)
                        .where(Upload.session_uuid == sid)
                        .values(updated_at=utcnow() - age)
                    )
                await db.commit()
            orphan = live.settings.data_dir / "uploads" / f"{uuid.uuid4()}.part"
            orphan.write_bytes(b"ANKLREC1")
            two_days_ago = time.time() - 2 * 86400
            os.utime(orphan, (two_days_ago, two_days_ago))
            recent_size = part_file(live, recent).stat().st_size
        async with running(settings) as live:
            for _ in range(100):
                if await held(live, world, old) is None and not orphan.exists():
                    break
                await asyncio.sleep(0.05)
            assert await held(live, world, old) is None and not part_file(live, old).exists()
            assert not orphan.exists()
            assert await held(live, world, recent) == recent_size
            assert part_file(live, recent).exists()


@pytest.mark.asyncio
async def test_a_full_disk_while_appending_is_a_507_and_loses_nothing_acknowledged(
    live: Live, world: World, monkeypatch: pytest.MonkeyPatch
) -> None:
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    assert len(data) > 2 * CHUNK
    url, station = f"/uploads/{sid}", bearer(world.s1)
    r = await live.client.patch(
        url, content=data[:CHUNK], headers={**station, "Upload-Offset": "0"}
    )
    assert r.status_code == 204

    real_pwrite = os.pwrite

    def disk_full(fd: int, data: bytes, offset: int) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", disk_full)
    r = await live.client.patch(
        url, content=data[CHUNK : 2 * CHUNK], headers={**station, "Upload-Offset": str(CHUNK)}
    )
    assert (r.status_code, r.json()["code"]) == (507, "storage_full"), r.text
    assert (await live.client.get("/health")).status_code == 200  # the server goes on
    assert await held(live, world, sid) == CHUNK  # what was acknowledged is still there
    monkeypatch.setattr(os, "pwrite", real_pwrite)

    assert await put_from(live, world, sid, data, CHUNK) == 204
    r = await complete(live, world, sid, data)
    assert r.status_code == 201, r.text
    got = await live.client.get(
        f"/sessions/{r.json()['id']}/download/rec", headers=bearer(world.t1)
    )
    assert got.content == data


@pytest.mark.asyncio
async def test_a_chunk_its_station_cuts_off_changes_nothing_and_is_no_error(
    live: Live, world: World, caplog: pytest.LogCaptureFixture
) -> None:
    """A station stopped while it sends a chunk: the server holds what it held before, logs
    no error (it logged an ASGI traceback), and the station's next try completes the upload."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    station = bearer(world.s1)
    r = await live.client.patch(
        f"/uploads/{sid}", content=data[:CHUNK], headers={**station, "Upload-Offset": "0"}
    )
    assert r.status_code == 204
    chunk = data[CHUNK : 2 * CHUNK]
    head = (
        f"PATCH /api/v1/uploads/{sid} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        f"Authorization: Bearer {world.s1}\r\nUpload-Offset: {CHUNK}\r\n"
        "Content-Type: application/offset+octet-stream\r\n"
        f"Content-Length: {len(chunk)}\r\n\r\n"
    )
    port = live.client.base_url.port
    assert port is not None
    for _ in range(3):
        _, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(head.encode() + chunk[: len(chunk) // 2])
        await writer.drain()
        await asyncio.sleep(0.3)  # the route is reading the body when the station goes
        writer.close()
        await writer.wait_closed()
    await asyncio.sleep(0.3)
    assert (await live.client.get("/health")).status_code == 200
    assert await held(live, world, sid) == CHUNK
    errors = [rec.getMessage() for rec in caplog.records if rec.levelno >= logging.ERROR]
    assert not errors, errors
    assert await put_from(live, world, sid, data, CHUNK) == 204
    r = await complete(live, world, sid, data)
    assert r.status_code == 201, r.text


async def put_from(live: Live, world: World, sid: str, data: bytes, start: int) -> int:
    for offset in range(start, len(data), CHUNK):
        r = await live.client.patch(
            f"/uploads/{sid}",
            content=data[offset : offset + CHUNK],
            headers={**bearer(world.s1), "Upload-Offset": str(offset)},
        )
        if r.status_code != 204:
            return r.status_code
    return 204


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_a_full_database_is_a_507_that_changes_nothing(live: Live, world: World) -> None:
    """SQLite's own SQLITE_FULL, made real by capping the database at its present size."""
    engine = live.app.state.engine

    def capped(dbapi_connection: Any, _record: Any, _proxy: Any) -> None:
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA page_count")
        (pages,) = cursor.fetchone()
        cursor.execute(f"PRAGMA max_page_count = {pages}")
        cursor.close()

    t1 = bearer(world.t1)
    before = (await live.client.get("/patients", headers=t1)).json()
    event.listen(engine.sync_engine.pool, "checkout", capped)
    try:
        r = await live.client.post(
            "/patients", json={"display_name": "Big", "notes": "n" * 4900}, headers=t1
        )
        for _ in range(20):  # until the free pages are used up
            if r.status_code != 201:
                break
            r = await live.client.post(
                "/patients", json={"display_name": "Big", "notes": "n" * 4900}, headers=t1
            )
        assert (r.status_code, r.json()) == (507, {"detail": DISK_FULL})
        async with live.sessionmaker() as db:
            assert (await db.execute(text("SELECT 1"))).scalar() == 1
    finally:
        event.remove(engine.sync_engine.pool, "checkout", capped)
    after = (await live.client.get("/patients", headers=t1)).json()
    # Every patient answered 201 is there; the refused one is not.
    assert len(after) >= len(before)
    assert all(p["display_name"] == "Big" for p in after[len(before) :])


def test_the_recordings_used_here_are_valid() -> None:
    """The control for the tests above: the same builder with good values decodes."""
    from sessions.recording import decode

    sid = str(uuid.uuid4())
    world = World("", "", "", 1, 2, 1, 2, "", 1, 2, "", 3, 1, 2)
    rec = decode(recording_with(sid, world, {"started_at": STARTED_AT}, {}))
    assert rec.header.started_at == STARTED_AT and rec.end is not None
    assert rec.end.ended_at == STARTED_AT + N / 100.0
    assert len(rec.samples) == 200 and np.all(rec.samples["t"][:2] == [42.0, 42.01])


@pytest.mark.asyncio
async def test_a_recording_naming_another_station_is_refused_with_the_first_chunk(
    live: Live, world: World
) -> None:
    """A station uploads only what it recorded: a header naming the patient's other station,
    or another patient's, is a 422 and nothing is held or filed. Taken: this station, 0 (a
    session recorded before the station first connected) and a revoked station of the same
    patient (its predecessor, provisioned again)."""
    t1 = bearer(world.t1)
    for named in (world.s1_spare_id, world.s2_id):
        sid = str(uuid.uuid4())
        bad = recording_with(sid, world, {"station_id": named}, {})
        r = await live.client.patch(
            f"/uploads/{sid}", content=bad, headers={**bearer(world.s1), "Upload-Offset": "0"}
        )
        assert r.status_code == 422, r.text
        assert r.json()["detail"] == (
            f"the recording names station {named}, but this upload comes from station "
            f"{world.s1_id}: a station uploads only the sessions it recorded"
        )
        assert await held(live, world, sid) is None
        assert (await complete(live, world, sid, bad)).status_code == 404
    assert (await live.client.get("/sessions", headers=t1)).json() == []

    r = await live.client.post(f"/stations/{world.s1_spare_id}/revoke", headers=t1)
    assert r.status_code == 200, r.text
    for named in (world.s1_id, 0, world.s1_spare_id):
        sid = str(uuid.uuid4())
        good = recording_with(sid, world, {"station_id": named}, {})
        assert await put(live, world, sid, good) == 204, named
        r = await complete(live, world, sid, good)
        assert r.status_code == 201, (named, r.text)
        assert r.json()["station_id"] == world.s1_id


async def _station(live: Live, world: World, name: str) -> tuple[int, str]:
    r = await live.client.post(
        f"/patients/{world.p1}/stations", json={"name": name}, headers=bearer(world.t1)
    )
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


@pytest.mark.asyncio
async def test_a_station_provisioned_again_finishes_what_its_revoked_predecessor_began(
    live: Live, world: World, tmp_path: Path
) -> None:
    """The old station sent one session whole but not ``complete``, another's first chunk
    only, and filed a third whose answer it never read; then it was revoked and a new one
    provisioned for the same patient, with the old one's spool. The new station's own
    uploader finishes all three (it was told 404 for a day, until the server dropped them).
    Neither a station of the patient that is not revoked nor another patient's takes them."""
    old_id, old = await _station(live, world, "Old")
    sids = [str(uuid.uuid4()) for _ in range(3)]
    data = {s: recording_bytes(s, samples(), old_id, world.p1, world.rx1) for s in sids}
    whole, begun, filed = sids
    assert len(data[begun]) > CHUNK
    spool = Spool(tmp_path / "spool")
    for s in sids:
        spool.path(s).write_bytes(data[s])
    for s, end in ((whole, len(data[whole])), (begun, CHUNK), (filed, len(data[filed]))):
        for offset in range(0, end, CHUNK):
            r = await live.client.patch(
                f"/uploads/{s}",
                content=data[s][offset : offset + CHUNK],
                headers={**bearer(old), "Upload-Offset": str(offset)},
            )
            assert r.status_code == 204, r.text
    body = {"size": len(data[filed]), "sha256": hashlib.sha256(data[filed]).hexdigest()}
    r = await live.client.post(f"/uploads/{filed}/complete", json=body, headers=bearer(old))
    assert r.status_code == 201, r.text
    filed_row = r.json()

    new_id, new = await _station(live, world, "New")
    for s in sids:  # the old station is not revoked yet: its uploads are its own
        r = await live.client.head(f"/uploads/{s}", headers=bearer(new))
        assert r.status_code == 404, s
    r = await live.client.post(f"/stations/{old_id}/revoke", headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    for s in sids:  # nor another patient's station's, revoked or not
        r = await live.client.head(f"/uploads/{s}", headers=bearer(world.s2))
        assert r.status_code == 404, s

    root = str(live.client.base_url).removesuffix("/api/v1/")
    uploader = Uploader(root, new, spool)
    try:
        assert await uploader.upload_all() == 3, (uploader.refused, uploader.last_error)
    finally:
        await uploader.client.aclose()
    assert not spool.pending() and not uploader.refused
    sessions = (await live.client.get("/sessions", headers=bearer(world.t1))).json()
    by_uuid = {row["session_uuid"]: row for row in sessions}
    assert by_uuid[filed] == filed_row  # filed once, by the old station, and not again
    for s in (whole, begun):
        assert by_uuid[s]["station_id"] == new_id
        got = await live.client.get(
            f"/sessions/{by_uuid[s]['id']}/download/rec", headers=bearer(world.t1)
        )
        assert got.content == data[s]

    # Taken over, an upload is the new station's: the patient's other station, not
    # revoked, does not take it in turn.
    later = str(uuid.uuid4())
    later_data = recording_bytes(later, samples(), new_id, world.p1, world.rx1)
    r = await live.client.patch(
        f"/uploads/{later}",
        content=later_data[:CHUNK],
        headers={**bearer(new), "Upload-Offset": "0"},
    )
    assert r.status_code == 204, r.text
    r = await live.client.patch(
        f"/uploads/{later}",
        content=later_data[CHUNK : 2 * CHUNK],
        headers={**bearer(world.s1), "Upload-Offset": str(CHUNK)},
    )
    assert r.status_code == 404, r.text
    assert (
        await live.client.head(f"/uploads/{later}", headers=bearer(world.s1))
    ).status_code == 404


@pytest.mark.asyncio
async def test_no_upload_lock_is_kept_once_its_requests_are_done(live: Live, world: World) -> None:
    """Each upload's lock lives as long as a request holds it or waits for it: after many
    requests (refused ones for ids nothing holds, concurrent ones for one id, an upload
    filed) the server keeps none, so a station sending random ids grows nothing."""
    station = bearer(world.s1)

    async def stray() -> None:
        sid = str(uuid.uuid4())
        r = await live.client.patch(
            f"/uploads/{sid}", content=b"not a recording", headers={**station, "Upload-Offset": "0"}
        )
        assert r.status_code == 422, r.text
        r = await live.client.patch(
            f"/uploads/{sid}", content=b"x", headers={**station, "Upload-Offset": "5"}
        )
        assert r.status_code == 409, r.text
        body = {"size": 8, "sha256": "0" * 64}
        r = await live.client.post(f"/uploads/{sid}/complete", json=body, headers=station)
        assert r.status_code == 404, r.text

    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)

    async def same_chunk() -> int:
        r = await live.client.patch(
            f"/uploads/{sid}", content=data, headers={**station, "Upload-Offset": "0"}
        )
        return r.status_code

    results = await asyncio.gather(*(stray() for _ in range(40)), *(same_chunk() for _ in range(8)))
    assert sorted(s for s in results if s is not None) == [204] + [409] * 7
    assert (await complete(live, world, sid, data)).status_code == 201
    assert live.app.state.upload_locks == {}


MALFORMED_PRESCRIPTIONS: list[tuple[dict[str, Any], str]] = [
    (
        {"exercise": "flexibility", "axes": [{"axis": ["pitch"], "waveform": "sine"}]},
        "prescription.axes.0.axis: ",
    ),
    ({"exercise": "strength", "axes": "pitch"}, "prescription.axes: "),
    ({"exercise": "strength", "axes": [{"axis": "pitch"}, 5, None]}, "prescription.axes.1: "),
    ({"exercise": "strength", "axes": [{"axis": "pitch", "waveform": {}}]}, "waveform: "),
    ({"exercise": ["x"], "axes": [{"axis": "pitch"}]}, "prescription.exercise: "),
    ({"exercise": "strength", "axes": []}, "prescription.axes: "),
    ({"exercise": "strength"}, "prescription.axes: "),
    ({"exercise": "strength", "axes": [{"axis": "pitch"}], "sets": 10**30}, ".sets: "),
    ({"exercise": "strength", "axes": [{"axis": "pitch"}], "repetitions": True}, "repetitions"),
]


@pytest.mark.asyncio
@pytest.mark.parametrize(("prescription", "named"), MALFORMED_PRESCRIPTIONS)
async def test_a_header_whose_prescription_cannot_be_read_is_refused_with_the_first_chunk(
    live: Live, world: World, prescription: dict[str, Any], named: str
) -> None:
    """The summaries read the header's prescription: one they cannot read (an axis named by
    a list made ``complete`` a 500, retried by the station for a day) is a 422 naming the
    field, and nothing is held."""
    sid = str(uuid.uuid4())
    bad = recording_with(sid, world, {"prescription": prescription}, {})
    r = await live.client.patch(
        f"/uploads/{sid}", content=bad, headers={**bearer(world.s1), "Upload-Offset": "0"}
    )
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("the header record is not valid: prescription.") and named in detail
    assert await held(live, world, sid) is None and not part_file(live, sid).exists()


async def held_before(live: Live, world: World, sid: str, data: bytes) -> None:
    """``data`` held whole as an upload under way, as a server without the first chunk's
    checks of today took it before it was upgraded."""
    part_file(live, sid).write_bytes(data)
    async with live.sessionmaker() as db:
        db.add(Upload(session_uuid=sid, station_id=world.s1_id, received_bytes=len(data)))
        await db.commit()


@pytest.mark.asyncio
@pytest.mark.parametrize(("prescription", "named"), MALFORMED_PRESCRIPTIONS[:3])
async def test_a_prescription_that_cannot_be_read_is_refused_at_complete_and_discarded(
    live: Live, world: World, prescription: dict[str, Any], named: str
) -> None:
    sid = str(uuid.uuid4())
    bad = recording_with(sid, world, {"prescription": prescription}, {})
    await held_before(live, world, sid, bad)
    assert await held(live, world, sid) == len(bad)
    r = await complete(live, world, sid, bad)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("not a valid recording: prescription.") and named in detail
    assert detail.endswith("upload the session again")
    assert await held(live, world, sid) is None and not part_file(live, sid).exists()
    good = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, good) == 204
    assert (await complete(live, world, sid, good)).status_code == 201


@pytest.mark.asyncio
async def test_a_recording_the_server_fails_to_summarise_is_refused_not_a_500(
    live: Live, world: World, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Whatever fails in summarising a recording fails again for the same bytes: a fault
    the checks do not name yet (here injected) is a 422 that discards the upload, and the
    server logs it as its own error, with the traceback, to be fixed."""
    import server.routes.uploads as uploads_route

    def broken(rec: Any) -> Any:
        raise TypeError("unhashable type: 'list'")

    monkeypatch.setattr(uploads_route, "summarize", broken)
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    r = await complete(live, world, sid, data)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == (
        "not a valid recording: the server could not summarise it (TypeError: unhashable "
        "type: 'list'); upload the session again"
    )
    assert await held(live, world, sid) is None and not part_file(live, sid).exists()
    logged = [rec for rec in caplog.records if rec.levelno >= logging.ERROR]
    assert [rec.getMessage() for rec in logged] == [
        f"upload {sid}: could not summarise the recording"
    ]
    assert logged[0].exc_info is not None
    monkeypatch.undo()
    assert await put(live, world, sid, data) == 204
    assert (await complete(live, world, sid, data)).status_code == 201


@pytest.mark.asyncio
async def test_a_sha256_in_upper_case_is_taken_and_one_not_hex_says_what_it_must_be(
    live: Live, world: World
) -> None:
    """``sha256sum`` writes lower case, other tools upper: both name the same digest. One that
    is not hex was told only that it was "not in the expected form"."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    bad = {"size": len(data), "sha256": "g" * 64}
    r = await live.client.post(f"/uploads/{sid}/complete", json=bad, headers=bearer(world.s1))
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["msg"] == "SHA-256 must be 64 hexadecimal digits (0-9 and a-f)."
    digest = hashlib.sha256(data).hexdigest()
    body = {"size": len(data), "sha256": digest.upper()}
    r = await live.client.post(f"/uploads/{sid}/complete", json=body, headers=bearer(world.s1))
    assert r.status_code == 201, r.text
    assert r.json()["sha256"] == digest


@pytest.mark.asyncio
async def test_another_patients_station_learns_nothing_of_a_filed_session(
    live: Live, world: World
) -> None:
    """A filed session's uuid sent to by another patient's station is a 404, as HEAD
    answers it: PATCH answered 409 "already complete", saying the uuid is a session."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    assert (await complete(live, world, sid, data)).status_code == 201
    other = bearer(world.s2)
    assert (await live.client.head(f"/uploads/{sid}", headers=other)).status_code == 404
    r = await live.client.patch(
        f"/uploads/{sid}", content=data[:CHUNK], headers={**other, "Upload-Offset": "0"}
    )
    assert (r.status_code, r.json()) == (404, {"detail": "no such upload"})
    # Its own station is still told it is complete.
    r = await live.client.patch(
        f"/uploads/{sid}", content=data[:CHUNK], headers={**bearer(world.s1), "Upload-Offset": "0"}
    )
    assert r.status_code == 409, r.text
