"""Live K/B changes that overlap: two therapists' views (or one view's two quick clicks) send
changes milliseconds apart, and the second reaches the station while the first waits for the
device's ACK. Each change's before and after, as its answer, the session's event and the
server's audit row carry them, must be its own, and undoing a change the device refused must
not put back a value over a change made since. A real station and the simulated device on a
real pty; no server (the station works offline)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio

from device.hardware import SimulatedHardware
from device.plant.params import PlantConfig
from device.service import WATCHDOG_MS_MAX, ServiceConfig
from device.transport import PtyLink
from sessions import wire
from sessions.prescription import PrescriptionBody
from sessions.recording import recover
from station.app import Station
from tests.device.service_thread import service_in_thread
from tests.station.offline import exercising
from tests.system.harness import short_strength

BODY = PrescriptionBody.model_validate(short_strength("Overlapping changes", 3))
"""K 40 N m/rad and B 2 N m s/rad in pitch, 4 s repetitions."""


@pytest.fixture
def device() -> Iterator[PtyLink]:
    hardware = SimulatedHardware(PlantConfig(patient="relaxed"), seed=11)
    # The longest watchdog the device allows: the test shares its process with the device.
    config = ServiceConfig(telemetry_hz=100, watchdog_ms=WATCHDOG_MS_MAX)
    with service_in_thread(hardware, config) as link:
        yield link


@pytest_asyncio.fixture
async def running(device: PtyLink, tmp_path: Path) -> AsyncIterator[Station]:
    """A station whose exercise is in a repetition (the device ACTIVE)."""
    async with exercising(device.name, tmp_path / "spool", BODY) as station:
        yield station


def change(request_id: str, **values: Any) -> wire.Command:
    return wire.Command(request_id=request_id, action="set_impedance", by="therapist:1", **values)


def impedance_events(station: Station) -> list[dict[str, Any]]:
    """The session's impedance events as written so far."""
    assert station.writer is not None
    station.writer.flush_soon()
    return [e.detail for e in recover(station.writer.path).events if e.kind == "impedance"]


@pytest.mark.asyncio
async def test_two_changes_at_once_each_report_their_own_before_and_after(
    running: Station,
) -> None:
    """The second change used to be merged while the first waited for its ACK, and the
    first then reported the second's K as its own new value (the audit saw K 70 twice and
    the 30 asked for nowhere)."""
    t0 = time.perf_counter()
    a, b = await asyncio.gather(
        running.command(change("a", stiffness={"pitch": 30.0})),
        running.command(change("b", stiffness={"pitch": 70.0})),
    )
    took = time.perf_counter() - t0
    assert a.ok and b.ok, (a, b)
    assert a.change is not None and b.change is not None
    assert (a.change.old.stiffness, a.change.new.stiffness) == ({"pitch": 40.0}, {"pitch": 30.0})
    assert (b.change.old.stiffness, b.change.new.stiffness) == ({"pitch": 30.0}, {"pitch": 70.0})
    assert a.change.applies == b.change.applies == "now"
    assert running.run_ is not None and running.run_.stiffness == {"pitch": 70.0}
    # The session's record says the same, in the order they were made.
    assert impedance_events(running) == [
        a.change.model_dump(mode="json"),
        b.change.model_dump(mode="json"),
    ]
    print(f"\ntwo overlapping K changes answered in {took * 1e3:.0f} ms")


@pytest.mark.asyncio
async def test_a_refused_change_is_undone_without_undoing_the_one_made_since(
    running: Station,
) -> None:
    """B 0.1 is below the least damping the device allows at K 40 (it refuses it); the K
    change sent meanwhile carried that B too and was refused with it, and the first's undo
    put back its before over the second's K: the station believed K 40 after an accepted
    change to 70, or the reverse."""
    a, b = await asyncio.gather(
        running.command(change("a", damping={"pitch": 0.1})),
        running.command(change("b", stiffness={"pitch": 70.0})),
    )
    assert not a.ok and a.code == "OUT_OF_RANGE" and a.field == "damping", a
    assert b.ok and b.change is not None, b
    assert (b.change.old.stiffness, b.change.new.stiffness) == ({"pitch": 40.0}, {"pitch": 70.0})
    run = running.run_
    assert run is not None
    assert (run.stiffness, run.damping) == ({"pitch": 70.0}, {"pitch": 2.0})
    # What the device renders agrees: its telemetry's K and B in pitch.
    dev = running.dev
    assert dev is not None
    async with asyncio.timeout(10.0):
        while dev.latest is None or round(float(dev.latest.stiffness[4]), 3) != 70.0:
            await asyncio.sleep(0.02)
    assert round(float(dev.latest.damping[4]), 3) == 2.0
    assert impedance_events(running) == [b.change.model_dump(mode="json")]
