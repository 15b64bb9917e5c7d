"""The station's own disk and clock under a running exercise: a spool that fills up, and a
wall clock set back or forward. A real station in this process and the simulated device in
its own (``ankle device --sim`` on a pty); no server (the station works offline). The full
disk is made at the session file's writes (``os.write`` to its descriptor) and at
``statvfs``; the clock is ``time.time`` alone, the monotonic clock left as it is."""

from __future__ import annotations

import asyncio
import errno
import os
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from device.process import ServiceProcess
from device.protocol.messages import DeviceMode
from sessions import wire
from sessions.prescription import PrescriptionBody
from sessions.recording import check_session, read
from station.timeline import HOMING_TIMEOUT_S
from tests.station.offline import PRESCRIPTION_ID, exercising
from tests.system.harness import WATCHDOG_MS, short_strength
from webui.home.app import page_status

BODY = PrescriptionBody.model_validate(short_strength("Disk and clock", 3))


@pytest.fixture
def device() -> Iterator[ServiceProcess]:
    with ServiceProcess(
        "--link", "pty", "--patient-torque", "3", "--watchdog-ms", str(WATCHDOG_MS)
    ) as service:
        yield service


async def until(what: str, done: object, timeout: float) -> None:
    assert callable(done)
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout:g} s: {what}")
        await asyncio.sleep(0.02)


def station_running() -> bool:
    return any(
        t.get_coro().__qualname__ == "Station.run" and not t.done()  # type: ignore[union-attr]
        for t in asyncio.all_tasks()
    )


@pytest.mark.asyncio
@pytest.mark.parametrize("stays_full", [False, True])
async def test_a_disk_that_fills_mid_exercise_stops_it_safely_and_the_station_carries_on(
    device: ServiceProcess, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, stays_full: bool
) -> None:
    """ENOSPC in the session file's write crashed the station: the device was left to its
    watchdog's hold, the patient read "the platform's link was lost: closed by this host".
    Now the exercise stops as on STOP, the session ends saying the disk is full, with what
    was written before, and the station goes on; a Start then is refused in a sentence."""
    async with exercising(device.link, tmp_path / "spool", BODY) as station:
        run, writer = station.run_, station.writer
        assert run is not None and writer is not None
        path = writer.path
        await until("samples on disk", lambda: writer.samples_written >= 50, 10.0)
        real = os.write
        failures: list[int] = []

        def full(fd: int, data: bytes | memoryview) -> int:
            if fd != writer._fd:
                return real(fd, data)
            if not failures or stays_full:  # the disk takes part of a block, then refuses
                failures.append(real(fd, bytes(data)[: len(data) // 2]))
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real(fd, data)  # the cut-back block freed room for the end record

        monkeypatch.setattr(os, "write", full)
        modes: list[DeviceMode] = []

        def ended() -> bool:
            dev = station.dev
            modes.append(dev.mode if dev is not None and dev.mode is not None else DeviceMode.IDLE)
            return station.run_ is None

        await until("the exercise stopped", ended, HOMING_TIMEOUT_S + 10.0)
        assert failures, "the test must fill the disk"
        assert station_running() and station.dev is not None
        assert run.phase == "interrupted" and not run.link_lost, run.message
        assert DeviceMode.HOLD in modes or DeviceMode.HOMING in modes, modes
        await until("the platform home", lambda: station.dev.mode == DeviceMode.READY, 30.0)
        page = page_status(station)
        assert page.message.startswith("the station's disk is full: the exercise was stopped")
        assert not page.link_lost

        rec = read(path)
        assert not rec.damaged, rec  # the torn block cut back: whole records only
        assert len(rec.samples) >= 50  # what was written before is kept
        if stays_full:
            # No end record: not sent (the server refuses a cut-off file) until the next
            # start closes it from what it holds.
            assert rec.end is None
            assert page.message.endswith("; the session's end could not be recorded")
            assert station.uploader.pending() == 0 and path.exists()
        else:
            assert rec.end is not None and rec.end.reason == "interrupted", rec.end
            assert rec.end.text.startswith("the station's disk is full"), rec.end.text

        # The spool's disk is full before a Start: refused in words, nothing written.
        def no_room(where: object) -> os.statvfs_result:
            return os.statvfs_result((4096, 4096, 1 << 20, 10, 10, 1000, 10, 10, 0, 255))

        monkeypatch.setattr(os, "statvfs", no_room)
        before = sorted(p.name for p in (tmp_path / "spool").glob("*.rec"))
        why = station.start(PRESCRIPTION_ID)
        assert why.startswith(
            "the station's disk is too full to record this exercise: 0.0 MB free where "
            "sessions are kept, and it needs 6.8 MB"  # 12 s at 100 Hz, a hold and a homing
        ), why
        assert "free some space on the station, then start again" in why
        assert station.run_ is None and station.writer is None
        assert sorted(p.name for p in (tmp_path / "spool").glob("*.rec")) == before
        assert station.status().message == why and station_running()


@pytest.mark.asyncio
async def test_a_clock_set_back_then_forward_mid_session_keeps_its_order_and_length(
    device: ServiceProcess, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Start and end came from the wall clock: set back during a session, it ended before
    it started (refused by the server for good); set forward by hours, a short session
    lasted hours. Now its time is counted from its start on the monotonic clock."""
    real = time.time
    shift = [0.0]
    monkeypatch.setattr(time, "time", lambda: real() + shift[0])
    began = time.monotonic()
    async with exercising(device.link, tmp_path / "spool", BODY) as station:
        assert station.writer is not None
        path = station.writer.path
        await asyncio.sleep(1.0)
        shift[0] = -3 * 3600.0  # set back three hours
        await asyncio.sleep(1.0)
        shift[0] = 5 * 3600.0  # then five hours ahead
        await asyncio.sleep(1.0)
        stop = wire.Command(request_id="stop", action="stop", by="patient")
        assert (await station.command(stop)).ok
        await until("the session ended", lambda: station.run_ is None, HOMING_TIMEOUT_S + 10.0)
    lasted = time.monotonic() - began
    rec = read(path)
    assert rec.end is not None and rec.end.reason == "stopped", rec.end
    elapsed = rec.end.ended_at - rec.header.started_at
    assert 3.0 <= elapsed <= lasted, (elapsed, lasted)
    walls = rec.samples["wall"].astype(np.float64)
    assert np.all(np.diff(walls) >= 0.0) and walls[0] >= rec.header.started_at
    assert walls[-1] <= rec.end.ended_at
    assert all(rec.header.started_at <= e.wall <= rec.end.ended_at for e in rec.events)
    check_session(rec)  # what the server asks of it: it would be filed


@pytest.mark.asyncio
async def test_a_clock_set_back_during_a_hold_does_not_stretch_the_hold_limit(
    device: ServiceProcess, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """How long an exercise had been held came from the wall clock: set back an hour during
    a hold, it kept the patient's foot in a held platform an hour past the limit. Held 2 s
    past its limit, it ends, however the clock moves."""
    real = time.time
    shift = [0.0]
    monkeypatch.setattr(time, "time", lambda: real() + shift[0])
    async with exercising(device.link, tmp_path / "spool", BODY) as station:
        station.config = station.config.model_copy(update={"hold_limit_s": 2.0})
        hold = wire.Command(request_id="hold", action="hold", by="therapist")
        assert (await station.command(hold)).ok
        await until("the exercise held", lambda: station._hold() is not None, 30.0)
        shift[0] = -3600.0  # set back an hour
        # Ends 2 s after the hold (an hour and 2 s without the fix): the bound is a busy
        # machine's, far under the hour.
        await until("the held exercise ended", lambda: station.run_ is None, 60.0)
        assert station.writer is None or station.writer.path.exists()
