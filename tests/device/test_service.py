"""The device service over a real pty, driven by the real client: modes, refusals, safety."""

import asyncio
import itertools
import math
import threading
import time
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pytest

from device import controller as ctl
from device.client import (
    HEARTBEATS_PER_WATCHDOG,
    STALL_S,
    AxisPlan,
    ClientStats,
    CommandRefused,
    DeviceClient,
    Stall,
    build_segment,
)
from device.controller import Mode, Waveform
from device.hardware import SimulatedHardware
from device.identify import lower_and_vent
from device.plant.model import SCRIPT_SINE
from device.plant.params import PlantConfig
from device.protocol import messages as m
from device.protocol.framing import Frame, encode_frame
from device.protocol.messages import DeviceMode, EventKind, NackCode
from device.rig import Rig
from device.safety import SafetyLimits, Trip
from device.service import (
    EVENTS_KEPT,
    WATCHDOG_MS_MAX,
    WATCHDOG_MS_MIN,
    DeviceService,
    ServiceConfig,
)
from device.transport import PtyLink
from tests.device.service_thread import service_in_thread


@dataclass
class Running:
    service: DeviceService
    link: PtyLink
    thread: threading.Thread


@pytest.fixture
def device() -> Iterator[Running]:
    link = PtyLink()
    service = DeviceService(
        Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=3)),
        link,
        # The longest watchdog the device allows: a host stall on a machine shared with
        # other tests must not stop a homing these tests wait for. The watchdog's own test
        # sets the short one it measures.
        ServiceConfig(telemetry_hz=100, watchdog_ms=WATCHDOG_MS_MAX),
    )
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    yield Running(service, link, thread)
    service.stop()
    thread.join(5.0)
    assert not thread.is_alive(), "the service loop did not stop"
    service.shutdown()


def drive(device: Running, body: Callable[[DeviceClient], Awaitable[None]]) -> None:
    async def main() -> None:
        # What these tests check is what the device answers, not how fast: on a machine
        # shared with other tests a pass of the service may wait longer than the station's
        # 4 tries of 100 ms, so the test's client allows 6 tries of 300 ms.
        client = await DeviceClient.connect(device.link.name, command_timeout=0.3, retries=5)
        try:
            await body(client)
        finally:
            await client.close()

    asyncio.run(main())


PITCH = AxisPlan(
    Waveform.SINE,
    amplitude=math.radians(6.0),
    frequency=0.5,
    stiffness=30.0,
    damping=1.0,
    compliant=True,
)


async def home(dev: DeviceClient) -> None:
    await dev.arm_home()
    await dev.wait_for_mode(DeviceMode.READY, timeout=15.0)


async def start(dev: DeviceClient, duration: float = 30.0, **kw: float) -> m.StartSegment:
    assert dev.hello is not None
    seg = build_segment(dev.hello, 1, duration, {"pitch": PITCH}, **kw)  # type: ignore[arg-type]
    await dev.start_segment(seg)
    await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=2.0)
    return seg


def mode_of(device: Running) -> DeviceMode:
    return device.service.mode


def valves_closed(service: DeviceService) -> bool:
    return not service.rig.state.valves.any() and service.rig.mode in (Mode.IDLE, Mode.FAULT)


def test_hello_reports_the_devices_own_limits_and_geometry(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        h = dev.hello
        assert h is not None
        lim = SafetyLimits()
        assert h.hardware == "sim" and m.Capability.SIMULATED in h.capabilities
        assert h.tick_hz == 7000 and h.pwm_hz == 250
        assert np.allclose(h.rom_high, lim.rom_high) and np.allclose(h.rom_low, lim.rom_low)
        assert np.allclose(h.stiffness_max, lim.stiffness_max)
        assert h.torque_limit == pytest.approx(lim.torque_limit)
        assert h.stroke == pytest.approx(device.service.rig.geometry.stroke)
        assert (h.watchdog_ms, h.telemetry_hz) == (WATCHDOG_MS_MAX, 100)

    drive(device, body)


def test_homing_then_a_segment_runs_and_ends_ready(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        events: list[m.Event] = []

        async def collect() -> None:
            async for e in dev.events():
                events.append(e)

        task = asyncio.create_task(collect())
        await home(dev)
        assert valves_closed(device.service)
        assert dev.latest is not None and m.TelemetryFlags.HOMED in dev.latest.flags
        await start(dev, duration=1.5)
        peak = 0.0
        async for t in dev.telemetry():
            peak = max(peak, abs(t.pose_cmd[4]))
            assert t.segment_time <= 1.5
            if t.mode == DeviceMode.READY:
                break
        await asyncio.sleep(0.05)
        task.cancel()
        kinds = [e.kind for e in events]
        assert kinds == [
            EventKind.MODE_CHANGE,
            EventKind.HOMED,
            EventKind.MODE_CHANGE,
            EventKind.SEGMENT_DONE,
        ]
        assert [e.event_id for e in events] == [1, 2, 3, 4]
        # The 6 deg sine ran, less what the relaxed foot's own stiffness (15 N m/rad against
        # the rendered 30) pushes it back by: about a third.
        assert math.radians(3.0) < peak < math.radians(6.5)
        assert valves_closed(device.service)

    drive(device, body)


def test_telemetry_arrives_at_the_configured_rate(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        await dev.configure(250, WATCHDOG_MS_MAX)
        times = []
        async for t in dev.telemetry():
            times.append(t.time)
            if len(times) == 251:
                break
        rate = 250 / (times[-1] - times[0])  # in device time: exact
        assert rate == pytest.approx(250.0, rel=0.01)
        assert dev.stats.frames_lost == 0

    drive(device, body)


def test_live_stiffness_changes_are_slewed_by_the_device(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await start(dev)
        await dev.set_impedance((0, 0, 0, 0, 100.0, 0), (0, 0, 0, 0, 1.0, 0))
        seen = []
        async for t in dev.telemetry():
            seen.append(t.stiffness[4])
            if t.stiffness[4] >= 100.0 - 1e-3:
                break
        # 30 -> 100 N m/rad at 200 N m/rad/s: 0.35 s, so several samples in between.
        assert len(seen) >= 25
        assert all(b >= a for a, b in itertools.pairwise(seen))

    drive(device, body)


def test_a_new_segment_renders_its_own_stiffness_from_the_start(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        await home(dev)
        await start(dev, duration=0.3)
        await dev.wait_for_mode(DeviceMode.READY, timeout=5.0)
        stiff = AxisPlan(Waveform.HOLD, stiffness=400.0, damping=1.0, compliant=True)
        await dev.start_segment(build_segment(dev.hello, 2, 5.0, {"pitch": stiff}))
        t = await dev.wait_for_mode(DeviceMode.ACTIVE)
        # Not slewed up from the previous segment's 30 N m/rad (that would take 1.9 s).
        assert t.stiffness[4] == pytest.approx(400.0)

    drive(device, body)


BAD_SEGMENTS: list[tuple[dict[str, object], NackCode, str]] = [
    ({"duration": 0.0}, NackCode.OUT_OF_RANGE, "duration"),
    ({"duration": math.nan}, NackCode.NOT_FINITE, "duration"),
    ({"force_limit": 1000.0}, NackCode.OUT_OF_RANGE, "force_limit"),
    ({"torque_limit": -1.0}, NackCode.OUT_OF_RANGE, "torque_limit"),
    ({"rom_low": (-0.03, -0.03, -0.025, -0.35, -0.9, -0.30)}, NackCode.OUT_OF_RANGE, "rom_low"),
    ({"rom_high": (0.03, 0.03, 0.025, 0.35, 0.05, 0.30)}, NackCode.OUT_OF_RANGE, "center"),
    ({"stiffness": (0, 0, 0, 0, 1e5, 0)}, NackCode.OUT_OF_RANGE, "stiffness"),
    ({"damping": (0, 0, 0, 0, -1.0, 0)}, NackCode.OUT_OF_RANGE, "damping"),
    ({"stiffness": (0, 0, 0, 0, math.inf, 0)}, NackCode.NOT_FINITE, "stiffness"),
    ({"frequency": (0, 0, 0, 0, 10.0, 0)}, NackCode.OUT_OF_RANGE, "frequency"),
    ({"segment_id": 0}, NackCode.OUT_OF_RANGE, "segment_id"),
    # Below what a foot at rest puts on the plate: these tripped a motionless segment.
    ({"force_limit": 20.0}, NackCode.OUT_OF_RANGE, "force_limit"),
    ({"torque_limit": 0.1}, NackCode.OUT_OF_RANGE, "torque_limit"),
    # A compliant translation (it tripped LEG_SPEED or FOLLOWING).
    (
        {
            "compliant": (False, False, True, False, True, False),
            "stiffness": (0, 0, 500.0, 0, 30.0, 0),
            "damping": (0, 0, 50.0, 0, 1.0, 0),
        },
        NackCode.OUT_OF_RANGE,
        "compliant",
    ),
    # The end that is wrong is named (it was blamed on rom_low).
    ({"rom_high": (0.03, 0.03, 0.025, -3.4e38, 0.40, 0.30)}, NackCode.OUT_OF_RANGE, "rom_high"),
    # Roll, pitch and yaw each just within 2 rad/s: leg 6 together tripped LEG_SPEED.
    (
        {
            "waveform": (0, 0, 0, 1, 1, 1),
            "amplitude": (0, 0, 0, -0.159, -0.159, 0.159),
            "frequency": (0, 0, 0, 2.0, 2.0, 2.0),
        },
        NackCode.OUT_OF_RANGE,
        "waveform",
    ),
]


@pytest.mark.parametrize(
    ("change", "code", "field"),
    BAD_SEGMENTS,
    ids=[c[2] + str(i) for i, c in enumerate(BAD_SEGMENTS)],
)
def test_a_bad_segment_is_refused_and_changes_nothing(
    device: Running, change: dict[str, object], code: NackCode, field: str
) -> None:
    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        await home(dev)
        good = build_segment(dev.hello, 1, 10.0, {"pitch": PITCH})
        bad = m.StartSegment(**{**good.__dict__, **change})
        before = device.service.rig.state.trajectory.copy()
        limits = device.service.rig.params.limits.copy()
        with pytest.raises(CommandRefused) as err:
            await dev.start_segment(bad)
        assert err.value.nack.code == code
        assert err.value.nack.field == field
        assert err.value.nack.mode == DeviceMode.READY
        t = await dev.wait_for_mode(DeviceMode.READY)
        assert t.segment_id == 0 and t.mode == DeviceMode.READY
        assert np.array_equal(device.service.rig.state.trajectory, before)
        assert np.array_equal(device.service.rig.params.limits, limits)
        assert valves_closed(device.service)
        # The same command, corrected, is accepted: the refusal left the device usable.
        await dev.start_segment(good)

    drive(device, body)


def test_commands_in_the_wrong_mode_are_refused(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        seg = build_segment(dev.hello, 1, 10.0, {"pitch": PITCH})
        cases = [
            (dev.start_segment(seg), NackCode.NOT_HOMED),
            (dev.resume(), NackCode.WRONG_MODE),
            (dev.set_impedance((0,) * 6, (0,) * 6), NackCode.WRONG_MODE),
            (dev.rearm(), NackCode.WRONG_MODE),
            (dev.configure(0, 200), NackCode.OUT_OF_RANGE),
            (dev.configure(100, 10), NackCode.OUT_OF_RANGE),
            (dev.configure(251, 200), NackCode.OUT_OF_RANGE),
        ]
        for call, code in cases:
            with pytest.raises(CommandRefused) as err:
                await call
            assert err.value.nack.code == code, err.value
            if code == NackCode.NOT_HOMED:
                assert err.value.nack.text == "home the platform first (ArmHome)"
        assert device.service.mode == DeviceMode.IDLE
        assert (device.service.telemetry_hz, device.service.watchdog_ms) == (100, WATCHDOG_MS_MAX)
        assert device.service.commands_refused == len(cases)

    drive(device, body)


def test_malformed_and_unknown_frames_get_a_nack_and_change_nothing(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        good = m.pack(build_segment(dev.hello, 1, 10.0, {"pitch": PITCH}))
        wave = bytearray(good)
        wave[8 + 4] = 3  # pitch's waveform byte: no such waveform
        bool_at = m.StartSegment.size() - 2 * 24 - 2 * 4 - 6  # the compliant bytes
        flag = bytearray(good)
        flag[bool_at + 4] = 7  # pitch's compliant byte: neither false (0) nor true (1)
        for frame, code, field, text in [
            (Frame(99, 40000, b""), NackCode.UNKNOWN_COMMAND, "", ""),
            (Frame(m.StartSegment.TYPE, 40001, b"\x01\x02"), NackCode.MALFORMED, "", ""),
            (
                Frame(m.StartSegment.TYPE, 40002, bytes(wave)),
                NackCode.MALFORMED,
                "waveform",
                "waveform of pitch: 3 is not a known Waveform",
            ),
            (
                Frame(m.StartSegment.TYPE, 40003, bytes(flag)),
                NackCode.MALFORMED,
                "compliant",
                "compliant of pitch: 7 is not 0 or 1",
            ),
        ]:
            loop = asyncio.get_running_loop()
            fut: asyncio.Future[m.Ack | m.Nack] = loop.create_future()
            dev._pending[frame.seq] = fut
            dev._writer.write(encode_frame(frame))
            reply = await asyncio.wait_for(fut, 1.0)
            assert isinstance(reply, m.Nack) and reply.code == code
            if field:
                assert (reply.field, reply.text) == (field, text)
        assert device.service.mode == DeviceMode.IDLE

    drive(device, body)


def test_refusals_print_their_numbers_on_the_side_of_their_bounds(device: Running) -> None:
    """A refusal never contradicts itself: "damping 0.4 is below 0.8, the least ... at
    stiffness 50" for K = 49.999996 (where 0.8 is the least), "leg 4 at 50.0..95.0 mm,
    beyond its usable 5..95 mm" for 95.000001 mm; a speed says its unit."""
    import re

    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        await home(dev)

        async def refused(axes: dict[str, AxisPlan]) -> str:
            assert dev.hello is not None
            with pytest.raises(CommandRefused) as err:
                await dev.start_segment(build_segment(dev.hello, 3, 2.0, axes))
            return err.value.nack.text

        below_50 = float(np.nextafter(np.float32(50.0), np.float32(0.0)))
        text = await refused({"pitch": AxisPlan(stiffness=below_50, damping=0.4, compliant=True)})
        found = re.fullmatch(
            r"pitch damping 0\.4 is below (\S+), the least that renders stably at "
            r"stiffness (\S+)",
            text,
        )
        assert found is not None, text
        band = 0 if float(found[2]) < 5.0 else (1 if float(found[2]) < 50.0 else 2)
        assert float(found[2]) < 50.0 and band == 1  # K as sent: below the 50 band edge
        assert float(found[1]) == pytest.approx(dev.hello.damping_min[3 * 4 + band])
        text = await refused(
            {
                "z": AxisPlan(Waveform.HOLD, 0.025),
                "pitch": AxisPlan(Waveform.HOLD, 0.2142036408185959),
            }
        )
        found = re.fullmatch(
            r"these targets together need leg (\d) at (\S+)\.\.(\S+) mm, beyond its usable "
            r"(\S+)\.\.(\S+) mm",
            text,
        )
        assert found is not None, text
        low, high, usable_low, usable_high = (float(found[i]) for i in range(2, 6))
        assert low < usable_low or high > usable_high, text
        fast = float(np.nextafter(np.float32(2.0), np.float32(3.0)))
        text = await refused({"roll": AxisPlan(Waveform.RAMP, 0.0, ramp_end=0.1, ramp_rate=fast)})
        assert re.fullmatch(r"roll waveform peaks at \S+ rad/s, above 2 rad/s", text), text
        fast = float(np.nextafter(np.float32(0.1), np.float32(1.0)))
        text = await refused({"x": AxisPlan(Waveform.RAMP, 0.0, ramp_end=0.01, ramp_rate=fast)})
        assert re.fullmatch(r"x waveform peaks at \S+ m/s, above \S+ m/s", text), text
        assert device.service.mode == DeviceMode.READY

    drive(device, body)


def test_estop_latches_until_rearmed_and_rearm_moves_nothing(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await start(dev)
        await asyncio.sleep(0.3)
        await dev.estop()
        t = await dev.wait_for_mode(DeviceMode.ESTOP, timeout=1.0)
        assert t.trip == Trip.ESTOP
        assert valves_closed(device.service)
        for call in (dev.arm_home(), dev.resume(), dev.set_impedance((0,) * 6, (0,) * 6)):
            with pytest.raises(CommandRefused) as err:
                await call
            assert err.value.nack.code == NackCode.LATCHED
        await asyncio.sleep(0.3)
        assert device.service.mode == DeviceMode.ESTOP and valves_closed(device.service)
        await dev.rearm()
        t = await dev.wait_for_mode(DeviceMode.IDLE, timeout=1.0)
        assert t.trip == Trip.NONE and m.TelemetryFlags.HOMED not in t.flags
        await asyncio.sleep(0.3)
        assert mode_of(device) == DeviceMode.IDLE and valves_closed(device.service)
        await home(dev)  # and it can be used again

    drive(device, body)


def test_watchdog_holds_within_one_pwm_period_and_never_resumes_by_itself(
    device: Running,
) -> None:
    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await dev.configure(100, 200)
        await start(dev)
        events = dev.events()
        for _ in range(3):
            passes = device.service.pacing.steps
            dev.heartbeats = False
            await asyncio.sleep(0.12)
            await dev.command(m.Heartbeat())
            last = time.perf_counter()
            lag = asyncio.create_task(loop_lag_ms())
            while (e := await asyncio.wait_for(anext(events), 2.0)).kind != EventKind.WATCHDOG:
                pass
            host_ms = (time.perf_counter() - last) * 1e3
            lag.cancel()
            own_ms = LAG_MS[0]
            # On a busy machine a pass can start late; the service measures by how much. The
            # lags that count are those of every pass since the heartbeats stopped, the one
            # that held included: the service records a pass's lag after the pass has sent
            # its event, so this waits for a pass more. Not a fixed number of the newest
            # passes: this test can hear of the hold hundreds of passes later (once in CI: a
            # 495 ms hold, its stall out of sight).
            late_ms = max(await passes_since(device, passes))
            assert e.mode_from == DeviceMode.ACTIVE and e.mode_to == DeviceMode.HOLD
            assert 200.0 <= e.value <= 204.0 + max(0.0, late_ms)
            # The host's own measure adds the trip over the pty and this test's own wait for a
            # core: 221 ms was seen with two whole test suites running on two cores, 358 ms
            # at a load of 10 on two cores. What this process stood still meanwhile (its
            # event loop's lateness) is its own, not the device's or the link's. Nor is the
            # kernel's: a pty hands what is written to its reader from a worker thread of
            # its own, which neither lateness above measures (once 291 ms, with the passes
            # 4.5 ms and this loop 3.5 ms late). The bound is for a device that counts its
            # silence from the wrong frame (a hold a whole watchdog later), not a latency.
            assert host_ms <= 204.0 + max(0.0, late_ms) + 150.0 + own_ms, (host_ms, own_ms)
            assert valves_closed(device.service)
            dev.heartbeats = True
            await asyncio.sleep(0.5)  # the link is back: still holding
            assert device.service.mode == DeviceMode.HOLD
            assert dev.latest is not None and dev.latest.mode == DeviceMode.HOLD
            await dev.resume()
            await dev.wait_for_mode(DeviceMode.ACTIVE)
        await events.aclose()

    drive(device, body)


def test_a_new_host_connection_holds_a_moving_platform_and_a_repeated_hello_does_not(
    device: Running,
) -> None:
    """A station that crashed and restarted faster than the watchdog must not find the
    platform still running a segment nobody on its connection commanded."""

    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await start(dev)
        assert dev.hello is not None
        await dev.handshake()  # the same client again: a new nonce, as a new process sends
        await dev.wait_for_mode(DeviceMode.HOLD, timeout=2.0)
        assert device.service.events[-1].kind == EventKind.WATCHDOG
        assert "new host connection" in device.service.events[-1].text
        await dev.resume()
        await dev.wait_for_mode(DeviceMode.ACTIVE)
        # A HELLO repeated with its nonce (unanswered, sent again) changes nothing.
        dev._write(m.Hello(host="test", nonce=dev_nonce(device)), 60000)
        await asyncio.sleep(0.3)
        assert device.service.mode == DeviceMode.ACTIVE

    drive(device, body)


def test_a_new_host_hears_the_hold_its_hello_caused_though_it_subscribes_after(
    device: Running,
) -> None:
    """The hold a new HELLO causes is sent, and replayed, while the handshake is under way,
    before the host can ask for events: a station that connected again after losing the
    link found the device holding and never heard why ("the station did not hear why")."""

    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await start(dev)
        await dev.close()  # the link lost; the segment runs on
        other = await DeviceClient.connect(device.link.name, command_timeout=0.3, retries=5)
        try:
            await other.wait_for_mode(DeviceMode.HOLD, timeout=5.0)
            newest = device.service.events[-1]
            assert "new host connection" in newest.text
            async with asyncio.timeout(5.0):  # everything the device sent has arrived
                while other.last_event is None or other.last_event.event_id < newest.event_id:
                    await asyncio.sleep(0.01)
            events = other.events()
            heard: list[m.Event] = []
            async with asyncio.timeout(5.0):
                while not heard or heard[-1].event_id < newest.event_id:
                    heard.append(await anext(events))
            assert heard[-1].kind == EventKind.WATCHDOG and heard[-1].mode_to == DeviceMode.HOLD
            ids = [e.event_id for e in heard]
            assert ids == list(range(ids[0], newest.event_id + 1))  # each once, in order
            later = other.events()  # a second subscription starts from its call
            await other.resume()
            assert (await asyncio.wait_for(anext(later), 5.0)).mode_to == DeviceMode.ACTIVE
        finally:
            await other.close()

    drive(device, body)


LAG_MS = [0.0]
"""The longest lateness (ms) :func:`loop_lag_ms` saw since it started."""


async def loop_lag_ms() -> None:
    """Measure, until cancelled, how late this event loop wakes from 5 ms sleeps."""
    LAG_MS[0] = 0.0
    while True:
        began = time.perf_counter()
        await asyncio.sleep(0.005)
        LAG_MS[0] = max(LAG_MS[0], (time.perf_counter() - began - 0.005) * 1e3)


async def passes_since(device: Running, steps: int) -> list[float]:
    """The pacing lags (ms) of the service's passes since it had made ``steps``, once it
    has finished the pass under way."""
    pacing = device.service.pacing
    now = pacing.steps
    while pacing.steps < now + 2:
        await asyncio.sleep(0.002)
    lags = list(pacing.lags_ms)  # one C call under the GIL: no pass appends meanwhile
    return lags[-(pacing.steps - steps + 2) :]


def dev_nonce(device: Running) -> int:
    nonce = device.service._nonce
    assert nonce is not None
    return nonce


def test_a_duplicated_command_runs_once(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        await home(dev)
        assert dev.hello is not None
        seg = build_segment(dev.hello, 5, 10.0, {"pitch": PITCH})
        wire = m.encode(seg, 777)
        loop = asyncio.get_running_loop()
        replies: list[m.Ack | m.Nack] = []
        for _ in range(3):
            fut: asyncio.Future[m.Ack | m.Nack] = loop.create_future()
            dev._pending[777] = fut
            dev._writer.write(wire)
            replies.append(await asyncio.wait_for(fut, 1.0))
        assert all(isinstance(r, m.Ack) for r in replies)
        await asyncio.sleep(0.1)
        starts = [e for e in device.service.events if e.mode_to == DeviceMode.ACTIVE]
        assert len(starts) == 1

    drive(device, body)


def test_a_tripped_limit_is_a_latched_fault_with_its_code(device: Running) -> None:
    hw = device.service.rig.hardware
    assert isinstance(hw, SimulatedHardware)

    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await start(dev, torque_limit=2.0)
        # The patient pushes 6 N m: over the segment's own 2 N m limit.
        hw.script_torque(4, SCRIPT_SINE, device.service.time, 6.0, 0.5)
        t = await dev.wait_for_mode(DeviceMode.FAULT, timeout=3.0)
        assert t.trip == Trip.WRENCH_LIMIT
        faults = [e for e in device.service.events if e.mode_to == DeviceMode.FAULT]
        assert faults[0].kind == EventKind.LIMIT and faults[0].code == Trip.WRENCH_LIMIT
        assert "torque about pitch" in faults[0].text, faults[0].text  # the channel over it
        assert valves_closed(device.service)
        # The device's own limits are back in force for whatever comes next.
        assert device.service.rig.params.limits[7, 1] == pytest.approx(60.0)

    drive(device, body)


def test_release_vents_and_needs_homing_again(device: Running) -> None:
    async def body(dev: DeviceClient) -> None:
        await home(dev)
        before = dev.latest
        assert before is not None
        await start(dev)
        with pytest.raises(CommandRefused) as err:
            await dev.release()  # not while ACTIVE
        assert err.value.nack.code == NackCode.WRONG_MODE
        await dev.hold()
        await dev.release()
        t = await dev.wait_for_mode(DeviceMode.IDLE)
        assert m.TelemetryFlags.VENTING in t.flags and m.TelemetryFlags.HOMED not in t.flags
        await asyncio.sleep(1.5)
        after = dev.latest
        assert after is not None
        assert max(after.pressures) < max(before.pressures) - 0.5e5
        assert not device.service.rig.state.valves[0::2].any()  # intakes shut
        await dev.arm_home()  # homing stops the vent
        t = await dev.wait_for_mode(DeviceMode.HOMING)
        assert device.service.rig.state.istate[ctl.I_VENT] == 0
        # From the half-vented chambers back to home, without a trip.
        t = await dev.wait_for_mode(DeviceMode.READY, DeviceMode.FAULT, timeout=15.0)
        assert t.mode == DeviceMode.READY and t.trip == Trip.NONE

    drive(device, body)


async def on_the_stops(dev: DeviceClient, timeout: float = 40.0) -> m.Telemetry:
    """The first sample with every leg down on its stop, inside the stroke-end trip band,
    and still (under 0.1 mm over 0.5 s)."""
    margin = SafetyLimits().stroke_margin
    last: list[m.Telemetry] = []

    async def watch() -> m.Telemetry:
        async for t in dev.telemetry():
            last[:] = [x for x in last if x.time > t.time - 0.5] + [t]
            span = np.ptp([x.legs for x in last], axis=0).max()
            if last[-1].time - last[0].time >= 0.45 and max(t.legs) < margin and span < 1e-4:
                return t
        raise AssertionError("telemetry ended")

    return await asyncio.wait_for(watch(), timeout)


def test_a_platform_resting_on_its_stops_homes_over_the_wire() -> None:
    """Where the start-up identification and every power-off leave a unit, and where a
    release on an empty plate lets it sink: every leg on its stop, inside the 2 mm trip
    band. ArmHome is accepted there and homes without a trip; after a release onto the
    stops, it homes again. Before, ArmHome was refused there (every leg outside 2..98 mm)
    and such a unit could never be homed. (A relaxed foot holds a vented platform up at
    34-38 mm, 15 mm below home: test_identify homes it from there.)"""
    hw = SimulatedHardware(PlantConfig(patient="absent"), seed=3)
    lower_and_vent(hw)
    config = ServiceConfig(telemetry_hz=50, watchdog_ms=WATCHDOG_MS_MAX)

    async def body(dev: DeviceClient) -> None:
        start = await on_the_stops(dev, timeout=10.0)
        assert start.mode == DeviceMode.IDLE
        await dev.arm_home()
        t = await dev.wait_for_mode(DeviceMode.READY, DeviceMode.FAULT, timeout=30.0)
        assert t.mode == DeviceMode.READY and t.trip == Trip.NONE
        await dev.release()  # nothing on the plate: it sinks onto its stops
        await on_the_stops(dev)
        await dev.arm_home()
        t = await dev.wait_for_mode(DeviceMode.READY, DeviceMode.FAULT, timeout=30.0)
        assert t.mode == DeviceMode.READY and t.trip == Trip.NONE

    async def main(name: str) -> None:
        dev = await DeviceClient.connect(name, command_timeout=0.3, retries=5)
        try:
            await body(dev)
        finally:
            await dev.close()

    with service_in_thread(hw, config) as link:
        asyncio.run(main(link.name))


def test_a_stall_ended_by_another_tasks_frame_still_counts_the_devices_silence(
    device: Running,
) -> None:
    """The event loop blocked 400 ms, and the first thing to run after it sends a command
    (as a station's other tasks do on waking). The stall's measure of the device's silence
    was the time since the last frame written, taken when the heartbeat task woke, after
    that command: next to nothing, and a watchdog hold the stall caused was said to have an
    unknown cause. It is the gap the command ended. The blocked stall is taken as the
    heartbeat task counts it: a later, shorter one (a test machine's load) would replace it
    as the last."""
    stalls: list[Stall] = []

    async def body(dev: DeviceClient) -> None:
        await asyncio.sleep(0.2)  # heartbeats running
        time.sleep(0.4)  # the host's event loop blocked: no frame can leave
        await dev.command(m.Heartbeat())  # written before the heartbeat task wakes
        for _ in range(100):
            await asyncio.sleep(0.01)
            stall = dev.stats.last_stall
            if stall is not None and stall.ms >= 340.0:
                stalls.append(stall)
                return

    drive(device, body)
    assert stalls, "the 400 ms block was not counted as a stall"
    assert stalls[0].quiet_ms >= 340.0, stalls[0]


def test_a_host_that_stands_still_counts_the_stall_and_says_so(
    device: Running, caplog: pytest.LogCaptureFixture
) -> None:
    stats = ClientStats()

    async def body(dev: DeviceClient) -> None:
        nonlocal stats
        await asyncio.sleep(0.2)  # heartbeats running
        time.sleep(0.4)  # the host's event loop blocked: no heartbeat can leave
        await asyncio.sleep(0.2)  # the heartbeat task wakes, late
        stats = dev.stats

    with caplog.at_level("WARNING", logger="ankle.host"):
        drive(device, body)
    assert stats.stalls >= 1 and stats.last_stall is not None
    # Blocked 400 ms in the sleep (bound 50 ms) or in the ACK's wait (bound 50 ms).
    assert 340.0 <= stats.stall_ms_max <= 1000.0, stats
    assert any("this computer stood still for" in r.getMessage() for r in caplog.records)


def test_at_the_least_watchdog_every_hold_a_host_stall_causes_is_counted(
    device: Running,
) -> None:
    """At the least watchdog (100 ms, heartbeats 25 ms apart) a host stall of 75 ms already
    holds the platform, but a stall was counted only past 100 ms: the hold went unexplained.
    The client counts a stall past half its watchdog."""

    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        await home(dev)
        await dev.configure(100, dev.hello.watchdog_ms_min)
        await start(dev)
        await asyncio.sleep(0.3)  # heartbeats running at the short watchdog
        stalls = dev.stats.stalls
        watchdogs = [e.event_id for e in device.service.events if e.kind == EventKind.WATCHDOG]
        began = time.perf_counter()
        time.sleep(0.09)  # the host's event loop blocked: no heartbeat can leave
        blocked_ms = (time.perf_counter() - began) * 1e3
        await asyncio.sleep(0.3)  # the heartbeat task wakes, late
        held = [
            e.event_id
            for e in device.service.events
            if e.kind == EventKind.WATCHDOG and e.event_id not in watchdogs
        ]
        # The heartbeat's sleep (25 ms) began before the block: it ended at least the block
        # less one period late, over half the watchdog (and under the fixed 100 ms).
        assert dev.stats.stalls > stalls, (blocked_ms, dev.stats, held)
        assert dev.stats.stall_ms_max >= blocked_ms - 25.0 - 1.0, (blocked_ms, dev.stats)
        await dev.configure(100, WATCHDOG_MS_MAX)
        if held:  # the device held on the host's stall: it is resumable, and was counted
            await dev.resume()

    drive(device, body)


def test_a_subscription_gets_what_the_device_sent_before_its_first_read(
    device: Running,
) -> None:
    """Events and telemetry are delivered from the moment they are asked for: a caller that
    asks for events, stops the heartbeats and only then waits must hear of the hold, however
    late its first read (a benchmark on a busy machine read after the hold, and waited for
    an event it had missed)."""

    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await dev.configure(100, 200)
        await start(dev)
        events = dev.events()
        samples = dev.telemetry()
        dev.heartbeats = False
        async with asyncio.timeout(5.0):
            while device.service.mode != DeviceMode.HOLD:  # read nothing meanwhile
                await asyncio.sleep(0.01)
            await asyncio.sleep(0.1)  # the event is on its way to this client, or in
            while (e := await anext(events)).kind != EventKind.WATCHDOG:
                pass
            first = await anext(samples)
        assert e.mode_from == DeviceMode.ACTIVE and e.mode_to == DeviceMode.HOLD
        assert first.mode == DeviceMode.ACTIVE  # sent before the hold, read after it
        await events.aclose()
        await samples.aclose()
        assert not dev._event_subs and not dev._telemetry_subs  # closed: delivered no more
        dev.heartbeats = True

    drive(device, body)


@pytest.mark.parametrize("passes", [0, 1, 2, 3])
def test_a_task_that_commands_in_a_loop_stops_when_cancelled_as_an_ack_arrives(
    device: Running, passes: int
) -> None:
    """A cancel that lands in the same turn of the event loop as a command's ACK stops the
    task: on Python 3.11 ``asyncio.wait_for`` dropped it, and a benchmark waiting for its
    K-changing task to end waited until its test's timeout killed it. The race is made
    exact here: the cancel is scheduled ``passes`` turns of the loop after the ACK lands."""

    async def body(dev: DeviceClient) -> None:
        dev.heartbeats = False  # only the task's commands (the watchdog is 2 s here)
        loop = asyncio.get_running_loop()

        async def commands() -> None:
            while True:
                await dev.command(m.Heartbeat())

        for _ in range(20):
            task = asyncio.create_task(commands())
            async with asyncio.timeout(5.0):
                while not dev._pending:
                    await asyncio.sleep(0)
            ack = next(iter(dev._pending.values()))

            def cancel_later(_: object, n: int = passes, t: asyncio.Task[None] = task) -> None:
                if n == 0:
                    t.cancel()
                else:
                    loop.call_soon(cancel_later, None, n - 1, t)

            ack.add_done_callback(cancel_later)
            done, _ = await asyncio.wait({task}, timeout=5.0)
            assert task in done, "the cancelled task went on sending commands"
            assert task.cancelled()
        dev.heartbeats = True

    drive(device, body)


def test_a_host_that_connects_after_more_events_than_the_device_keeps_hears_the_new_ones(
    device: Running,
) -> None:
    """The device keeps its latest EVENTS_KEPT events for replay. A host that connects
    later (a station restarted after a long session) has heard none: the ones it can no
    longer get are counted lost, and it goes on from the oldest kept, rather than asking
    for the missing ones again and again while holding back every event after them."""

    async def body(dev: DeviceClient) -> None:
        await home(dev)
        await start(dev, duration=120.0)
        for _ in range(EVENTS_KEPT // 2 + 4):
            await dev.hold()
            await dev.resume()
        assert device.service.events[0].event_id > 1  # the oldest are gone
        await dev.close()
        other = await DeviceClient.connect(device.link.name, command_timeout=0.3, retries=5)
        try:
            events = other.events()
            await other.wait_for_mode(DeviceMode.HOLD, timeout=5.0)  # a new host: held
            await other.resume()
            kept = [e.event_id for e in device.service.events]  # the resume's event included
            heard: list[m.Event] = []
            async with asyncio.timeout(5.0):
                while not heard or heard[-1].event_id < kept[-1]:
                    heard.append(await anext(events))
            ids = [e.event_id for e in heard]
            assert heard[-1].mode_to == DeviceMode.ACTIVE  # the resume, heard
            # Every event the device kept when this host asked, each once and in order, and
            # the ones before them counted lost.
            assert ids == list(range(ids[0], kept[-1] + 1))
            assert 1 < ids[0] <= kept[0]
            assert other.stats.events_lost == ids[0] - 1
        finally:
            await other.close()

    drive(device, body)


def test_the_client_beats_several_times_in_any_watchdog_the_device_accepts(
    device: Running,
) -> None:
    """The least watchdog the device publishes, configured or set at its start, leaves the
    client room for several heartbeats (it used to equal the client's fixed 50 ms, and a
    segment held with no host stall)."""

    async def body(dev: DeviceClient) -> None:
        assert dev.hello is not None
        least = dev.hello.watchdog_ms_min
        assert dev.watchdog_ms == dev.hello.watchdog_ms  # from HELLO
        await dev.configure(100, least)
        assert dev.heartbeat_interval * HEARTBEATS_PER_WATCHDOG <= least / 1e3
        # A stall that holds the platform (a heartbeat period and the stall past the
        # watchdog) is one the client counts.
        assert dev.heartbeat_interval + dev.stall_threshold < least / 1e3
        assert dev.stall_threshold <= STALL_S
        await dev.configure(100, 400)
        assert dev.heartbeat_interval == dev.heartbeat_period  # 50 ms: four fit in 400

    drive(device, body)
    with service_in_thread(
        SimulatedHardware(PlantConfig(), seed=3), ServiceConfig(100, WATCHDOG_MS_MIN)
    ) as link:

        async def started() -> None:  # ankle device --watchdog-ms at its least
            dev = await DeviceClient.connect(link.name, command_timeout=0.3, retries=5)
            try:
                assert dev.hello is not None and dev.hello.watchdog_ms == WATCHDOG_MS_MIN
                assert dev.heartbeat_interval * HEARTBEATS_PER_WATCHDOG <= WATCHDOG_MS_MIN / 1e3
            finally:
                await dev.close()

        asyncio.run(started())


def test_a_loop_that_fell_over_a_second_behind_counts_the_time_it_gave_up() -> None:
    """A process stopped 2.5 s (here: a clock that jumps) gives the time up rather than
    racing to catch it up, and says so in telemetry; it used to hide in one overrun."""
    calls = 0

    def clock() -> float:
        nonlocal calls
        calls += 1
        return time.perf_counter() + (2.5 if calls > 300 else 0.0)

    service = DeviceService(
        Rig(SimulatedHardware(PlantConfig(), seed=3)), PtyLink(), ServiceConfig(), clock=clock
    )
    try:
        assert service.telemetry().clock_resets == 0
        service.run(0.3)
        assert calls > 300  # the jump came
        assert service.pacing.clock_resets == 1
        assert service.pacing.overruns >= 1
        assert service.telemetry().clock_resets == 1
        # The time lost was given up once: the passes after it kept pace.
        assert service.pacing.lags_ms[-1] < 1000.0
    finally:
        service.shutdown()
