"""What the patient's page says while the station cannot open the platform's link: a
sentence, not the link's error numbers ("[Errno 19] cannot open socket://…: [Errno 111]
Connect call failed")."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from pathlib import Path

import pytest

from station.app import Station
from station.config import StationConfig
from tests.processes import free_port
from webui.home.app import page_status


@pytest.mark.asyncio
async def test_a_platform_nobody_answers_for_is_said_in_a_sentence(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, "ankle.station")
    link = f"socket://127.0.0.1:{free_port()}"  # nothing listens there
    station = Station(
        StationConfig(
            device=link,
            server=f"http://127.0.0.1:{free_port()}",
            token="not-used-offline",
            spool=tmp_path / "spool",
        )
    )
    task = asyncio.create_task(station.run())
    try:
        async with asyncio.timeout(30.0):
            while not station.status().message:
                assert not task.done(), task
                await asyncio.sleep(0.05)
        said = page_status(station).message
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    assert said == (
        f"cannot reach the platform: nothing answers at {link}: is the platform switched on "
        "and connected?"
    ), said
    assert "Errno" not in said
    # The link's own words are kept for a technician, in the log, once.
    logged = [
        r.getMessage() for r in caplog.records if "cannot reach the platform" in r.getMessage()
    ]
    assert len(logged) == 1 and "Errno 111" in logged[0], logged
