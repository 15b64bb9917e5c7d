"""Events from before an exercise began are history to it: a station that connects to a
device with a past (an e-stop pressed yesterday and re-armed) and starts an exercise at
once, as the patient's station does on its own, must not be stopped by the device's replay
of that past. A real simulated device over a pty and the real client."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest

from device.client import DeviceClient
from device.hardware import SimulatedHardware
from device.plant.params import PlantConfig
from device.protocol import messages as msg
from device.protocol.messages import DeviceMode, EventKind
from device.service import ServiceConfig
from device.transport import PtyLink
from sessions.prescription import PrescriptionBody
from station.timeline import ExerciseRun
from tests.device.service_thread import service_in_thread
from tests.system.harness import short_strength

BODY = PrescriptionBody.model_validate(short_strength("History test", 1))


@pytest.fixture
def link() -> Iterator[PtyLink]:
    hardware = SimulatedHardware(PlantConfig(patient="relaxed"), seed=5)
    with service_in_thread(hardware, ServiceConfig(telemetry_hz=50, watchdog_ms=2000)) as link:
        yield link


def test_a_run_started_as_the_station_connects_ignores_the_devices_replayed_past(
    link: PtyLink,
) -> None:
    async def main() -> None:
        # Yesterday: an e-stop, then a re-arm.
        dev = await DeviceClient.connect(link.name, command_timeout=0.3, retries=5)
        await dev.estop()
        await dev.rearm()
        await dev.close()

        # Today: the station connects and starts at once, before any telemetry came.
        dev = await DeviceClient.connect(link.name, command_timeout=0.3, retries=5)
        try:
            run = ExerciseRun(dev, 1, BODY, lambda e: None, lambda: None)
            heard: list[msg.Event] = []

            async def watch() -> None:
                async for e in dev.events():
                    heard.append(e)
                    run.device_event(e)

            watcher = asyncio.create_task(watch())
            session = asyncio.create_task(run.run())
            async with asyncio.timeout(60.0):
                while run.phase != "running":
                    assert not session.done(), await session
                    await asyncio.sleep(0.05)
            run.stop()
            end = await asyncio.wait_for(session, 60.0)
            watcher.cancel()

            # The past was heard (replayed), and did not stop the run.
            assert any(e.kind == EventKind.ESTOP for e in heard), heard
            assert end.reason == "stopped", end  # by this test's stop, after it ran
            assert run.reps_done == 0 and "emergency" not in end.text.lower(), end
            assert (await dev.wait_for_mode(DeviceMode.READY, timeout=30)).mode == (
                DeviceMode.READY
            )
        finally:
            await dev.close()

    asyncio.run(main())
