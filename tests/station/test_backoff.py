"""Reconnects and upload retries wait jittered, exponentially growing, bounded times; a
session the server refuses for good is kept aside and reported, not sent again."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import statistics
import time
import uuid
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import httpx
import pytest

from sessions import wire
from station import server_link, uploader
from station.app import Station
from station.backoff import Backoff
from station.config import StationConfig
from station.server_link import ServerLink
from station.spool import Spool
from station.uploader import Uploader
from tests.processes import free_port
from tests.server.live_server import Live, World, live, world
from tests.server.test_series import recording_bytes, samples
from webui.home.app import page_status

__all__ = ["live", "world"]  # the real server's fixtures, for the tests below

DEADLINE_S = 60.0
RETRYING = re.compile(r"retrying in ([0-9.]+) s")


def test_waits_are_jittered_bounded_and_grow() -> None:
    backoff = Backoff(first=1.0, cap=10.0)
    draws: dict[int, list[float]] = {n: [] for n in range(1, 9)}
    for _ in range(300):
        backoff.reset()
        for n in draws:
            draws[n].append(backoff.next())
    for n, waits in draws.items():
        bound = min(10.0, 1.0 * 2 ** (n - 1))
        assert all(0.0 <= w <= bound for w in waits), (n, max(waits))
        # jittered: spread over most of the window, not one value for every station
        assert max(waits) - min(waits) > 0.8 * bound, (n, min(waits), max(waits))
        assert len({round(w, 6) for w in waits}) > 250
    means = [statistics.fmean(draws[n]) for n in draws]
    assert means[0] < means[2] < means[4]  # grows until the cap holds it
    assert all(m < 6.0 for m in means)  # the cap: uniform in 0..10 has mean 5


def test_a_success_starts_again_from_the_first_window() -> None:
    backoff = Backoff(first=1.0, cap=10.0)
    for _ in range(6):
        backoff.next()
    backoff.reset()
    assert all(Backoff(1.0, 10.0).next() <= 1.0 for _ in range(50))
    assert backoff.next() <= 1.0


async def _waits(
    run: Coroutine[Any, Any, None], caplog: pytest.LogCaptureFixture, logger: str, count: int
) -> list[float]:
    """Run ``run`` until ``logger`` said "retrying in ..." ``count`` times; those waits."""
    task = asyncio.create_task(run)
    deadline = time.monotonic() + DEADLINE_S
    try:
        while True:
            found = [
                float(m.group(1))
                for r in caplog.records
                if r.name == logger and (m := RETRYING.search(r.getMessage()))
            ]
            if len(found) >= count or time.monotonic() > deadline:
                return found
            await asyncio.sleep(0.05)
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


@pytest.mark.asyncio
async def test_the_station_link_retries_an_absent_server_with_jittered_waits(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, "ankle.station.server")

    async def ignore(message: object) -> None:
        return None

    link = ServerLink(
        f"http://127.0.0.1:{free_port()}",
        "token",
        lambda: wire.StationHello(protocol=wire.PROTOCOL, software="test"),
        ignore,
    )
    waits = await _waits(link.run(), caplog, "ankle.station.server", 4)
    assert len(waits) >= 4, waits
    first = server_link.RECONNECT_FIRST_S
    for n, wait in enumerate(waits, start=1):
        assert 0.0 <= wait <= min(server_link.RECONNECT_MAX_S, first * 2 ** (n - 1)), waits
    assert "unreachable" in link.last_error


@pytest.mark.asyncio
async def test_uploads_retry_an_absent_server_with_jittered_waits(
    caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.INFO, "ankle.station.upload")
    spool = Spool(tmp_path)
    spool.path(str(uuid.uuid4())).write_bytes(b"a finished session")
    up = Uploader(f"http://127.0.0.1:{free_port()}", "token", spool)
    try:
        waits = await _waits(up.run(period=0.1), caplog, "ankle.station.upload", 3)
    finally:
        await up.aclose()
    assert len(waits) >= 3, waits
    for n, wait in enumerate(waits, start=1):
        assert 0.0 <= wait <= min(uploader.RETRY_MAX_S, uploader.RETRY_FIRST_S * 2 ** (n - 1))
    assert "unreachable" in up.last_error


def _station_client(live: Live, token: str, sent: list[tuple[str, str]]) -> httpx.AsyncClient:
    """The station's own client to ``live``, noting each request it sends (method, path)."""

    async def note(request: httpx.Request) -> None:
        sent.append((request.method, request.url.path))

    return httpx.AsyncClient(
        base_url=f"http://127.0.0.1:{live.client.base_url.port}",
        headers={"Authorization": f"Bearer {token}"},
        timeout=60.0,
        event_hooks={"request": [note]},
    )


@pytest.mark.asyncio
async def test_a_recording_the_server_refuses_is_kept_aside_once_and_reported(
    live: Live, world: World, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A recording with 100 NUL bytes after its end is refused (422, "not a valid recording:
    it is cut off"): it is sent once, moved to ``refused/`` byte for byte, logged once, and
    counted in the station's status and on the patient's page, while a good session after it
    still goes up."""
    caplog.set_level(logging.INFO, "ankle.station.upload")
    spool = Spool(tmp_path / "spool")
    bad_id, good_id = str(uuid.uuid4()), str(uuid.uuid4())
    rows = samples()[:200]
    bad = recording_bytes(bad_id, rows, world.s1_id, world.p1, world.rx1) + b"\0" * 100
    spool.path(bad_id).write_bytes(bad)
    good = recording_bytes(good_id, rows, world.s1_id, world.p1, world.rx1)
    spool.path(good_id).write_bytes(good)
    os.utime(spool.path(good_id), (time.time() + 1, time.time() + 1))  # after the bad one
    sent: list[tuple[str, str]] = []
    up = Uploader("", "", spool, _station_client(live, world.s1, sent))
    task = asyncio.create_task(up.run(period=0.05))
    try:
        async with asyncio.timeout(DEADLINE_S):
            while good_id not in up.uploaded:  # sent after the bad one
                await asyncio.sleep(0.05)
        await asyncio.sleep(1.0)  # some 20 rounds more: none may send the refused file
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await up.aclose()

    bad_requests = [r for r in sent if bad_id in r[1]]
    assert [m for m, _ in bad_requests] == ["HEAD", "PATCH", "POST"], bad_requests
    kept = tmp_path / "spool" / "refused" / f"{bad_id}.rec"
    assert kept.read_bytes() == bad  # the patient's data, whole
    assert spool.pending() == [] and up.pending() == 0
    assert "not a valid recording" in up.refused[bad_id]
    assert "cut off" in (kept.parent / f"{bad_id}.reason.txt").read_text()
    lines = [r for r in caplog.records if bad_id in r.getMessage()]
    assert len(lines) == 1 and lines[0].levelno == logging.ERROR, lines
    assert "422" in lines[0].getMessage() and "refused" in lines[0].getMessage()
    r = await live.client.head(
        f"/uploads/{good_id}", headers={"Authorization": f"Bearer {world.s1}"}
    )
    assert r.headers["Upload-Complete"] == "1"

    # A station started on this spool reports it: to the server and on the patient's page.
    station = Station(
        StationConfig(
            device="socket://127.0.0.1:1",
            server="http://127.0.0.1:1",
            token="t",
            spool=tmp_path / "spool",
        )
    )
    try:
        status = station.status()
        assert status.refused_uploads == 1
        assert status.refused_sessions[0].startswith(f"{bad_id}: ")
        assert "not a valid recording" in status.refused_sessions[0]
        assert status.pending_uploads == 0
        assert page_status(station).refused_uploads == 1
    finally:
        await station.uploader.aclose()


@pytest.mark.asyncio
async def test_a_refusal_that_may_pass_is_retried_with_jittered_waits_and_the_file_kept(
    live: Live, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A token the server does not know (401) may be put right: the file stays queued and
    is tried again after growing, jittered waits, not every round."""
    caplog.set_level(logging.INFO, "ankle.station.upload")
    spool = Spool(tmp_path)
    sid = str(uuid.uuid4())
    spool.path(sid).write_bytes(b"a finished session")
    sent: list[tuple[str, str]] = []
    up = Uploader("", "", spool, _station_client(live, "not-a-station-token", sent))
    try:
        waits = await _waits(up.run(period=0.05), caplog, "ankle.station.upload", 3)
    finally:
        await up.aclose()
    assert len(waits) >= 3, waits
    for n, wait in enumerate(waits, start=1):
        assert 0.0 <= wait <= min(uploader.RETRY_MAX_S, uploader.RETRY_FIRST_S * 2 ** (n - 1))
    assert "401" in up.last_error
    assert spool.pending() == [spool.path(sid)] and up.refused == {}
    assert not (tmp_path / "refused").exists()
