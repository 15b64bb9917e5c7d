"""A real station working offline (no server listens) on a real device link, in a
repetition of its one prescription: what the station tests that drive a running exercise
start from."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

from device.protocol.messages import DeviceMode
from sessions import wire
from sessions.prescription import PrescriptionBody
from station.app import Station
from station.config import StationConfig
from tests.processes import free_port

PRESCRIPTION_ID = 7


@contextlib.asynccontextmanager
async def exercising(
    link: str, spool: Path, body: PrescriptionBody, timeout: float = 60.0
) -> AsyncIterator[Station]:
    """A station on ``link`` whose exercise (``body``) is in a repetition, the device ACTIVE;
    stopped on the way out."""
    station = Station(
        StationConfig(
            device=link,
            server=f"http://127.0.0.1:{free_port()}",  # nobody listens: offline
            token="not-used-offline",
            spool=spool,
        )
    )
    station.prescriptions = [
        wire.PrescriptionItem(id=PRESCRIPTION_ID, version=1, patient_id=3, body=body)
    ]
    task = asyncio.create_task(station.run())
    try:
        async with asyncio.timeout(timeout):
            while station.dev is None:
                assert not task.done(), task
                await asyncio.sleep(0.05)
            assert station.start(PRESCRIPTION_ID) == ""
            while not (
                station.run_ is not None
                and station.run_.phase == "running"
                and station.dev.mode == DeviceMode.ACTIVE
            ):
                assert not task.done(), task
                await asyncio.sleep(0.02)
        yield station
    finally:
        task.cancel()
        await asyncio.wait({task}, timeout=20.0)
