"""Reconnects and upload retries wait jittered, exponentially growing, bounded times."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import statistics
import time
import uuid
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

import pytest

from sessions import wire
from station import server_link, uploader
from station.backoff import Backoff
from station.server_link import ServerLink
from station.spool import Spool
from station.uploader import Uploader
from tests.processes import free_port

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
