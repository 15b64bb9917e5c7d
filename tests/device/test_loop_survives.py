"""Nothing inside a pass of the device loop ends the service.

An error is raised once inside each stage of a pass while a segment runs (reading the link,
applying a command, the control chunk reading the hardware, the mode machine, building
telemetry, flushing the link). Each time the device latches FAULT with trip SOFTWARE, every
valve is closed, an event names the stage, and the service goes on: it answers commands,
sends telemetry, and after a re-arm it homes and runs again.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from device.client import CommandRefused, DeviceClient, build_segment
from device.hardware import Hardware, SimulatedHardware
from device.plant.params import PlantConfig
from device.protocol import messages as m
from device.protocol.messages import DeviceMode, EventKind, NackCode
from device.rig import Rig
from device.service import WATCHDOG_MS_MAX, DeviceService, ServiceConfig
from device.transport import READ_MAX, PtyLink
from device.trips import Trip
from tests.device.test_service import PITCH


class Breaker:
    """Raises once, the first time it is passed while armed."""

    def __init__(self) -> None:
        self.armed = False
        self.fired = 0

    def __call__(self, where: str) -> None:
        if self.armed:
            self.armed = False
            self.fired += 1
            raise RuntimeError(f"injected failure in {where}")


class BreakingLink(PtyLink):
    def __init__(self, breaker: Breaker, where: str) -> None:
        super().__init__()
        self.breaker = breaker
        self.where = where

    def read(self, limit: int = READ_MAX) -> bytes:
        if self.where == "read":
            self.breaker("link read")
        return super().read(limit)

    def flush(self) -> None:
        if self.where == "flush":
            self.breaker("link flush")
        super().flush()


class BreakingHardware(Hardware):
    """The plant behind the plain hardware interface (so the loop runs tick by tick in
    Python, as on a board), with sensor reads that can fail."""

    def __init__(self, breaker: Breaker) -> None:
        self.sim = SimulatedHardware(PlantConfig(patient="relaxed"), seed=5)
        self.breaker = breaker

    def read_sensors(self, out: NDArray[np.float64]) -> None:
        self.breaker("sensor read")
        self.sim.read_sensors(out)

    def write_valves(self, valves: NDArray[np.uint8]) -> None:
        self.sim.write_valves(valves)

    def wait_tick(self) -> None:
        self.sim.wait_tick()


@dataclass
class Running:
    service: DeviceService
    link: PtyLink
    breaker: Breaker
    thread: threading.Thread


STAGES = ("read", "flush", "sensors", "modes", "telemetry", "command")


@pytest.fixture(params=STAGES)
def running(request: pytest.FixtureRequest) -> Iterator[Running]:
    stage: str = request.param
    breaker = Breaker()
    link = BreakingLink(breaker, stage)
    hardware: Hardware = (
        BreakingHardware(breaker)
        if stage == "sensors"
        else SimulatedHardware(PlantConfig(patient="relaxed"), seed=5)
    )
    # The longest watchdog the device allows: this test is about errors inside a pass, and
    # a host stall on a machine shared with other tests must not stop the homing it waits for.
    service = DeviceService(
        Rig(hardware), link, ServiceConfig(telemetry_hz=100, watchdog_ms=WATCHDOG_MS_MAX)
    )
    if stage == "modes":
        step = service.modes.step

        def breaking_step() -> None:
            breaker("mode machine")
            step()

        service.modes.step = breaking_step  # type: ignore[method-assign]
    elif stage == "telemetry":
        build = service.telemetry

        def breaking_telemetry() -> m.Telemetry:
            breaker("telemetry")
            return build()

        service.telemetry = breaking_telemetry  # type: ignore[method-assign]
    elif stage == "command":
        apply_impedance = service.modes.set_impedance

        def breaking_impedance(c: object) -> None:
            breaker("command")
            apply_impedance(c)  # type: ignore[arg-type]

        service.modes.set_impedance = breaking_impedance  # type: ignore[method-assign]
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    yield Running(service, link, breaker, thread)
    service.stop()
    thread.join(5.0)
    assert not thread.is_alive(), "the service loop did not stop"
    service.shutdown()


def test_an_error_in_any_stage_latches_fault_and_the_service_goes_on(running: Running) -> None:
    service = running.service

    async def main() -> None:
        dev = await DeviceClient.connect(running.link.name, command_timeout=0.5)
        try:
            events: list[m.Event] = []

            async def collect() -> None:
                async for e in dev.events():
                    events.append(e)

            collector = asyncio.create_task(collect())
            assert dev.hello is not None
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            await dev.start_segment(build_segment(dev.hello, 1, 30.0, {"pitch": PITCH}))
            await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=2.0)
            await asyncio.sleep(0.5)

            running.breaker.armed = True
            if service.modes.set_impedance.__name__ == "breaking_impedance":
                with pytest.raises(CommandRefused) as err:
                    await dev.set_impedance((0, 0, 0, 0, 40.0, 0), (0, 0, 0, 0, 1.0, 0))
                assert err.value.nack.code == NackCode.DEVICE_FAULT
            t = await dev.wait_for_mode(DeviceMode.FAULT, timeout=2.0)
            assert running.breaker.fired == 1
            assert t.trip == Trip.SOFTWARE
            assert service.software_faults == 1
            assert not service.rig.state.valves.any()

            # Still serving: commands are answered and telemetry keeps coming.
            await dev.configure(50, WATCHDOG_MS_MAX)
            before = dev.stats.frames
            await asyncio.sleep(0.3)
            assert dev.stats.frames > before + 5
            assert dev.latest is not None and dev.latest.mode == DeviceMode.FAULT
            with pytest.raises(CommandRefused) as latched:
                await dev.arm_home()
            assert latched.value.nack.code == NackCode.LATCHED

            # Re-armed, it homes and runs again.
            await dev.rearm()
            await dev.wait_for_mode(DeviceMode.IDLE, timeout=2.0)
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            await dev.start_segment(build_segment(dev.hello, 2, 0.5, {"pitch": PITCH}))
            await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=2.0)

            fault = [e for e in events if e.kind == EventKind.FAULT]
            assert len(fault) == 1 and fault[0].code == Trip.SOFTWARE
            assert "injected failure" in fault[0].text
            collector.cancel()
        finally:
            await dev.close()

    asyncio.run(main())
    assert running.thread.is_alive()


def test_a_stage_that_keeps_failing_never_stops_the_loop() -> None:
    """A link whose read fails on every pass: the device latches FAULT once and keeps
    running its passes (valves closed), logging only the first few tracebacks."""
    breaker = Breaker()
    link = BreakingLink(breaker, "read")
    service = DeviceService(
        Rig(SimulatedHardware(PlantConfig(patient="relaxed"))), link, ServiceConfig()
    )
    rearm: Callable[[], None] = lambda: setattr(breaker, "armed", True)  # noqa: E731
    try:
        for _ in range(50):
            rearm()
            service.step()
        assert service.mode == DeviceMode.FAULT
        assert service.software_faults == 50
        assert [e.kind for e in service.events].count(EventKind.FAULT) == 1
        assert not service.rig.state.valves.any()
        assert service.rig.time > 49 * 7 / 7000  # the control chunk ran every pass
    finally:
        service.shutdown()
