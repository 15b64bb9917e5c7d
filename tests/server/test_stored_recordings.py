"""A stored recording that is no longer the file the station uploaded (cut short, changed
on disk) is never served, nor anything made from it; exports are kept for the very bytes
they were made from."""

from __future__ import annotations

import hashlib
import logging
import shutil
from pathlib import Path

import pytest
from sqlalchemy import update

from server.models import Session
from server.routes.sessions import DAMAGED, DOWNLOAD_FORMATS
from tests.server.live_server import Live, World, bearer
from tests.server.test_report import TODAY, exports, rows_at
from tests.server.test_series import upload

pytestmark = pytest.mark.asyncio


async def stored(live: Live, session_id: int) -> Session:
    async with live.sessionmaker() as db:
        row = await db.get(Session, session_id)
        assert row is not None and row.file_path is not None
        return row


def file_of(live: Live, row: Session) -> Path:
    assert row.file_path is not None
    return live.settings.data_dir / row.file_path


async def test_a_damaged_recording_is_a_500_saying_so_and_nothing_is_made_from_it(
    live: Live, world: World, caplog: pytest.LogCaptureFixture
) -> None:
    """Cut to 300,000 bytes on disk, it was served whole: every format 200, ``rec`` with the
    upload's SHA-256, a JSON export with no end and a third of the samples, which stayed in
    the export cache after the file was restored."""
    session_id = await upload(live, world, rows_at(TODAY))
    t1 = bearer(world.t1)
    url = f"/sessions/{session_id}/download/"
    whole = {f: (await live.client.get(url + f, headers=t1)).content for f in ("csv", "rec")}
    file = file_of(live, await stored(live, session_id))
    cache = live.settings.data_dir / "exports"
    kept = sorted(p.name for p in cache.iterdir())
    audited = len(await exports(live, world))
    backup = file.read_bytes()
    assert len(backup) > 300_000
    with file.open("r+b") as f:
        f.truncate(300_000)

    with caplog.at_level(logging.ERROR):
        for fmt in (*DOWNLOAD_FORMATS, "csv"):
            r = await live.client.get(url + fmt, headers=t1)
            assert (r.status_code, r.json()) == (500, {"detail": DAMAGED}), fmt
        r = await live.client.get(f"/sessions/{session_id}/series", headers=t1)
        assert r.status_code == 500
    damaged = [r for r in caplog.records if "damaged" in r.getMessage()]
    assert len(damaged) == 1, [r.getMessage() for r in caplog.records]  # logged once
    assert sorted(p.name for p in cache.iterdir()) == kept  # nothing made, nothing cached
    assert len(await exports(live, world)) == audited  # nothing left the system

    file.write_bytes(backup)  # restored from backup
    for fmt in ("csv", "rec"):
        r = await live.client.get(url + fmt, headers=t1)
        assert r.status_code == 200, r.text
        assert r.content == whole[fmt], fmt
        assert r.headers["x-content-sha256"] == hashlib.sha256(r.content).hexdigest()


async def test_an_export_is_served_only_for_the_recording_it_was_made_from(
    live: Live, world: World
) -> None:
    """The export cache was keyed on the session alone: once a file is replaced by another
    (a restore from another backup, the database told so), the old export was served on."""
    a = await upload(live, world, rows_at(TODAY))
    b = await upload(live, world, rows_at(TODAY, scale=0.5))
    t1 = bearer(world.t1)
    old = await live.client.get(f"/sessions/{a}/download/json", headers=t1)
    other = await live.client.get(f"/sessions/{b}/download/json", headers=t1)
    assert old.status_code == other.status_code == 200
    assert old.content != other.content
    row_a, row_b = await stored(live, a), await stored(live, b)
    shutil.copyfile(file_of(live, row_b), file_of(live, row_a))
    async with live.sessionmaker() as db:
        await db.execute(
            update(Session)
            .where(Session.id == a)
            .values(sha256=row_b.sha256, size_bytes=row_b.size_bytes)
        )
        await db.commit()
    again = await live.client.get(f"/sessions/{a}/download/json", headers=t1)
    assert again.status_code == 200
    assert again.content == other.content
