"""The ring guard (device.ring): what it takes for a ring, and what it does about one."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from device import ring
from device.controller import CONTROL_PERIOD, ControllerConfig, build_params
from device.hardware import SimulatedHardware
from device.plant.params import TICK_HZ

DT = CONTROL_PERIOD / TICK_HZ
P = build_params(ControllerConfig())[0].ring


def _feed(rate: np.ndarray, decay: float = 6.7, drive: float = 0.0) -> tuple[np.ndarray, list[int]]:
    """Feed the law's ``rate``; ``decay``: its own mode's (B / 2J; K = 50, B = 0.4);
    ``drive``: the axis's own sine (Hz, 0: none)."""
    row = ring.new_ring()[4]
    ring.factor(row, 50.0, 1.0)
    seen = [n for n, r in enumerate(rate) if ring.watch(row, float(r), P, decay, drive)]
    return row, seen


def _t(seconds: float) -> np.ndarray:
    return np.arange(round(seconds / DT)) * DT


@pytest.mark.parametrize("hz", [6.0, 9.5, 11.0, 20.0])
def test_a_sustained_oscillation_in_the_band_is_a_ring_within_its_half_cycles(hz: float) -> None:
    t = _t(2.0)
    row, seen = _feed(0.3 * np.sin(2 * math.pi * hz * t))
    assert seen, hz
    # Six cycles are twelve half-cycles, after the high-pass has come up to the signal.
    assert seen[0] * DT <= (P.cycles + 4) / (2 * hz), (hz, seen[0] * DT)
    assert row[ring.G_FACTOR] > 1.0
    assert row[ring.G_HZ] == pytest.approx(hz, rel=0.12)


@pytest.mark.parametrize(
    ("hz", "amplitude"), [(0.5, 5.0), (2.0, 3.0), (3.0, 1.0), (4.0, 0.5)], ids=str
)
def test_a_foots_own_motion_however_large_is_no_ring(hz: float, amplitude: float) -> None:
    """A torque sine moves the law at the foot's pace: the high-pass and the half-cycles'
    length both keep it out (amplitudes in rad/s, far above the guard's 0.05)."""
    _row, seen = _feed(amplitude * np.sin(2 * math.pi * hz * _t(4.0)))
    assert seen == []


def test_a_push_that_rings_down_is_no_ring() -> None:
    """A kick excites the loop's mode for a few cycles and dies: 9 Hz falling by half a
    cycle, as a push on a damped axis does."""
    t = _t(2.0)
    _row, seen = _feed(0.6 * np.exp(-t / 0.1) * np.sin(2 * math.pi * 9.0 * t))
    assert seen == []


def test_the_laws_own_light_mode_ringing_down_after_a_push_is_no_ring() -> None:
    """A stiff axis on an empty plate rings down on the law's virtual mode (9 Hz) for dozens
    of half-cycles, losing a few percent of its amplitude on each: not sustained."""
    w = 2 * math.pi * 9.0
    decay = -math.log(0.6) / (P.cycles / (2 * 9.0))  # 0.6 of it left after a run
    x = v = 0.0
    rate = []
    for n in range(round(3.0 / DT)):  # J a + B v + K x = F, a 0.1 s push (J = 1)
        push = 2.0 * w if n * DT < 0.1 else 0.0
        for _ in range(10):
            a = push - 2.0 * decay * v - w * w * x
            v += a * DT / 10
            x += v * DT / 10
        rate.append(v)
    assert max(np.abs(rate[-25:])) < 0.1 * max(np.abs(rate))  # it did ring down
    _row, seen = _feed(np.array(rate), decay)
    assert seen == []


def test_a_ring_that_grows_or_holds_is_one() -> None:
    t = _t(3.0)
    _row, seen = _feed(0.1 * np.exp(0.3 * t) * np.sin(2 * math.pi * 9.0 * t))
    assert seen


def test_a_multiple_of_the_exercises_own_sine_is_its_motion_not_a_ring() -> None:
    """A 3 Hz pitch sine moves the law at 9 Hz too (a stiff foot's torque is no pure sine);
    the same 9 Hz with no sine, or beside a 0.5 Hz one, is a ring."""
    rate = 0.3 * np.sin(2 * math.pi * 9.0 * _t(2.0))
    assert _feed(rate, drive=3.0)[1] == []
    assert _feed(rate, drive=0.0)[1]
    assert _feed(rate, drive=0.5)[1]  # the 18th multiple: beyond the fifth


def test_an_oscillation_too_small_is_no_ring() -> None:
    _row, seen = _feed(0.5 * P.rate * np.sin(2 * math.pi * 9.0 * _t(2.0)))
    assert seen == []


def test_each_ring_multiplies_the_factor_up_to_its_most_and_a_new_prescription_forgets_it() -> None:
    row, seen = _feed(0.3 * np.sin(2 * math.pi * 9.0 * _t(10.0)))
    assert len(seen) >= 4
    assert row[ring.G_FACTOR] == P.most  # 1.5**4 > 4: capped
    assert row[ring.G_RINGS] == len(seen)
    assert ring.factor(row, 50.0, 1.0) == P.most  # the same prescription keeps it
    assert ring.factor(row, 50.0, 1.2) == 1.0  # a new one starts anew
    assert row[ring.G_RINGS] == 0


def test_a_pause_between_repetitions_keeps_the_factor_and_homing_forgets_it() -> None:
    """Each repetition is a segment of its own, the axis rendering nothing in between: the
    factor a ring earned holds through that, the watch starting anew; a new exercise (the
    device homes again) starts at 1."""
    from device.rig import Rig

    row, seen = _feed(0.3 * np.sin(2 * math.pi * 9.0 * _t(1.2)))
    assert len(seen) == 1 and row[ring.G_FACTOR] == P.step
    assert row[ring.G_RUN] > 0 or row[ring.G_SIGN] != 0.0  # the watch was under way
    ring.pause(row)
    assert row[ring.G_FACTOR] == P.step and row[ring.G_RINGS] == 1
    assert row[ring.G_RUN] == 0 and row[ring.G_SIGN] == 0 and not row[ring.G_Z : ring.G_Z + 4].any()
    assert ring.factor(row, 50.0, 1.0) == P.step  # the same prescription, next repetition
    rig = Rig()
    rig.state.ring[4] = row
    rig.forget_rings()
    assert rig.state.ring[4, ring.G_FACTOR] == 1.0 and rig.state.ring[4, ring.G_RINGS] == 0


def test_the_guard_is_on_for_the_rotations_only_and_off_when_configured() -> None:
    assert list(P.on) == [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
    off = build_params(ControllerConfig(ring_guard=False))[0].ring
    assert list(off.on) == [0.0] * 6


@pytest.mark.parametrize(
    "change",
    [
        {"ring_rate": 0.0},
        {"ring_half_cycles": 1},
        {"ring_band": (30.0, 5.0)},
        {"ring_band": (5.0, 200.0)},
        {"ring_step": 1.0},
        {"ring_most": 0.5},
        {"ring_sustain": 1.5},
        {"ring_own": -1.0},
        {"ring_harmonics": -1},
        {"ring_harmonic_share": 0.5},
        {"ring_corner": float("nan")},
    ],
    ids=str,
)
def test_a_guard_that_could_not_work_is_refused(change: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="ring guard"):
        build_params(ControllerConfig(**change))  # type: ignore[arg-type]


def test_a_stiff_resisting_ankle_below_the_pitch_edge_rings_without_the_guard_and_not_with_it() -> (
    None
):
    """Build 18 (long tubes), pitch, K = 50, a patient co-contracting on the stiffest
    plausible ankle (30 N m/rad). At the published least damping (0.4) the plate rang at
    9-10 Hz, 0.4 deg peak to peak, while the law kept that floor at every frequency; since
    it holds only above the lag corner (``ControllerConfig.impedance_lag_corner``), whose
    filter leaves more than the floor at 5-9 Hz, it stays within 0.05 deg without the guard.
    With the lab's floor lowered to 0.3 it rings at 10 Hz, 0.7 deg: without the guard for as
    long as it is watched; with it, the ring is seen and the plate is still in the last
    second."""
    from lab import envelope
    from lab.experiments import PlantChoice

    unit = PlantChoice(draw=18, calibrate=False)  # uncalibrated: no identification to wait for
    edge = envelope.run_point("pitch", envelope.STIFF, 50.0, 0.4, unit=unit, ring_guard=False)
    assert not edge["unstable"] and edge["pp_det_deg"] < 0.1, edge
    b = 0.3
    low = envelope.floor_at(b)
    bare = envelope.run_point(
        "pitch", envelope.STIFF, 50.0, b, unit=unit, ring_guard=False, limits=low
    )
    assert bare["rings"] == 0
    assert bare["unstable"] and 6.0 <= bare["f_hz"] <= 12.0, bare
    guarded = envelope.run_point("pitch", envelope.STIFF, 50.0, b, unit=unit, limits=low)
    assert guarded["rings"] >= 1, guarded
    assert not guarded["unstable"], guarded


def test_through_the_service_a_ring_is_an_event_and_its_damping_holds_to_the_next_exercise() -> (
    None
):
    """The device service on a pty, build 18 with a patient co-contracting on the stiffest
    plausible ankle, pitch at K = 50 and the least damping the device publishes, here
    lowered to 0.3 (lab limits: at the published 0.4 this foot no longer makes the loop
    ring, see the test above): after a push, the host hears a DAMPING_RAISED event naming
    pitch, the factor and the ring's frequency. The next repetition (a segment of its own)
    starts with the raised damping; homing again for a new exercise starts from the law's
    own."""
    import asyncio

    from device.client import AxisPlan, DeviceClient, build_segment
    from device.hardware import SimulatedHardware
    from device.plant.model import SCRIPT_CONSTANT, SCRIPT_NONE
    from device.plant.params import draw_plant
    from device.protocol import messages as m
    from device.protocol.messages import DeviceMode, EventKind
    from device.rig import Rig
    from device.service import WATCHDOG_MS_MAX, ServiceConfig
    from device.waveforms import Waveform
    from lab import envelope
    from tests.device.service_thread import service_in_thread

    foot, ankle = envelope.plant_patient(envelope.STIFF)
    hardware = SimulatedHardware(draw_plant(18, foot).changed(ankle), seed=1)
    lowered = envelope.floor_at(0.3)
    rig = Rig(hardware, limits=lowered)
    seen: list[m.Event] = []
    factors: list[float] = []

    async def push() -> None:
        now = float(hardware.state.time[0])
        hardware.script_torque(4, SCRIPT_CONSTANT, now, envelope.PULSE_NM, 0.0)
        await asyncio.sleep(0.1)
        hardware.script_torque(4, SCRIPT_NONE, 0.0, 0.0, 0.0)

    async def main(link: str) -> None:
        dev = await DeviceClient.connect(link)
        try:
            events = dev.events()

            async def collect() -> None:
                async for event in events:
                    if event.kind == EventKind.DAMPING_RAISED:
                        seen.append(event)

            collector = asyncio.create_task(collect())
            assert dev.hello is not None
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            least = lowered.published().damping_min_at(4, 50.0)  # as HELLO says
            plan = AxisPlan(Waveform.HOLD, stiffness=50.0, damping=least, compliant=True)
            await dev.start_segment(build_segment(dev.hello, 1, 4.0, {"pitch": plan}))
            await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=5.0)
            await asyncio.sleep(0.5)
            await push()
            async with asyncio.timeout(30.0):
                while not seen:
                    await asyncio.sleep(0.05)
            await dev.wait_for_mode(DeviceMode.READY, timeout=30.0)  # the repetition ends
            factors.append(float(rig.state.ring[4, ring.G_FACTOR]))
            await dev.start_segment(build_segment(dev.hello, 2, 4.0, {"pitch": plan}))
            await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=5.0)
            factors.append(float(rig.state.ring[4, ring.G_FACTOR]))  # the next one starts
            await asyncio.sleep(0.5)
            await push()
            await dev.wait_for_mode(DeviceMode.READY, timeout=30.0)
            factors.append(float(rig.state.ring[4, ring.G_FACTOR]))
            await dev.arm_home()  # a new exercise
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            factors.append(float(rig.state.ring[4, ring.G_FACTOR]))
            collector.cancel()
        finally:
            await dev.close()

    with service_in_thread(hardware, ServiceConfig(watchdog_ms=WATCHDOG_MS_MAX), rig) as link:
        asyncio.run(main(link.name))
    assert seen and all(e.code == 4 for e in seen), [e.text for e in seen]
    event = seen[0]
    assert event.value == pytest.approx(P.step)
    assert event.text.startswith("pitch rang at ") and "raised 1.50 times" in event.text, event.text
    assert "(law 0.45)" in event.text, event.text  # 1.5 times the edge's 0.3, from now on
    assert event.text.endswith("until its K or B changes"), event.text  # whole, not cut at 120
    # The factor earned in the first repetition is where the second starts (a foot that
    # rang at 0.6 too may raise it once more there); homing again starts from 1.
    first, second_start, second_end, homed = factors
    assert first >= P.step and second_start == first and second_end >= first, factors
    assert homed == 1.0


def test_an_experiment_during_which_the_guard_acted_says_so_and_is_not_valid() -> None:
    """A measurement of rendered damping while the guard had raised it measures the guard:
    the experiment's health names the axis, the ring and the factor, and is not valid."""
    from device.plant.model import SCRIPT_CONSTANT, SCRIPT_NONE
    from device.plant.params import draw_plant
    from device.rig import Rig
    from lab import envelope, experiments

    foot, ankle = envelope.plant_patient(envelope.STIFF)
    hardware = SimulatedHardware(draw_plant(18, foot).changed(ankle), seed=1)
    rig = Rig(hardware, limits=envelope.floor_at(0.3))  # where this foot rings (above)
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(0.5, log_hz=0)
    stiffness, damping = np.zeros(6), np.zeros(6)
    stiffness[4], damping[4] = 50.0, 0.3
    rig.set_impedance(stiffness, damping, [k == 4 for k in range(6)])
    rig.track({})
    rig.run(0.5, log_hz=0)
    assert experiments.assess(rig, rig.run(0.2)).valid  # nothing rang yet
    hardware.script_torque(4, SCRIPT_CONSTANT, rig.time, envelope.PULSE_NM, 0.0)
    rig.run(0.1, log_hz=0)
    hardware.script_torque(4, SCRIPT_NONE, 0.0, 0.0, 0.0)
    health = experiments.assess(rig, rig.run(3.0))
    assert not health.valid and not health.tripped
    assert health.reason is not None and health.reason.startswith("pitch rang at ")
    # Once or twice at this floor (1.50 or 2.25 times): each ring multiplies by 1.5.
    assert re.search(r"ring guard raised its damping (1\.50|2\.25) times", health.reason), (
        health.reason
    )
