"""The station standing still, and the device's link lost, mid-exercise: a real station in
this process and the simulated device in its own (``ankle device --sim`` on a pty, stopped
with SIGSTOP as a device that stalls); no server (the station works offline).

A station that stood still for longer than it waits for the device's telemetry closed the
session as the device's lost link, the device's watchdog hold (waiting unread in the port)
left out of it. And a device left holding the segment of an exercise the station had ended
(its link lost) moved it again on Resume, with no session recording it and a Stop that said
"no exercise is running"."""

from __future__ import annotations

import asyncio
import os
import signal
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
import pytest_asyncio

from device.process import ServiceProcess
from device.protocol.messages import DeviceMode
from sessions import wire
from sessions.prescription import PrescriptionBody
from sessions.recording import recover
from station.app import DEVICE_STALE_S, ENDED, Station
from station.timeline import HOMING_TIMEOUT_S
from tests.station.offline import exercising
from tests.system.harness import WATCHDOG_MS, short_strength

BODY = PrescriptionBody.model_validate(short_strength("Ended early", 3))
STILL_S = DEVICE_STALE_S + 1.0
"""Longer than the station waits for the device's telemetry before it drops the link."""


@pytest.fixture
def device() -> Iterator[ServiceProcess]:
    with ServiceProcess(
        "--link", "pty", "--patient-torque", "3", "--watchdog-ms", str(WATCHDOG_MS)
    ) as service:
        yield service


async def until(what: str, done: object, timeout: float) -> None:
    """Wait until ``done()`` is true (polled)."""
    assert callable(done)
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout:g} s: {what}")
        await asyncio.sleep(0.02)


@pytest_asyncio.fixture
async def running(device: ServiceProcess, tmp_path: Path) -> AsyncIterator[Station]:
    """A station whose exercise is in a repetition (the device ACTIVE)."""
    async with exercising(device.link, tmp_path / "spool", BODY) as station:
        yield station


def command(action: wire.Action) -> wire.Command:
    return wire.Command(request_id=action, action=action, by="therapist:1")


@pytest.mark.asyncio
async def test_a_station_that_stood_still_keeps_its_exercise_and_the_watchdogs_hold(
    running: Station,
) -> None:
    run, sid = running.run_, running.session_id
    assert run is not None and running.writer is not None
    path = running.writer.path
    time.sleep(STILL_S)  # the station's event loop blocked: as if its process were stopped
    # Awake again, it reads what the device sent meanwhile (the watchdog's hold among it)
    # before it judges the link: the exercise goes on, paused by the device.
    await until("the watchdog's hold heard", lambda: run.phase == "paused", 10.0)
    named = "the home station's computer stood still and sent nothing for "
    await until("the stall named", lambda: named in str(running.status().hold), 10.0)
    assert running.run_ is run and running.session_id == sid, running.status()
    assert not run.link_lost and not run.ending, run.message
    status = running.status()
    assert status.device_link == "connected" and status.device_mode == "HOLD", status
    hold = status.hold
    assert hold is not None and hold.code == "watchdog", hold
    # Named as the station's own stall, which covers the silence the device measured.
    quiet = float(hold.text.split("sent nothing for ")[1].split(" ms")[0])
    silence = float(hold.text.split("no frame from the station for ")[1].split(" ms")[0])
    assert quiet >= STILL_S * 1e3 > silence, hold.text

    # Resumed, it carries on; stopped, the session ends stopped, the hold in its record.
    assert (await running.command(command("resume"))).ok
    await until("resumed", lambda: run.phase == "running", 10.0)
    assert (await running.command(command("stop"))).ok
    await until("the session ended", lambda: running.run_ is None, HOMING_TIMEOUT_S + 10.0)
    rec = recover(path)
    assert rec.end is not None and rec.end.reason == "stopped", rec.end
    kinds = [(e.kind, e.by) for e in rec.events]
    assert ("watchdog", "device") in kinds and ("interrupted", "station") not in kinds, kinds


@pytest.mark.asyncio
@pytest.mark.parametrize("action", ["resume", "stop"])
async def test_a_segment_left_by_a_lost_link_goes_home_and_is_never_resumed(
    running: Station, device: ServiceProcess, action: wire.Action
) -> None:
    run, first = running.run_, running.dev
    assert run is not None
    os.kill(device.pid, signal.SIGSTOP)  # the device stalls: the station loses its link
    try:
        await until("the link lost", lambda: running.run_ is None, STILL_S + 30.0)
    finally:
        os.kill(device.pid, signal.SIGCONT)
    assert run.link_lost and run.phase == "interrupted", run.message
    # Connected again, the device holds the ended exercise's segment.
    await until(
        "the device holding, connected again",
        lambda: (
            running.dev is not None
            and running.dev is not first
            and running.dev.mode == DeviceMode.HOLD
        ),
        30.0,
    )
    dev = running.dev
    assert dev is not None and dev.latest is not None and dev.latest.segment_id != 0
    result = await running.command(command(action))
    if action == "resume":
        # Nothing would record the motion: refused, in words.
        assert not result.ok and result.code == "REFUSED" and result.text == ENDED, result
    else:
        # It ends that segment, rather than saying nothing runs while the platform holds.
        assert result.ok, result
    # Either way (the station sends it home by itself), the platform goes home, and never
    # moves as the ended exercise again.
    modes: list[DeviceMode] = []

    def home() -> bool:
        modes.append(dev.mode or DeviceMode.IDLE)
        return dev.mode == DeviceMode.READY

    await until("home", home, HOMING_TIMEOUT_S + 10.0)
    assert DeviceMode.ACTIVE not in modes, modes
    assert DeviceMode.HOMING in modes, modes
    assert running.run_ is None and running.status().hold is None, running.status()
    # Nothing is left to resume now either.
    again = await running.command(command("resume"))
    assert not again.ok and again.code == "REFUSED", again
