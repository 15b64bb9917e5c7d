"""Uploads that are wrong, or that meet a full disk: a 4xx or 507 with a sentence, nothing
acknowledged lost, and the upload completes once the station sends what is right."""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import struct
import uuid
import zlib
from typing import Any

import numpy as np
import pytest
from sqlalchemy import event, text

from server.errors import DISK_FULL
from station.uploader import CHUNK
from tests.server.live_server import Live, World, bearer
from tests.server.test_series import STARTED_AT, N, recording_bytes, samples

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
    assert (r.status_code, r.json()) == (507, {"detail": DISK_FULL})
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
