"""Every command is checked once, against exactly the limits the device publishes.

The checks themselves (pure), then the real service on a pty: values at, just inside and just
outside every published limit (float32 neighbours of the exact bound) are each ACKed or
NACKed as the one check module says, the service never dies, and accepted segments at the
extremes of what is allowed run without tripping the device by their own targets.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import threading
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

from device import commands
from device.client import CommandRefused, DeviceClient, build_segment
from device.commands import CommandError, Context
from device.geometry import DEFAULT_GEOMETRY
from device.hardware import SimulatedHardware
from device.limits import SafetyLimits
from device.plant.params import PlantConfig
from device.protocol import messages as m
from device.protocol.messages import DeviceMode, EventKind, NackCode
from device.rig import Rig
from device.service import WATCHDOG_MS_MAX, DeviceService, ServiceConfig
from device.transport import PtyLink
from device.trips import Trip
from device.waveforms import Waveform

LIMITS = SafetyLimits().published()


def up(x: float) -> float:
    """The next float32 above ``x`` (what a host can send just past a published bound)."""
    return float(np.nextafter(np.float32(x), np.float32(np.inf)))


def down(x: float) -> float:
    return float(np.nextafter(np.float32(x), np.float32(-np.inf)))


def hello() -> m.DeviceHello:
    lim = LIMITS
    return m.DeviceHello(
        rom_low=lim.rom_low,
        rom_high=lim.rom_high,
        force_limit=lim.force_limit,
        torque_limit=lim.torque_limit,
    )


def segment(**axes_and_fields: object) -> m.StartSegment:
    base = build_segment(hello(), 1, 5.0, {})
    return dataclasses.replace(base, **axes_and_fields)  # type: ignore[arg-type]


def with_axis(field: str, k: int, value: object, seg: m.StartSegment) -> m.StartSegment:
    values = list(getattr(seg, field))
    values[k] = value
    changed: dict[str, object] = {field: tuple(values)}
    return dataclasses.replace(seg, **changed)  # type: ignore[arg-type]


def ready() -> Context:
    return Context(LIMITS, DEFAULT_GEOMETRY, DeviceMode.READY)


def verdict(command: m.Message, ctx: Context) -> NackCode | None:
    try:
        commands.check(command, ctx)
    except CommandError as exc:
        return exc.code
    return None


def test_the_published_limits_are_float32_and_the_rig_runs_on_them() -> None:
    rig = Rig(SimulatedHardware(PlantConfig(patient="absent")))
    assert rig.limits == LIMITS
    for value in (*LIMITS.rom_high, *LIMITS.stiffness_max, LIMITS.torque_limit):
        assert float(np.float32(value)) == value
    assert np.array_equal(rig.params.limits, LIMITS.as_array())


@pytest.mark.parametrize("k", range(6))
def test_a_hold_on_each_range_bound_is_accepted_and_just_past_it_refused(k: int) -> None:
    for bound, past in (
        (LIMITS.rom_high[k], up(LIMITS.rom_high[k])),
        (LIMITS.rom_low[k], down(LIMITS.rom_low[k])),
    ):
        seg = with_axis("center", k, bound, segment())
        assert verdict(seg, ready()) is None, (k, bound)
        outside = with_axis("center", k, past, segment())
        assert verdict(outside, ready()) == NackCode.OUT_OF_RANGE
        wider = with_axis("rom_high" if past > bound else "rom_low", k, past, segment())
        assert verdict(wider, ready()) == NackCode.OUT_OF_RANGE


@pytest.mark.parametrize("k", range(3, 6))
def test_stiffness_damping_and_speed_bounds(k: int) -> None:
    compliant = with_axis("compliant", k, True, segment())
    # Damped enough for any stiffness: the envelope's largest least damping.
    compliant = with_axis("damping", k, max(LIMITS.damping_min), compliant)
    at_k = with_axis("stiffness", k, LIMITS.stiffness_max[k], compliant)
    assert verdict(at_k, ready()) is None
    assert verdict(with_axis("stiffness", k, up(LIMITS.stiffness_max[k]), compliant), ready())
    at_b = with_axis("damping", k, LIMITS.damping_max[k], compliant)
    assert verdict(at_b, ready()) is None
    assert verdict(with_axis("damping", k, up(LIMITS.damping_max[k]), compliant), ready())
    # A ramp at exactly the axis speed limit is accepted, just above it refused.
    ramp = with_axis("waveform", k, Waveform.RAMP, segment())
    ramp = with_axis("ramp_end", k, 0.1, ramp)
    assert verdict(with_axis("ramp_rate", k, LIMITS.axis_speed_max[k], ramp), ready()) is None
    too_fast = with_axis("ramp_rate", k, up(LIMITS.axis_speed_max[k]), ramp)
    with pytest.raises(CommandError) as err:
        commands.check(too_fast, ready())
    assert err.value.field == "ramp_rate" and "above" in str(err.value)


def test_targets_no_leg_can_reach_together_are_refused_with_the_leg_named() -> None:
    seg = with_axis("center", 3, LIMITS.rom_high[3], segment())
    seg = with_axis("center", 4, LIMITS.rom_high[4], seg)
    with pytest.raises(CommandError) as err:
        commands.check(seg, ready())
    assert "leg" in str(err.value) and "mm" in str(err.value)
    # Each alone is fine: it is the combination the stroke cannot give.
    assert verdict(with_axis("center", 3, 0.0, seg), ready()) is None
    assert verdict(with_axis("center", 4, 0.0, seg), ready()) is None


def rotations(hz: float, signs: tuple[int, int, int], share: float) -> m.StartSegment:
    """Roll, pitch and yaw sines at ``hz``, each at ``share`` of its axis speed limit."""
    seg = segment()
    for k, sign in zip((3, 4, 5), signs, strict=True):
        amplitude = share * LIMITS.axis_speed_max[k] / (2 * math.pi * hz)
        seg = with_axis("waveform", k, Waveform.SINE, seg)
        seg = with_axis("amplitude", k, float(np.float32(sign * amplitude)), seg)
        seg = with_axis("frequency", k, hz, seg)
    return commands.as_received(seg)


def at_the_leg_speed_bound(hz: float, signs: tuple[int, int, int]) -> m.StartSegment:
    """:func:`rotations` at the largest share the leg speed check accepts."""
    bound = commands.LEG_SPEED_SHARE * LIMITS.leg_speed_limit
    low, high = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (low + high)
        targets = commands.segment_targets(rotations(hz, signs, mid))
        if commands.planned_leg_speeds(targets, DEFAULT_GEOMETRY).max() <= bound:
            low = mid
        else:
            high = mid
    return rotations(hz, signs, low)


def test_axes_each_within_their_speed_that_together_drive_a_leg_too_fast_are_refused() -> None:
    """Roll, pitch and yaw sines at 2 Hz, each at 0.999 of its 2 rad/s, were accepted and
    tripped LEG_SPEED on leg 6: each axis was checked alone. The legs' speed they plan
    together is checked, and the refusal names the leg, its planned speed and the bound."""
    import re

    with pytest.raises(CommandError) as err:
        commands.check(rotations(2.0, (-1, -1, 1), 0.999), ready())
    found = re.fullmatch(
        r"these targets together move leg (\d) at up to (\S+) m/s, above the (\S+) m/s "
        r"they may plan",
        str(err.value),
    )
    assert found is not None, str(err.value)
    assert err.value.field == "waveform" and err.value.code == NackCode.OUT_OF_RANGE
    assert (
        float(found[2])
        > float(found[3])
        == pytest.approx(commands.LEG_SPEED_SHARE * LIMITS.leg_speed_limit, rel=1e-3)
    )
    assert len(str(err.value).encode()) <= 96  # the NACK's text field
    # Just inside the bound is accepted, just outside refused.
    edge = at_the_leg_speed_bound(2.0, (-1, -1, 1))
    assert verdict(edge, ready()) is None
    scaled = [float(np.float32(1.01 * a)) for a in edge.amplitude]
    assert verdict(dataclasses.replace(edge, amplitude=tuple(scaled)), ready()) is not None
    # Any one axis at its speed limit (sines from the slowest that fits the range to the
    # fastest, and ramps end to end) still plans within the bound.
    for k in range(6):
        for hz in (0.8, 1.0, 2.0, 5.0, 10.0, 20.0):
            amplitude = min(LIMITS.axis_speed_max[k] / (2 * math.pi * hz), LIMITS.rom_high[k])
            one = with_axis("waveform", k, Waveform.SINE, segment())
            one = with_axis("amplitude", k, down(amplitude), one)
            one = with_axis("frequency", k, hz, one)
            assert verdict(one, ready()) is None, (k, hz)
        ramp = with_axis("waveform", k, Waveform.RAMP, segment())
        ramp = with_axis("center", k, LIMITS.rom_low[k], ramp)
        ramp = with_axis("ramp_end", k, LIMITS.rom_high[k], ramp)
        ramp = with_axis("ramp_rate", k, LIMITS.axis_speed_max[k], ramp)
        assert verdict(ramp, ready()) is None, k


def test_only_the_ankles_rotations_may_be_compliant() -> None:
    """A compliant translation tripped (z at 500 N/m, 50 N s/m: LEG_SPEED or FOLLOWING; at
    K 0, B 1: FOLLOWING within 0.3 s); no exercise renders one and no stable damping is
    known. Refused by the segment, a live change and the rig alike, naming the axis."""
    for k in range(3):
        seg = with_axis("compliant", k, True, segment())
        seg = with_axis("stiffness", k, 500.0, seg)
        seg = with_axis("damping", k, 50.0, seg)
        with pytest.raises(CommandError, match="renders impedance about the ankle's rotations"):
            commands.check(seg, ready())
    rig = Rig(SimulatedHardware(PlantConfig(patient="absent")))
    with pytest.raises(CommandError) as err:
        rig.set_impedance(
            (0, 0, 500.0, 0, 0, 0), (0, 0, 50.0, 0, 0, 0), [False, False, True] + [False] * 3
        )
    assert err.value.field == "compliant" and err.value.axis == 2
    assert not rig.state.compliant.any()
    # Unnamed, the compliant axes are the rotations.
    rig.set_impedance((0, 0, 0, 20.0, 20.0, 20.0), (0, 0, 0, 2.0, 2.0, 2.0))
    assert list(rig.state.compliant) == [0, 0, 0, 1, 1, 1]


def test_a_force_or_torque_limit_a_foot_at_rest_exceeds_is_refused() -> None:
    """Force limits of 1, 5 and 20 N and torque limits of 0.1 N m were accepted and tripped
    WRENCH_LIMIT with nothing moving: a relaxed foot at rest puts more on the plate."""
    for name, least in (
        ("force_limit", commands.FORCE_LIMIT_MIN),
        ("torque_limit", commands.TORQUE_LIMIT_MIN),
    ):
        low: dict[str, object] = {name: down(least)}
        with pytest.raises(CommandError) as err:
            commands.check(dataclasses.replace(segment(), **low), ready())  # type: ignore[arg-type]
        assert err.value.field == name and f"is below {least:g} " in str(err.value)
        at: dict[str, object] = {name: least}
        assert verdict(dataclasses.replace(segment(), **at), ready()) is None  # type: ignore[arg-type]


def test_modes_are_part_of_the_check() -> None:
    idle = Context(LIMITS, DEFAULT_GEOMETRY, DeviceMode.IDLE)
    assert verdict(segment(), idle) == NackCode.NOT_HOMED
    latched = Context(LIMITS, DEFAULT_GEOMETRY, DeviceMode.FAULT, Trip.SOFTWARE)
    assert verdict(m.ArmHome(), latched) == NackCode.LATCHED
    assert verdict(m.Rearm(), latched) is None
    assert verdict(m.SetImpedance(), ready()) == NackCode.WRONG_MODE
    assert verdict(dataclasses.replace(segment(), duration=math.nan), ready()) == (
        NackCode.NOT_FINITE
    )


def test_homing_starts_from_the_end_stops_not_from_a_reading_no_piston_gives() -> None:
    """A platform on its end stops (after a release, the start-up identification or a
    power-off) reads its legs inside the stroke-end trip band: homing starts from there.
    Only a reading no piston can give (not finite, or beyond the sensor's reach past either
    end of the stroke) is refused, naming the leg."""
    stroke = DEFAULT_GEOMETRY.stroke

    def idle(*legs: float) -> Context:
        return Context(LIMITS, DEFAULT_GEOMETRY, DeviceMode.IDLE, legs=legs)

    on_stops = (-0.01e-3, -0.01e-3, -0.02e-3, 0.01e-3, 0.01e-3, 0.0)  # as measured
    assert verdict(m.ArmHome(), idle(*on_stops)) is None
    assert verdict(m.ArmHome(), idle(*([stroke + 1.9e-3] * 6))) is None  # on the top stops
    assert verdict(m.ArmHome(), idle(0.0, 0.02, 0.05, 0.07, 0.09, stroke)) is None
    for leg, reading in ((2, 0.15), (5, -2.5e-3), (0, math.nan), (3, math.inf)):
        legs = [0.05] * 6
        legs[leg] = reading
        with pytest.raises(CommandError) as err:
            commands.check(m.ArmHome(), idle(*legs))
        assert err.value.code == NackCode.OUT_OF_RANGE and err.value.field == "legs"
        assert f"leg {leg + 1} at " in str(err.value) and "-2..102 mm" in str(err.value)


@pytest.mark.parametrize("k", range(3, 6))
def test_a_refusal_never_prints_its_value_on_the_bound(k: int) -> None:
    """A value just past a bound is printed with the digits that tell it from the bound:
    not "pitch stiffness 500 outside 0..500" for 500.0001."""
    import re

    active = Context(LIMITS, DEFAULT_GEOMETRY, DeviceMode.ACTIVE, compliant=commands.COMPLIANT_AXES)
    axis = ("roll", "pitch", "yaw")[k - 3]
    for field, bound in (
        ("stiffness", LIMITS.stiffness_max[k]),
        ("damping", LIMITS.damping_max[k]),
    ):
        for value in (up(bound), float(np.float32(bound + 1e-4))):
            change = {"stiffness": [0.0] * 6, "damping": [2.0] * 6}
            change[field][k] = value
            command = m.SetImpedance(tuple(change["stiffness"]), tuple(change["damping"]))
            with pytest.raises(CommandError) as err:
                commands.check(commands.as_received(command), active)
            found = re.fullmatch(rf"{axis} {field} (\S+) outside 0\.\.(\S+)", str(err.value))
            assert found is not None, str(err.value)
            assert float(found[1]) > float(found[2]) == pytest.approx(bound), str(err.value)
    too_fast = with_axis("waveform", k, Waveform.RAMP, segment())
    too_fast = with_axis("ramp_end", k, 0.1, too_fast)
    too_fast = with_axis("ramp_rate", k, up(LIMITS.axis_speed_max[k]), too_fast)
    with pytest.raises(CommandError) as err:
        commands.check(too_fast, ready())
    found = re.search(r"peaks at (\S+) rad/s, above (\S+) rad/s", str(err.value))
    assert found is not None and float(found[1]) > float(found[2]), str(err.value)
    wide = with_axis("rom_high", k, up(LIMITS.rom_high[k]), segment())
    with pytest.raises(CommandError) as err:
        commands.check(wide, ready())
    found = re.search(
        r"range \S+\.\.(\S+) is not within the device's \S+\.\.(\S+)$", f"{err.value}"
    )
    assert found is not None and float(found[1]) > float(found[2]), str(err.value)
    stiffness = (0.0, 0.0, 0.0, 0.0, 500.0001, 0.0)
    pitch = commands.as_received(m.SetImpedance(stiffness=stiffness, damping=(2.0,) * 6))
    with pytest.raises(CommandError, match=r"^pitch stiffness 500\.0001 outside 0\.\.500$"):
        commands.check(pitch, active)


# -- through the real wire -----------------------------------------------------------------


@pytest.fixture(scope="module")
def service() -> Iterator[DeviceService]:
    link = PtyLink()
    svc = DeviceService(
        Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=11)),
        link,
        ServiceConfig(watchdog_ms=WATCHDOG_MS_MAX),  # host stalls are not what these check
    )
    thread = threading.Thread(target=svc.run, daemon=True)
    thread.start()
    yield svc
    svc.stop()
    thread.join(5.0)
    assert not thread.is_alive()
    svc.shutdown()


def _values(bound: float, sign: float) -> st.SearchStrategy[float]:
    """At, just inside and just outside a bound, and a few float32 steps either side."""
    b = np.float32(bound)
    near = [float(np.nextafter(b, np.float32(sign * np.inf)) if i else b) for i in range(2)]
    near.append(float(np.nextafter(b, np.float32(-sign * np.inf))))
    span = 0.05 * abs(bound) + 1e-3
    lo = float(np.float32(float(bound) - span))
    hi = float(np.float32(float(bound) + span))
    return st.sampled_from(near) | st.floats(min_value=lo, max_value=hi, width=32)


def last_watchdog(service: DeviceService) -> int:
    """The id of the newest WATCHDOG event the service has sent (0 if none)."""
    ids = [e.event_id for e in list(service.events) if e.kind == EventKind.WATCHDOG]
    return max(ids, default=0)


BOUNDARY = st.one_of(
    st.tuples(st.just("center"), st.integers(0, 5), st.booleans()).flatmap(
        lambda t: st.tuples(
            st.just(t[0]),
            st.just(t[1]),
            _values(LIMITS.rom_high[t[1]] if t[2] else LIMITS.rom_low[t[1]], 1 if t[2] else -1),
        )
    ),
    st.integers(3, 5).flatmap(
        lambda k: st.tuples(st.just("stiffness"), st.just(k), _values(LIMITS.stiffness_max[k], 1))
    ),
    st.integers(3, 5).flatmap(
        lambda k: st.tuples(st.just("damping"), st.just(k), _values(LIMITS.damping_max[k], 1))
    ),
    st.tuples(st.just("torque_limit"), st.just(-1), _values(LIMITS.torque_limit, 1)),
    st.tuples(st.just("force_limit"), st.just(-1), _values(LIMITS.force_limit, 1)),
    st.tuples(st.just("torque_limit"), st.just(-1), _values(commands.TORQUE_LIMIT_MIN, -1)),
    st.tuples(st.just("force_limit"), st.just(-1), _values(commands.FORCE_LIMIT_MIN, -1)),
)


def test_boundary_commands_through_the_wire_match_the_check_and_never_kill_the_service(
    service: DeviceService,
) -> None:
    """StartSegment, SetImpedance and Configure at and around every published bound."""

    async def main() -> None:
        dev = await DeviceClient.connect(service.link.name)
        try:
            assert dev.hello is not None
            assert dev.hello.stiffness_max == LIMITS.stiffness_max  # what the host is told
            # The longest watchdog the device allows: this test is about the checks, and a
            # host stalled past 200 ms on a busy machine would hold the segment (ACTIVE ->
            # HOLD) between reading the mode and sending, a verdict the mode read did not see.
            await dev.configure(100, dev.hello.watchdog_ms_max)
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            sent = {"ack": 0, "nack": 0, "watchdog": 0}

            @settings(
                max_examples=60,
                suppress_health_check=list(HealthCheck),
                derandomize=True,
            )
            @given(change=BOUNDARY)
            def one(change: tuple[str, int, float]) -> None:
                name, k, value = change
                seg = segment(segment_id=7, duration=0.05)
                if k >= 0:
                    seg = with_axis(name, k, value, seg)
                    if name in ("stiffness", "damping"):
                        seg = with_axis("compliant", k, True, seg)
                        seg = with_axis(
                            "damping" if name == "stiffness" else "stiffness", k, 1.0, seg
                        )
                else:
                    scalar: dict[str, object] = {name: value}
                    seg = dataclasses.replace(seg, **scalar)  # type: ignore[arg-type]
                watchdogs = last_watchdog(service)
                ctx = dataclasses.replace(ready(), mode=service.mode)
                expected = verdict(seg, ctx)

                async def send() -> NackCode | None:
                    try:
                        await dev.start_segment(seg)
                    except CommandRefused as exc:
                        return exc.nack.code
                    return None

                got = asyncio.run_coroutine_threadsafe(send(), loop).result(5.0)
                if last_watchdog(service) > watchdogs:
                    # The host stalled past even the longest watchdog: the device held, as it
                    # must. This example's mode is unknown; carry on from the hold.
                    sent["watchdog"] += 1
                    if service.mode == DeviceMode.HOLD:
                        asyncio.run_coroutine_threadsafe(dev.resume(), loop).result(5.0)
                    reject()
                assert got == expected, (change, got, expected)
                sent["nack" if got else "ack"] += 1

            loop = asyncio.get_running_loop()
            await asyncio.to_thread(one)
            assert sent["ack"] > 5 and sent["nack"] > 5 and sent["watchdog"] < 5, sent
            # Configure and SetImpedance at their bounds.
            await dev.configure(dev.hello.telemetry_hz_max, dev.hello.watchdog_ms_max)
            with pytest.raises(CommandRefused):
                await dev.configure(dev.hello.telemetry_hz_max + 1, 200)
            await dev.configure(100, dev.hello.watchdog_ms_min)
            with pytest.raises(CommandRefused):
                await dev.configure(100, dev.hello.watchdog_ms_min - 1)
            await dev.configure(100, 200)
            assert service.software_faults == 0
            assert service.rig.trip == Trip.NONE
        finally:
            await dev.close()

    asyncio.run(main())


EXTREMES: dict[str, list[tuple[str, int, object]]] = {
    "pitch held at its published high end": [("center", 4, LIMITS.rom_high[4])],
    "pitch held at its published low end": [("center", 4, LIMITS.rom_low[4])],
    "roll sine over the whole range at the speed limit": [
        ("waveform", 3, Waveform.SINE),
        ("amplitude", 3, LIMITS.rom_high[3]),
        ("frequency", 3, 0.9999 * LIMITS.axis_speed_max[3] / (2 * math.pi * LIMITS.rom_high[3])),
    ],
    "yaw ramp end to end at the speed limit": [
        ("waveform", 5, Waveform.RAMP),
        ("center", 5, LIMITS.rom_low[5]),
        ("ramp_end", 5, LIMITS.rom_high[5]),
        ("ramp_rate", 5, LIMITS.axis_speed_max[5]),
    ],
    "heave held at its published high end": [("center", 2, LIMITS.rom_high[2])],
    # The legs' combined speed at its bound, where the fade-in adds most (1 Hz).
    "roll, pitch and yaw sines together at the leg speed bound": [
        (name, k, getattr(at_the_leg_speed_bound(1.0, (-1, -1, 1)), name)[k])
        for name in ("waveform", "amplitude", "frequency")
        for k in (3, 4, 5)
    ],
    "a hold with the least force and torque limits": [
        ("force_limit", -1, commands.FORCE_LIMIT_MIN),
        ("torque_limit", -1, commands.TORQUE_LIMIT_MIN),
    ],
}


@pytest.mark.parametrize("name", list(EXTREMES))
def test_an_accepted_extreme_segment_runs_without_tripping(
    service: DeviceService, name: str
) -> None:
    seg = segment(segment_id=9, duration=2.5)
    for field, k, value in EXTREMES[name]:
        if k < 0:
            scalar: dict[str, object] = {field: value}
            seg = dataclasses.replace(seg, **scalar)  # type: ignore[arg-type]
        else:
            seg = with_axis(field, k, value, seg)
    seg = dataclasses.replace(seg, duration=2.5)
    assert verdict(seg, ready()) is None, "the extreme must be one the device accepts"

    async def run_once(dev: DeviceClient) -> bool:
        """Run ``seg`` to its end; whether the host's stalls held it on the way."""
        held = False
        watchdogs = last_watchdog(service)
        await dev.start_segment(seg)
        await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=2.0)
        while True:
            t = await dev.wait_for_mode(DeviceMode.READY, DeviceMode.HOLD, timeout=20.0)
            assert t.trip == Trip.NONE, t.trip
            if t.mode == DeviceMode.READY:
                return held
            # Only a host that stood still past the watchdog may hold it (the device did
            # right); go on from where it held.
            assert last_watchdog(service) > watchdogs, dev.last_event
            watchdogs, held = last_watchdog(service), True
            await dev.resume()
            await dev.wait_for_mode(DeviceMode.ACTIVE, DeviceMode.READY, timeout=2.0)

    async def main() -> None:
        dev = await DeviceClient.connect(service.link.name)
        try:
            if service.mode == DeviceMode.ACTIVE:  # the last short segment, still returning
                await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            if service.mode != DeviceMode.READY:
                await dev.arm_home()
                await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            for _attempt in range(3):
                if not await run_once(dev):
                    break  # once through without a pause: the claim holds
            else:
                pytest.fail("the host stalled past the watchdog in each of three runs")
        finally:
            await dev.close()

    asyncio.run(main())
    assert service.rig.trip == Trip.NONE and service.mode == DeviceMode.READY
