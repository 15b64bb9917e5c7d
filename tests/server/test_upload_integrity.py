"""What the server holds of an upload is what it acknowledged, through a full disk, a crash
inside ``complete`` and bytes damaged on the way: every chunk answered 204 is on disk whole,
a retried ``complete`` files the session once, and bytes that are not the station's file are
sent again rather than the recording refused.

Crashes are not timed kills: each test leaves the files and rows as a kill between two
steps of ``complete`` leaves them, then asks the real server again."""

from __future__ import annotations

import errno
import hashlib
import logging
import os
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sqlalchemy import func, select

from server.models import Session, Upload
from station.spool import Spool
from station.uploader import CHUNK, Uploader
from tests.server.live_server import Live, World, bearer
from tests.server.test_metrics import sample, scrape
from tests.server.test_series import recording_bytes, samples
from tests.server.test_upload_refusals import (
    complete,
    held,
    part_file,
    put,
    put_from,
    refused_and_discarded,
)

pytestmark = [pytest.mark.both_stores, pytest.mark.asyncio]


def filed_file(live: Live, sid: str) -> Path:
    return live.settings.data_dir / "sessions" / f"{sid}.rec"


async def sessions_of(live: Live, sid: str) -> int:
    async with live.sessionmaker() as db:
        count = await db.scalar(select(func.count()).where(Session.session_uuid == sid))
    return int(count or 0)


async def download(live: Live, world: World, session_id: int) -> bytes:
    r = await live.client.get(f"/sessions/{session_id}/download/rec", headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    return r.content


async def first_chunk(live: Live, world: World, sid: str, data: bytes) -> None:
    r = await live.client.patch(
        f"/uploads/{sid}", content=data[:CHUNK], headers={**bearer(world.s1), "Upload-Offset": "0"}
    )
    assert r.status_code == 204, r.text


async def test_a_chunk_the_disk_takes_only_part_of_is_a_507_and_the_upload_resumes(
    live: Live, world: World, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A nearly full disk: ``pwrite`` writes half the chunk, then finds no space. Answered
    204, the server claimed bytes it did not have, and ``complete`` later refused the valid
    session as a checksum mismatch. Now: 507 saying so, the file cut back to what was
    acknowledged, an error logged and counted, and the station's retry completes it."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    await first_chunk(live, world, sid, data)
    before = sample((await scrape(live)).text, "ankle_upload_faults_total", fault="storage_full")
    real_pwrite = os.pwrite
    calls: list[int] = []

    def nearly_full(fd: int, chunk: Any, offset: int) -> int:
        calls.append(len(chunk))
        if len(calls) == 1:
            return real_pwrite(fd, bytes(chunk[: len(chunk) // 2]), offset)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", nearly_full)
    r = await live.client.patch(
        f"/uploads/{sid}",
        content=data[CHUNK : 2 * CHUNK],
        headers={**bearer(world.s1), "Upload-Offset": str(CHUNK)},
    )
    monkeypatch.undo()
    assert r.status_code == 507, r.text
    assert r.json() == {
        "detail": f"the server's storage is full: this chunk was not stored; the {CHUNK} bytes "
        "received before it are kept, and the upload resumes from there once an "
        "administrator has freed space",
        "code": "storage_full",
    }
    assert r.headers["Upload-Offset"] == str(CHUNK)
    assert calls == [CHUNK, CHUNK - CHUNK // 2]  # the rest was asked for, not dropped
    assert await held(live, world, sid) == CHUNK
    assert part_file(live, sid).stat().st_size == CHUNK
    errors = [rec.getMessage() for rec in caplog.records if rec.levelno >= logging.ERROR]
    assert any(f"upload {sid}: the server's storage is full" in e for e in errors), errors
    after = sample((await scrape(live)).text, "ankle_upload_faults_total", fault="storage_full")
    assert after == before + 1

    assert await put_from(live, world, sid, data, CHUNK) == 204
    r = await complete(live, world, sid, data)
    assert r.status_code == 201, r.text
    assert await download(live, world, r.json()["id"]) == data


async def test_short_writes_are_written_on_until_the_chunk_is_whole(
    live: Live, world: World, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``pwrite`` may write less than asked without an error: each chunk is written on from
    where it stopped, and the session files whole."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    real_pwrite = os.pwrite

    def a_third_at_a_time(fd: int, chunk: Any, offset: int) -> int:
        return real_pwrite(fd, bytes(chunk[: max(1, len(chunk) // 3)]), offset)

    monkeypatch.setattr(os, "pwrite", a_third_at_a_time)
    assert await put(live, world, sid, data) == 204
    monkeypatch.undo()
    assert part_file(live, sid).read_bytes() == data
    r = await complete(live, world, sid, data)
    assert r.status_code == 201, r.text
    assert await download(live, world, r.json()["id"]) == data


async def whole_upload(live: Live, world: World) -> tuple[str, bytes]:
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    return sid, data


async def filed_once(live: Live, world: World, sid: str, data: bytes, status: int) -> None:
    """``complete`` asked again files the session, once, with the station's bytes, and no
    upload or ``.part`` file is left of it."""
    r = await complete(live, world, sid, data)
    assert r.status_code == status, r.text
    assert await sessions_of(live, sid) == 1
    assert await download(live, world, r.json()["id"]) == data
    assert not part_file(live, sid).exists()
    async with live.sessionmaker() as db:
        assert await db.get(Upload, sid) is None
    r = await live.client.head(f"/uploads/{sid}", headers=bearer(world.s1))
    assert r.headers["Upload-Complete"] == "1" and r.headers["Upload-Offset"] == str(len(data))


async def test_a_crash_after_linking_before_the_row_is_filed_by_the_retry(
    live: Live, world: World
) -> None:
    """Killed once the bytes were given their name in ``sessions/``, before the row."""
    sid, data = await whole_upload(live, world)
    os.link(part_file(live, sid), filed_file(live, sid))
    await filed_once(live, world, sid, data, 201)


async def test_a_crash_after_the_commit_is_answered_200_and_the_part_file_goes(
    live: Live, world: World
) -> None:
    """Killed after the row was committed, before the ``.part`` name was dropped."""
    sid, data = await whole_upload(live, world)
    assert (await complete(live, world, sid, data)).status_code == 201
    os.link(filed_file(live, sid), part_file(live, sid))
    await filed_once(live, world, sid, data, 200)


async def test_a_crash_of_an_earlier_server_between_moving_and_the_row_is_filed(
    live: Live, world: World
) -> None:
    """An earlier server moved ``.part`` into ``sessions/`` before writing the row; killed
    between the two, every retry answered 500 (FileNotFoundError) until the upload expired,
    and a PATCH at the held offset made a file of zeros that then failed its checksum."""
    sid, data = await whole_upload(live, world)
    os.replace(part_file(live, sid), filed_file(live, sid))
    r = await live.client.patch(
        f"/uploads/{sid}",
        content=data[-10:],
        headers={**bearer(world.s1), "Upload-Offset": str(len(data))},
    )
    assert r.status_code == 204, r.text  # the bytes were found, and appended to
    assert part_file(live, sid).read_bytes() == data + data[-10:]
    assert await held(live, world, sid) == len(data) + 10

    sid, data = await whole_upload(live, world)
    os.replace(part_file(live, sid), filed_file(live, sid))
    await filed_once(live, world, sid, data, 201)


async def test_bytes_gone_from_the_disk_are_asked_for_again_never_made_up(
    live: Live, world: World
) -> None:
    """The row says the bytes were received, the disk has none: ``complete`` is a 409 that
    asks for the file from its first byte (it was a 500 for a day), and a chunk sent at the
    offset held is told where to start (it was written after 1.9 MB of zeros)."""
    sid, data = await whole_upload(live, world)
    part_file(live, sid).unlink()
    r = await complete(live, world, sid, data)
    assert r.status_code == 409, r.text
    assert r.json()["code"] == "upload_corrupted" and r.headers["Upload-Offset"] == "0"
    assert await held(live, world, sid) is None
    assert await put(live, world, sid, data) == 204
    await filed_once(live, world, sid, data, 201)

    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data[: 2 * CHUNK]) == 204
    with part_file(live, sid).open("r+b") as f:
        f.truncate(CHUNK)  # the storage lost the second chunk it acknowledged
    r = await live.client.patch(
        f"/uploads/{sid}",
        content=data[2 * CHUNK : 3 * CHUNK],
        headers={**bearer(world.s1), "Upload-Offset": str(2 * CHUNK)},
    )
    assert r.status_code == 409 and r.headers["Upload-Offset"] == str(CHUNK), r.text
    assert part_file(live, sid).stat().st_size == CHUNK
    assert await held(live, world, sid) == CHUNK
    assert await put_from(live, world, sid, data, CHUNK) == 204
    await filed_once(live, world, sid, data, 201)


async def test_bytes_damaged_on_the_way_are_sent_again_not_refused(
    live: Live, world: World, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A checksum mismatch means the server's bytes are not the station's file: a fault of
    the transport or the storage, not of the recording. It was a 422 ("upload again"),
    which the station takes as final: the valid session went to ``refused/``. Now a 409
    ``upload_corrupted`` with ``Upload-Offset: 0``; the station's own uploader sends the
    file again and it is filed."""
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    with part_file(live, sid).open("r+b") as f:
        f.seek(CHUNK + 1000)
        f.write(bytes([data[CHUNK + 1000] ^ 0x20]))
    damaged = hashlib.sha256(part_file(live, sid).read_bytes()).hexdigest()

    spool = Spool(tmp_path / "spool")
    spool.path(sid).write_bytes(data)
    root = str(live.client.base_url).removesuffix("/api/v1/")
    uploader = Uploader(root, world.s1, spool)
    try:
        first = await uploader.client.post(
            f"/api/v1/uploads/{sid}/complete",
            json={"size": len(data), "sha256": hashlib.sha256(data).hexdigest()},
        )
        assert first.status_code == 409, first.text
        assert first.json() == {
            "detail": f"the bytes the server received hash to {damaged}, not to the SHA-256 "
            "sent: they were damaged on the way or on the server's storage, not in the "
            "recording; the server discarded its copy: upload the same file again from its "
            "first byte",
            "code": "upload_corrupted",
        }
        assert first.headers["Upload-Offset"] == "0"
        assert not part_file(live, sid).exists() and await held(live, world, sid) is None
        assert await uploader.upload_all() == 1, (uploader.refused, uploader.last_error)
    finally:
        await uploader.client.aclose()
    assert not uploader.refused and not spool.pending()
    assert await sessions_of(live, sid) == 1
    errors = [rec.getMessage() for rec in caplog.records if rec.levelno >= logging.ERROR]
    assert any(f"upload {sid}: the bytes received hash to {damaged}" in e for e in errors)


def replayed() -> Any:
    """The first 600 samples twice, as a file whose samples were appended again."""
    s = samples()[:600]
    return np.concatenate([s, s])


def repeated() -> Any:
    """Sample 100 written twice in a row."""
    s = samples()[:200]
    return np.concatenate([s[:101], s[100:]])


@pytest.mark.parametrize(
    ("rows", "named"),
    [
        (
            replayed,
            "sample 600 (of 1200, counted from 0) goes back in time: its device time t "
            "(42 s) and wall time are not after those of the sample before it (t 47.99 s)",
        ),
        (repeated, "sample 101 (of 201, counted from 0) goes back in time"),
    ],
    ids=["replayed", "repeated"],
)
async def test_samples_going_back_on_both_clocks_are_a_422_naming_where(
    live: Live, world: World, rows: Any, named: str
) -> None:
    """Samples duplicated made a session of 162 s of exercise in 81 s: the device clock's
    forward steps were only held to the session's length plus an hour."""
    sid = str(uuid.uuid4())
    bad = recording_bytes(sid, rows(), world.s1_id, world.p1, world.rx1)
    detail = await refused_and_discarded(live, world, sid, bad)
    assert detail.startswith("not a valid recording: ") and named in detail, detail


async def filed_summary(live: Live, world: World, rows: Any) -> dict[str, Any]:
    sid = str(uuid.uuid4())
    started = time.time() - 3600  # within the attention list's week
    data = recording_bytes(sid, rows, world.s1_id, world.p1, world.rx1, started_at=started)
    assert await put(live, world, sid, data) == 204
    r = await complete(live, world, sid, data)
    assert r.status_code == 201, r.text
    summary: dict[str, Any] = r.json()["summary"]
    return summary


async def test_samples_missing_are_filed_and_told_to_the_therapist(
    live: Live, world: World
) -> None:
    """40 s of samples missing (the device's link or the station stalled) is a session
    that happened: filed, but no longer as whole. Its summary counts the gap and the time
    missing, left out of the exercise time, and the therapist's attention list says so.
    A restarted device (its clock back at 0, received later) is a gap too, not a replay."""
    s = samples()
    gap = np.concatenate([s[:6000], s[10000:]])  # 40 s gone
    summary = await filed_summary(live, world, gap)
    assert summary["telemetry_gaps"] == 1
    assert summary["telemetry_missing_s"] == pytest.approx(40.0, abs=1e-6)
    assert summary["end_reason"] == "completed"
    whole = await filed_summary(live, world, samples())
    assert whole["telemetry_gaps"] == 0 and whole["telemetry_missing_s"] == 0.0
    assert summary["duration_s"] == pytest.approx(whole["duration_s"] - 40.0, abs=0.02)

    restarted = samples()[:3000]
    restarted["t"][1500:] = 0.5 + np.arange(1500) / 100.0  # the device's clock starts again
    restarted["wall"][1500:] += 5.0  # received 5 s later
    again = await filed_summary(live, world, restarted)
    assert again["telemetry_gaps"] == 1
    assert again["telemetry_missing_s"] == pytest.approx(5.0, abs=1e-6)

    items = (await live.client.get("/patients/attention", headers=bearer(world.t1))).json()
    missing = sorted(i["text"] for i in items if i["kind"] == "data_missing")
    assert missing == [
        "Telemetry missing for 40 s (1 gap): the session's numbers leave that time out.",
        "Telemetry missing for 5 s (1 gap): the session's numbers leave that time out.",
    ]
