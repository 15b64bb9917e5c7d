"""STOP right after a repetition starts: the platform holds and goes home, whatever the
newest telemetry said when STOP came.

A real simulated device over a pty and the real client. Telemetry at 2 Hz makes the window
every station has (a segment ACKed, its ACTIVE not yet in a telemetry sample) half a second
wide, so the test always lands in it."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest

from device.client import DeviceClient
from device.hardware import SimulatedHardware
from device.plant.params import PlantConfig
from device.protocol import messages as msg
from device.protocol.messages import DeviceMode
from device.service import ServiceConfig
from device.transport import PtyLink
from sessions.prescription import PrescriptionBody
from station.timeline import ExerciseRun
from tests.device.service_thread import service_in_thread
from tests.system.harness import short_strength

BODY = PrescriptionBody.model_validate(short_strength("Stop test", 2))


@pytest.fixture
def link() -> Iterator[PtyLink]:
    hardware = SimulatedHardware(PlantConfig(patient="relaxed"), seed=5)
    with service_in_thread(hardware, ServiceConfig(telemetry_hz=2, watchdog_ms=2000)) as link:
        yield link


def test_stop_as_a_repetition_starts_holds_and_homes_though_telemetry_lags(
    link: PtyLink,
) -> None:
    async def main() -> None:
        dev = await DeviceClient.connect(link.name, command_timeout=0.3, retries=5)
        try:
            run = ExerciseRun(dev, 1, BODY, lambda e: None, lambda: None)
            stale: list[DeviceMode] = []
            start_segment = dev.start_segment

            async def start_then_stop(segment: msg.StartSegment) -> msg.Ack:
                ack = await start_segment(segment)
                assert ack.mode == DeviceMode.ACTIVE
                assert dev.latest is not None
                stale.append(dev.latest.mode)  # what the station believes as STOP comes
                run.stop()  # the patient presses STOP the moment the repetition starts
                return ack

            dev.start_segment = start_then_stop  # type: ignore[method-assign]
            events: list[msg.Event] = []

            async def watch() -> None:
                async for e in dev.events():
                    events.append(e)
                    run.device_event(e)

            watcher = asyncio.create_task(watch())
            end = await asyncio.wait_for(run.run(), 120)
            watcher.cancel()

            assert stale == [DeviceMode.READY], "the test must catch the telemetry lagging"
            assert dev.mode == DeviceMode.READY, "the run ended before the platform was home"
            assert end.reason == "stopped", end
            assert "could not go home" not in end.text, end.text
            modes = [e.mode_to for e in events if e.kind == msg.EventKind.MODE_CHANGE]
            assert DeviceMode.HOLD in modes, modes  # held at once, not run out
            assert not any(e.kind == msg.EventKind.SEGMENT_DONE for e in events), events
            fresh = await dev.wait_for_mode(DeviceMode.READY, timeout=30)
            assert fresh.mode == DeviceMode.READY
        finally:
            await dev.close()

    asyncio.run(main())
