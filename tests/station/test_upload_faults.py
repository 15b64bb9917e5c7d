"""Uploads that meet a fault that is not the recording's: the server's copy of the bytes no
longer matches the station's file at ``complete`` (its storage changed a byte), a session
file the station cannot read itself, a token the server no longer knows. A real server; the
fault is made where it happens, in the server's upload file on its disk."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import uuid
from pathlib import Path

import httpx
import pytest

from sessions import wire
from station import uploader
from station.server_link import ServerLink
from station.spool import Spool
from station.uploader import Uploader
from tests.server.live_server import Live, World, live, world
from tests.server.test_series import recording_bytes, samples

__all__ = ["live", "world"]  # the real server's fixtures, for the tests below

DEADLINE_S = 60.0


def _spoiling_client(live: Live, token: str, spoil: list[int]) -> httpx.AsyncClient:
    """The station's client to ``live``; before each ``complete``, while ``spoil`` counts
    down, one byte of the server's copy of the upload changes on the server's disk (a storage
    fault between the chunks and the check)."""
    uploads = live.settings.data_dir / "uploads"

    async def flip(request: httpx.Request) -> None:
        if request.url.path.endswith("/complete") and spoil[0] > 0:
            spoil[0] -= 1
            sid = request.url.path.split("/")[-2]
            part = uploads / f"{sid}.part"
            data = bytearray(part.read_bytes())
            data[len(data) // 2] ^= 0x40
            part.write_bytes(bytes(data))

    return httpx.AsyncClient(
        base_url=f"http://127.0.0.1:{live.client.base_url.port}",
        headers={"Authorization": f"Bearer {token}"},
        timeout=60.0,
        event_hooks={"request": [flip]},
    )


async def _run_until(up: Uploader, done: object) -> None:
    assert callable(done)
    task = asyncio.create_task(up.run(period=0.05))
    try:
        async with asyncio.timeout(DEADLINE_S):
            while not done():
                assert not task.done(), task
                await asyncio.sleep(0.05)
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


@pytest.mark.asyncio
async def test_a_checksum_mismatch_sends_the_same_file_again_and_never_refuses_it(
    live: Live, world: World, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A valid session whose copy on the server changed a byte before ``complete`` was set
    aside in ``refused/`` as "not sent again" (the 422 of a checksum mismatch taken for the
    recording's fault). It is a fault of the transport or the storage: the station sends
    the same file again, and the session is filed whole."""
    monkeypatch.setattr(uploader, "RETRY_FIRST_S", 0.05)
    spool = Spool(tmp_path / "spool")
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:300], world.s1_id, world.p1, world.rx1)
    spool.path(sid).write_bytes(data)
    spoil = [2]  # the first two copies spoilt, the third whole
    up = Uploader("", "", spool, _spoiling_client(live, world.s1, spoil))
    try:
        await _run_until(up, lambda: sid in up.uploaded or up.refused)
    finally:
        await up.aclose()
    assert up.refused == {} and not (tmp_path / "spool" / "refused").exists()
    assert up.uploaded == [sid] and spoil == [0]
    filed = await live.client.head(
        f"/uploads/{sid}", headers={"Authorization": f"Bearer {world.s1}"}
    )
    assert filed.headers["Upload-Complete"] == "1", filed.headers
    assert spool.pending() == []


@pytest.mark.asyncio
async def test_copies_that_keep_not_matching_are_kept_pending_and_said_so(
    live: Live, world: World, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Sent again a bounded number of times, after growing waits; then kept in the spool,
    not refused, and the station says why it waits."""
    monkeypatch.setattr(uploader, "RETRY_FIRST_S", 0.05)
    spool = Spool(tmp_path / "spool")
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:300], world.s1_id, world.p1, world.rx1)
    spool.path(sid).write_bytes(data)
    spoil = [1000]
    up = Uploader("", "", spool, _spoiling_client(live, world.s1, spoil))
    try:
        await _run_until(up, lambda: up.kept_back or up.refused)
        await asyncio.sleep(0.5)  # rounds meanwhile: none sends it while it is kept back
    finally:
        await up.aclose()
    assert spoil == [1000 - (uploader.RESENDS + 1)], spoil
    assert up.refused == {} and spool.pending() == [spool.path(sid)]
    assert spool.path(sid).read_bytes() == data
    assert "did not match this station's file" in up.kept_back[sid]
    assert "kept here and sent again in 10 minutes" in up.last_error, up.last_error
    assert up.pending() == 1


@pytest.mark.asyncio
async def test_a_session_file_the_station_cannot_read_is_named_not_the_server(
    live: Live, world: World, tmp_path: Path
) -> None:
    """Every local error was said as "server unreachable (IsADirectoryError)"."""
    spool = Spool(tmp_path / "spool")
    sid = str(uuid.uuid4())
    spool.path(sid).mkdir()  # not a file: reading it fails on the station
    up = Uploader("", "", spool, _spoiling_client(live, world.s1, [0]))
    try:
        await _run_until(up, lambda: up.last_error)
    finally:
        await up.aclose()
    assert "unreachable" not in up.last_error, up.last_error
    assert up.last_error.startswith(f"cannot read the session file {spool.path(sid)}: "), (
        up.last_error
    )


@pytest.mark.asyncio
async def test_a_revoked_or_unknown_token_is_named_on_the_station_link(
    live: Live, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "ankle.station.server")

    async def ignore(message: object) -> None:
        return None

    link = ServerLink(
        f"http://127.0.0.1:{live.client.base_url.port}",
        "a-token-this-server-never-gave",
        lambda: wire.StationHello(protocol=wire.PROTOCOL, software="test"),
        ignore,
    )
    task = asyncio.create_task(link.run())
    try:
        async with asyncio.timeout(DEADLINE_S):
            while not link.last_error:
                await asyncio.sleep(0.05)
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    assert "revoked" in link.last_error and "(403)" in link.last_error, link.last_error
    assert any("revoked" in r.getMessage() for r in caplog.records)
