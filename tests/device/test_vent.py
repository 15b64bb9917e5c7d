"""Release (slow vent) after a stop: exhaust pulses only, gentle sinking, no trips."""

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from device import controller as ctl
from device import pwm
from device.controller import ControllerConfig, Mode
from device.hardware import SimulatedHardware
from device.plant.faults import Fault, FaultKind
from device.plant.params import PlantConfig
from device.rig import Rig
from device.safety import Trip
from device.tickloop import COL, run_hardware

P0 = COL["pressure_g0"]
X0 = COL["leg_x0"]

VENT_BELOW = 0.2e5
"""Every chamber below this gauge pressure (Pa) counts as vented."""
VENT_TIME_MIN, VENT_TIME_MAX = 1.5, 4.0
"""Bounds on the time to vent from a hold at home (s); measured 2.6 s over seeds and
patients with 8-slot pulses every 4th period (every period: 0.7 s, too fast)."""
SPEED_MAX = 0.020
"""Largest leg speed while venting under a foot (m/s), over 10 ms; measured 16-17 mm/s."""


class RecordingHardware(SimulatedHardware):
    """The plant, keeping every valve vector the controller writes."""

    def __init__(self, config: PlantConfig, seed: int = 0) -> None:
        super().__init__(config, seed)
        self.written: list[NDArray[np.uint8]] = []

    def write_valves(self, valves: NDArray[np.uint8]) -> None:
        self.written.append(valves.copy())
        super().write_valves(valves)


def held_at_home(patient: str = "relaxed", seed: int = 2) -> Rig:
    """Legs held mid-stroke in JOINT mode (about 5 bar in every chamber), then IDLE."""
    r = Rig(RecordingHardware(PlantConfig(patient=patient), seed=seed))
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.hold()
    r.run(0.3, log_hz=0)
    assert r.mode == Mode.IDLE
    return r


def plant_gauge(r: Rig) -> NDArray[np.float64]:
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    return np.asarray(hw.state.pressure - hw.params.p_atm)


def record(r: Rig, ticks: int) -> tuple[int, NDArray[np.uint8]]:
    """Run the Python tick loop; returns the first tick and the (ticks, 24) valves written."""
    hw = r.hardware
    assert isinstance(hw, RecordingHardware)
    hw.written.clear()
    first = int(r.state.istate[ctl.I_TICK])
    run_hardware(r.state, r.params, hw, ticks)
    return first, np.array(hw.written)


def vent_time_and_speed(log: NDArray[np.float64]) -> tuple[float, float]:
    t = log[:, COL["t"]] - log[0, COL["t"]]
    vented = np.all(log[:, P0 : P0 + 12] < VENT_BELOW, axis=1)
    t_vent = float(t[np.argmax(vented)]) if vented.any() else float("inf")
    x = log[:, X0 : X0 + 6]
    k = 10  # 10 ms at 1 kHz
    speed = np.abs(x[k:] - x[:-k]) / (t[k:] - t[:-k])[:, None]
    return t_vent, float(speed.max())


def test_vent_pulse_must_fit_the_pwm_period() -> None:
    with pytest.raises(ValueError, match="vent_pulse_slots"):
        ctl.build_params(ControllerConfig(vent_pulse_slots=pwm.PWM_SLOTS + 1))


@pytest.mark.parametrize(("patient", "seed"), [("relaxed", 2), ("relaxed", 7), ("resisting", 1)])
def test_venting_from_a_hold_lowers_every_chamber_gently(patient: str, seed: int) -> None:
    r = held_at_home(patient, seed)
    # At working pressure (resting on their trapped air the chambers hold 3.4-4.9 bar).
    assert np.all(r.state.pressure > 3.0e5)
    r.state.istate[ctl.I_VENT] = 1
    log = r.run(6.0, log_hz=1000)
    t_vent, speed = vent_time_and_speed(log)
    assert VENT_TIME_MIN < t_vent < VENT_TIME_MAX
    assert speed < SPEED_MAX
    sink = log[0, X0 : X0 + 6] - log[-1, X0 : X0 + 6]
    assert np.all(sink > 5e-3)  # the platform has come down onto the foot's support
    assert np.all(log[-1, P0 : P0 + 12] < VENT_BELOW)
    assert r.mode == Mode.IDLE and r.trip == Trip.NONE
    assert np.all(log[:, COL["mode"]] == Mode.IDLE)


def test_venting_to_the_stroke_end_does_not_trip() -> None:
    r = held_at_home("absent", 3)  # no foot: the platform sinks onto the end stops
    r.state.istate[ctl.I_VENT] = 1
    log = r.run(10.0, log_hz=200)
    margin = r.limits.stroke_margin
    assert np.all(log[:, X0 : X0 + 6].min(axis=0) < margin)
    assert np.all(r.state.leg_x < margin)  # the controller saw it too
    assert r.mode == Mode.IDLE and r.trip == Trip.NONE
    assert int(r.state.istate[ctl.I_TRIPS]) == 0


def test_venting_works_while_tripped_and_keeps_the_trip() -> None:
    r = held_at_home()
    before = plant_gauge(r)
    r.estop()
    r.run(0.2, log_hz=0)
    # Tripped: everything closed, pressures held (what a chamber's piston leak moves aside).
    assert np.all(plant_gauge(r) > 3.5e5)
    assert np.allclose(plant_gauge(r), before, atol=0.1e5)
    r.state.istate[ctl.I_VENT] = 1
    log = r.run(5.0, log_hz=1000)
    t_vent, speed = vent_time_and_speed(log)
    assert t_vent < VENT_TIME_MAX and speed < SPEED_MAX
    assert r.mode == Mode.FAULT and r.trip == Trip.ESTOP
    assert int(r.state.istate[ctl.I_TRIPS]) == 1


@pytest.mark.parametrize("tripped", [False, True])
def test_only_exhaust_valves_open_while_venting(tripped: bool) -> None:
    r = held_at_home()
    if tripped:
        r.estop()
    r.state.istate[ctl.I_VENT] = 1
    before = plant_gauge(r)
    periods = 24  # a whole number of venting cycles for every 1, 2, 3, 4, 6 periods
    ticks = periods * pwm.PWM_SLOTS
    first, valves = record(r, ticks)
    assert valves.shape == (ticks, 24)
    assert not valves[:, 0::2].any()  # intakes never energised
    n, every = r.params.vent_pulse_slots, r.params.vent_every_periods
    assert n > 0 and periods % every == 0
    since = first + np.arange(ticks)[:, None] - r.params.pwm_phase[None, :]
    pulsing = (since // pwm.PWM_SLOTS) % every == 0
    expected = ((since % pwm.PWM_SLOTS < n) & pulsing).astype(np.uint8)  # (ticks, 6 legs)
    exhaust = valves[:, 1::2]
    assert np.array_equal(exhaust[:, 0::2], expected)  # cap side of each leg
    assert np.array_equal(exhaust[:, 1::2], expected)  # rod side
    assert np.all(exhaust.sum(axis=0) == periods // every * n)  # a pulse per `every` periods
    # The pulse outlasts the valve's delay: every chamber loses pressure.
    assert np.all(plant_gauge(r) < before - 0.1e5)


@pytest.mark.parametrize("motion", ["joint", "task"])
def test_vent_flag_has_no_effect_while_moving(motion: str) -> None:
    runs: list[NDArray[np.float64]] = []
    for vent in (0, 1):
        r = Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=4))
        r.state.istate[ctl.I_VENT] = vent
        if motion == "joint":
            r.move_legs(r.state.leg_x + np.array([0.004, 0.0, -0.003, 0.0, 0.0, 0.002]))
        else:
            r.track({})
        r.run(0.5, log_hz=0)
        s = r.state
        runs.append(np.concatenate([s.leg_x, s.pressure, s.slots, s.valves], dtype=np.float64))
        assert r.trip == Trip.NONE
        assert np.all(r.state.pressure > 3.0e5)
    assert np.array_equal(runs[0], runs[1])  # the same valves, pressures and legs, bit for bit
    # The flag was live all along: stopping the motion starts the release at once.
    held = plant_gauge(r)
    r.hold()
    r.run(0.2, log_hz=0)
    assert np.all(plant_gauge(r) < held - 0.5e5)


def test_idle_without_the_flag_keeps_every_valve_closed() -> None:
    r = held_at_home()
    before = plant_gauge(r)
    _, valves = record(r, 10 * pwm.PWM_SLOTS)
    assert not valves.any()
    assert np.allclose(plant_gauge(r), before, atol=0.02e5)
    # Venting for a while, then clearing the flag, holds the pressures where they are.
    r.state.istate[ctl.I_VENT] = 1
    r.run(0.3, log_hz=0)
    vented = plant_gauge(r)
    assert np.all(vented < before - 0.5e5)
    r.state.istate[ctl.I_VENT] = 0
    _, valves = record(r, 10 * pwm.PWM_SLOTS)
    assert not valves.any()
    assert np.allclose(plant_gauge(r), vented, atol=0.02e5)


@pytest.mark.parametrize(
    "valves",
    [
        (("valve_open_delay", 1.05e-3), ("valve_delay_spread", 0.15), ("valve_travel", 0.3e-3)),
        (("valve_open_delay", 0.55e-3), ("valve_close_delay", 0.6e-3), ("valve_travel", 0.15e-3)),
    ],
    ids=["slowest plausible valves", "fastest plausible valves"],
)
def test_release_vents_a_unit_with_the_slowest_or_fastest_plausible_valves(
    valves: tuple[tuple[str, float], ...],
) -> None:
    r = Rig(RecordingHardware(PlantConfig(patient="relaxed", overrides=valves), seed=2))
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.hold()
    r.run(0.3, log_hz=0)
    r.state.istate[ctl.I_VENT] = 1
    log = r.run(6.0, log_hz=1000)
    t_vent, speed = vent_time_and_speed(log)
    assert VENT_TIME_MIN < t_vent < VENT_TIME_MAX  # a trapped foot would never be vented
    assert speed < SPEED_MAX


# -- a valve that fails as the platform is released ------------------------------------------


def _released_with(
    kind: FaultKind, valve: int, stopped: str, config: ControllerConfig | None = None
) -> tuple[Rig, NDArray[np.float64], NDArray[np.float64]]:
    """Held at home with a relaxed foot, stopped by ``stopped`` (hold or e-stop), released,
    and ``valve`` failing as the release begins; watched 3 s. (rig, pose at the release,
    true pose log)."""
    r = Rig(
        SimulatedHardware(PlantConfig(patient="relaxed"), seed=2),
        ControllerConfig() if config is None else config,
    )
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.estop() if stopped == "estop" else r.hold()
    r.run(0.1, log_hz=0)
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    r.set_vent(True)
    hw.inject(Fault(kind, float(hw.state.time[0]), valve, 0.0))
    start = np.array(hw.state.pose[:6])
    log = r.run(3.0, log_hz=1000)
    return r, start, log[:, COL["pose_x"] : COL["pose_x"] + 6]


def _tilt_and_shift(start: NDArray[np.float64], pose: NDArray[np.float64]) -> tuple[float, float]:
    """Largest turn about roll or pitch (deg) and sideways shift (mm) from ``start``."""
    d = np.abs(pose - start)
    return float(np.degrees(d[:, 3:5].max())), float(d[:, :2].max() * 1e3)


@pytest.mark.parametrize("stopped", ["hold", "estop"])
@pytest.mark.parametrize(
    ("kind", "valve", "chamber", "why"),
    [
        (FaultKind.VALVE_STUCK_OPEN, 8, 4, "gained"),  # leg 3's cap-side intake
        (FaultKind.VALVE_STUCK_OPEN, 2, 1, "gained"),  # leg 1's rod-side intake
        (FaultKind.VALVE_STUCK_OPEN, 3, 1, "lost"),  # leg 1's rod-side exhaust
        (FaultKind.VALVE_STUCK_CLOSED, 9, 4, "kept"),  # leg 3's cap-side exhaust
        (FaultKind.VALVE_STUCK_CLOSED, 11, 5, "kept"),  # leg 3's rod-side exhaust
    ],
)
def test_a_valve_that_fails_as_the_platform_is_released_stops_the_release(
    kind: FaultKind, valve: int, chamber: int, why: str, stopped: str
) -> None:
    """A release opens no intake, so a chamber whose air rises is fed by a stuck intake, and
    one that keeps its air while the others vent has a stuck exhaust: either would push its
    leg onto an end stop and tilt the foot (measured before the watch, strength exercise:
    10-11 deg in roll). The release stops, the chamber is named, the platform is held
    (measured: stuck-shut exhausts 0.8-1.0 deg, 1.7-1.9 mm; a stuck-open exhaust, its
    chamber refilled to where the others' venting would have left it, 0.69 deg and 1.01 mm,
    2.84 mm held where it was found; stuck intakes, their legs' other sides fed to match,
    1.06-1.32 deg and 2.61-2.73 mm, 3.1-3.6 mm with the exhaust alone)."""
    r, start, pose = _released_with(kind, valve, stopped)
    assert r.release_stopped == (chamber, why)
    assert not r.venting and r.mode == Mode.FAULT
    if stopped == "estop":  # the trip that came first stays the one latched
        assert r.trip == Trip.ESTOP
    else:
        assert r.trip == Trip.VALVE and r.trip_channel == chamber
    tilt, shift = _tilt_and_shift(start, pose)
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


def test_without_the_release_watch_the_same_stuck_exhaust_tilts_the_platform() -> None:
    """The counterfactual of the test above: the watch made (nearly) blind."""
    from device.supervision import SupervisionConfig

    blind = ControllerConfig(
        supervision=SupervisionConfig(
            release_gain=9.0, release_judged=9.9e5, release_ahead=0.99, release_ahead_ratio=99.0
        )
    )
    r, start, pose = _released_with(FaultKind.VALVE_STUCK_CLOSED, 9, "hold", blind)
    assert r.release_stopped == (-1, "") and r.venting
    tilt, _ = _tilt_and_shift(start, pose)
    assert tilt > 4.0, tilt


def test_a_stopped_release_is_reported_once_and_a_new_release_watches_again() -> None:
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind

    r = Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=2))
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(r, lambda *e: events.append(e))
    machine.estop()
    machine.release()
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.VALVE_STUCK_OPEN, float(hw.state.time[0]), 8, 0.0))
    for _ in range(100):
        r.run(0.01, log_hz=0)
        machine.step()
    stops = [e for e in events if e[0] == EventKind.FAULT]
    assert len(stops) == 1, events
    _, mode_from, mode_to, code, value, text = stops[0]
    assert mode_from == mode_to == DeviceMode.ESTOP and code == Trip.VALVE and value == 4
    assert "chamber 5 (leg 3, cap side)" in str(text) and "release stopped" in str(text)
    assert str(text).endswith("(intake stuck open): exhaust and other side hold it"), text
    # Asked again, the device releases again, and stops again on the same valve.
    machine.release()
    assert r.venting and r.release_stopped == (-1, "")
    for _ in range(100):
        r.run(0.01, log_hz=0)
        machine.step()
    assert r.release_stopped == (4, "gained") and not r.venting
    assert len([e for e in events if e[0] == EventKind.FAULT]) == 2


def _held_with(
    kind: FaultKind,
    channel: int,
    patient: str = "relaxed",
    value: float = 0.0,
    seconds: float = 1.0,
) -> tuple[Rig, NDArray[np.float64], NDArray[np.float64]]:
    """Held at home in IDLE (the service's HOLD: every valve shut), ``kind`` injected 0.3 s
    in, watched ``seconds``: (rig, pose at the fault, true pose log)."""
    r = Rig(SimulatedHardware(PlantConfig(patient=patient), seed=2))
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.hold()
    r.run(0.3, log_hz=0)
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(kind, float(hw.state.time[0]), channel, value))
    start = np.array(hw.state.pose[:6])
    log = r.run(seconds, log_hz=1000)
    return r, start, log[:, COL["pose_x"] : COL["pose_x"] + 6]


@pytest.mark.parametrize(
    ("kind", "channel", "chamber"),
    [
        (FaultKind.VALVE_STUCK_OPEN, 3, 1),  # leg 1's rod-side exhaust
        (FaultKind.VALVE_STUCK_OPEN, 8, 4),  # leg 3's cap-side intake
        (FaultKind.VALVE_STUCK_OPEN, 9, 4),  # leg 3's cap-side exhaust
        (FaultKind.CHAMBER_LEAK, 6, 6),  # leg 4's cap side
    ],
)
def test_a_valve_stuck_open_while_every_valve_is_shut_is_held(
    kind: FaultKind, channel: int, chamber: int
) -> None:
    """The service's HOLD shuts every valve; a chamber whose air then moves has a valve
    stuck open or a leak. Before this watch leg 1's rod-side exhaust, held at home, let the
    leg run 37 mm and the platform turn 8.4 deg in roll, unseen (only the bleed after a
    trip watched shut valves). Now a VALVE trip names the chamber and a valve of its own
    holds it."""
    value = 0.1 if kind == FaultKind.CHAMBER_LEAK else 0.0  # a tenth of a valve's C
    r, start, pose = _held_with(kind, channel, value=value)
    assert r.trip == Trip.VALVE and r.trip_channel == chamber, (r.trip, r.trip_channel)
    tilt, shift = _tilt_and_shift(start, pose)
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


@pytest.mark.parametrize(("valve", "after"), [(1, 0.0), (9, 0.02), (2, 0.05)])
def test_a_valve_that_fails_just_after_the_valves_shut_is_named_at_once(
    valve: int, after: float
) -> None:
    """The hold that ends the safety matrix's pitch exercise, and a valve stuck open
    ``after`` s later, inside the first window of the shut watch. While that window only
    set the references, an exhaust stuck then was named 56-106 ms in, its leg 8.2-12.8 mm
    down and the platform turned 4.2-6.1 deg; a rod-side intake was not named at all."""
    from lab import shutwatch

    r = shutwatch._exercise_held("relaxed", None)
    r.run(after, log_hz=0) if after > 0 else None
    named, at, tilt, shift = shutwatch._watch(
        r, Fault(FaultKind.VALVE_STUCK_OPEN, 0.0, valve, 0.0), False
    )
    assert named == valve // 2 and at <= 30.0, (named, at)
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
@pytest.mark.parametrize("valve", [4, 16, 20])
def test_an_intake_stuck_open_while_every_valve_is_shut_is_balanced_by_its_legs_other_side(
    valve: int, patient: str
) -> None:
    """An intake stuck open with every valve shut: its exhaust cannot hold the chamber (it
    rises toward the supply), so, as in a release (``release_balance``), the leg's other
    chamber is fed by what the stuck one gained since it was named. By the exhaust alone
    (``ankle bench shutwatch``, 3 s, every axis): valves 4, 16 and 20 turned the platform
    1.26-2.02 deg and shifted it 2.19-3.70 mm; balanced, 0.57-1.49 deg and 1.17-2.73 mm."""
    chamber = valve // 2
    r, start, pose = _held_with(FaultKind.VALVE_STUCK_OPEN, valve, patient)
    assert r.trip == Trip.VALVE and r.trip_channel == chamber, (r.trip, r.trip_channel)
    assert r.state.istate[ctl.I_BLEED] == ctl.HOLD_BALANCE + chamber
    moved = np.abs(pose - start).max(axis=0)
    assert np.degrees(moved[3:]).max() < 2.0 and 1e3 * moved[:3].max() < 3.0, moved


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
@pytest.mark.parametrize(("chamber", "size"), [(1, 0.02), (9, 0.02), (4, 0.05)])
def test_a_slow_leak_while_every_valve_is_shut_is_held(
    chamber: int, size: float, patient: str
) -> None:
    """A leak of a fiftieth or a twentieth of a valve moves its chamber's air 1.5-3.8 % in
    0.1 s, under the window's 5 %: before the trailing average (``shut_slow_air``) a
    twentieth ran the platform 3.6 deg and 6.9 mm, and was never named on some holds.
    Measured since: 0.19-0.51 deg and 0.53-1.04 mm, named and held."""
    r, start, pose = _held_with(FaultKind.CHAMBER_LEAK, chamber, patient, size)
    assert r.trip == Trip.VALVE and r.trip_channel == chamber, (r.trip, r.trip_channel)
    assert r.state.istate[ctl.I_BLEED] == ctl.HOLD_FEED + chamber  # its intake holds it
    tilt, shift = _tilt_and_shift(start, pose)
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
@pytest.mark.parametrize(("chamber", "size"), [(4, 0.01), (5, 0.005), (0, 0.005), (9, 0.01)])
def test_a_leak_too_slow_for_the_chambers_windows_is_named_by_its_legs_air(
    chamber: int, size: float, patient: str
) -> None:
    """A leak of a hundredth or a two-hundredth of a valve loses about 4 or 2 % of its
    chamber's air a second, under the window's and the trailing average's floors (about 13
    % a second): it was never named, and the resting platform tilted 7 deg and moved 8 mm
    in 15 s. Its leg's air, against what the seats and the piston move by their model, is
    named within seconds, the chamber of the two that lost more held by its intake."""
    r, start, pose = _held_with(FaultKind.CHAMBER_LEAK, chamber, patient, size, seconds=6.0)
    assert r.trip == Trip.VALVE and r.trip_channel == chamber, (r.trip, r.trip_channel)
    assert r.state.istate[ctl.I_BLEED] == ctl.HOLD_FEED + chamber  # its intake holds it
    assert r.tripped_at is not None
    named = r.tripped_at - (r.time - 6.0)  # s after the leak began
    print(f"named {named:.3f} s in")
    assert named < 4.0, named
    moved = np.abs(pose - start).max(axis=0)
    assert np.degrees(moved[3:]).max() < 2.0 and 1e3 * moved[:3].max() < 3.0, moved


@pytest.mark.parametrize(("chamber", "size"), [(4, 0.01), (7, 0.005)])
def test_a_slow_leak_in_ready_is_reported_by_the_service_with_its_chamber(
    chamber: int, size: float
) -> None:
    """The calibrated nominal unit homed by the mode machine as the service does, resting in
    READY with a relaxed foot: a leak too slow for the chamber windows, starting 2 s in, is
    a FAULT event naming its chamber (before: never named, 7 deg and 8 mm in 15 s)."""
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind
    from device.trips import where
    from lab.safety import _rig

    r = _rig("relaxed", 1)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(r, lambda *e: events.append(e))
    machine.arm_home()
    while machine.mode == DeviceMode.HOMING:
        r.run(0.01, log_hz=0)
        machine.step()
    assert machine.mode == DeviceMode.READY
    r.run(2.0, log_hz=0)
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.CHAMBER_LEAK, float(hw.state.time[0]), chamber, size))
    start = np.array(hw.state.pose[:6])
    for _ in range(400):  # 4 s
        r.run(0.01, log_hz=0)
        machine.step()
    faults = [e for e in events if e[0] == EventKind.FAULT]
    assert len(faults) == 1 and r.mode == Mode.FAULT and r.trip_channel == chamber, events
    assert faults[0][3] == Trip.VALVE, faults
    assert where(Trip.VALVE, chamber) in str(faults[0][5]), faults
    moved = np.abs(np.array(hw.state.pose[:6]) - start)
    assert np.degrees(moved[3:]).max() < 2.0 and 1e3 * moved[:3].max() < 3.0, moved


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
@pytest.mark.parametrize(("chamber", "size"), [(1, 0.005), (6, 0.01)])
def test_a_slow_leak_after_the_hold_that_ends_an_exercise_is_named(
    chamber: int, size: float, patient: str
) -> None:
    """The hold that ends the safety matrix's pitch exercise, then a slow leak: the chambers
    were just filled and vented by the loop, and the fills' cooling a real chamber would
    still lose is allowed for (``shut_thermal_time``); the leak is named within 3 s."""
    from lab import shutwatch

    r = shutwatch._exercise_held(patient, None)
    named, at, tilt, shift = shutwatch._watch(
        r, Fault(FaultKind.CHAMBER_LEAK, 0.0, chamber, size), False
    )
    print(f"named {named} at {at:.0f} ms, {tilt:.2f} deg, {shift:.2f} mm")
    assert named == chamber, (named, at)
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
def test_worn_valve_seats_are_not_taken_for_a_leak(patient: str) -> None:
    """Drawn build 1's valve seats pass 0.43 NL/min (a new one 0.01): resting 20 s in READY
    its legs' air moves by several percent, as much as a leak's (its exhausts' seats let
    air out, its intakes' let supply air in). Against the seats' and the pistons' model,
    at the rates the legs themselves show, no leg loses more than a fraction of the
    threshold."""
    from device import supervision
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode
    from lab.safety import _drawn_rig

    r = _drawn_rig(patient, 1)
    machine = ModeMachine(r, lambda *e: None)
    machine.arm_home()
    while machine.mode == DeviceMode.HOMING:
        r.run(0.01, log_hz=0)
        machine.step()
    r.run(0.02, log_hz=0)

    def legs_air() -> NDArray[np.float64]:
        air = np.array([ctl.chamber_air(r.state, r.params, c) for c in range(12)])
        return np.asarray(air[0::2] + air[1::2])

    before = legs_air()
    r.run(20.0, log_hz=0)
    moved = np.abs(legs_air() / before - 1.0).max()
    assert moved > 0.03, moved  # the seats moved a leg's air as a leak would
    assert r.trip == Trip.NONE and machine.mode == DeviceMode.READY
    assert r.state.monitor[supervision.M_LEG_AIR] > 0.0  # judged: a trailing average
    peak = r.state.monitor[supervision.M_LEG_AIR + 42]
    assert peak < 0.5, peak


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
def test_a_long_healthy_hold_is_not_taken_for_a_stuck_valve(patient: str) -> None:
    """Held 20 s with every valve shut while the foot pushes (5 N m in pitch at 0.3 Hz):
    the seals' leak past their pistons and the foot's squeeze move no chamber's air by the
    watch's share within its window."""
    r, _ = _held_while_the_foot_pushes(patient, 4, 5.0, 0.3, 20.0)
    assert r.trip == Trip.NONE and r.mode == Mode.IDLE


def _held_while_the_foot_pushes(
    patient: str, axis: int, torque: float, hz: float, seconds: float
) -> tuple[Rig, NDArray[np.float64]]:
    """Held at home (IDLE, every valve shut), the foot pushing a sine of ``torque`` N m at
    ``hz`` on ``axis`` for ``seconds``: (rig, log at 100 Hz)."""
    from device.plant.model import SCRIPT_SINE

    r = Rig(SimulatedHardware(PlantConfig(patient=patient), seed=3))
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.hold()
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.script_torque(axis, SCRIPT_SINE, r.time, torque, hz)
    return r, r.run(seconds, log_hz=100)


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
@pytest.mark.parametrize(("axis", "hz"), [(3, 2.0), (4, 0.3)])
def test_a_foot_that_shakes_the_held_platform_hard_is_not_taken_for_a_leak(
    patient: str, axis: int, hz: float
) -> None:
    """20 N m in roll or pitch, at 2 Hz or 0.3 Hz, for 10 s with every valve shut: the
    foot squeezes the chambers (their air as ``p^(1/k) V`` does not count it) and warms
    them, and neither the window's 5 % nor the trailing averages' 4 % is reached
    (measured at 10 and 20 N m, 0.3-2 Hz, both axes and feet: no trip)."""
    r, log = _held_while_the_foot_pushes(patient, axis, 20.0, hz, 10.0)
    turn = np.degrees(np.ptp(log[:, COL["pose_x"] + axis]))
    assert turn > 2.0, turn  # the foot swung the platform on its trapped air (7.8-9.9 deg)
    assert r.trip == Trip.NONE and r.mode == Mode.IDLE


@pytest.mark.parametrize("code", [1, 13, 25])
def test_every_stopped_release_event_fits_the_wire(code: int) -> None:
    """An event's text is 120 bytes on the wire: the longest part's name still fits whole."""
    from device.modes import ModeMachine

    r = Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=2))
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(r, lambda *e: events.append(e))
    r.state.istate[ctl.I_RELEASE_STOP] = code + 11  # chamber 12 (leg 6, rod side)
    machine.step()
    machine.step()
    assert len(events) == 1, events
    text = str(events[0][5])
    assert len(text.encode()) <= 120 and text.startswith("VALVE on chamber 12 (leg 6, rod side)")
    assert text.endswith(("hold it", "holds it", "held")), text


@pytest.mark.parametrize(
    "bad",
    [
        {"release_gain": 0.0},
        {"release_rise": math.nan},
        {"release_judged": -1.0},
        {"release_lag": 1.0},
        {"release_median": 0.0},
        {"release_ahead": math.inf},
        {"release_ahead_ratio": 0.5},
        {"shut_air": -0.05},
        {"shut_reads": 0},
        {"shut_settle_reads": 0},
        {"release_window": 0},
        {"release_recent_median": 1.0},
        {"shut_slow_air": 0.0},
        {"shut_slow_reads": 0},
        {"shut_leg_air": 0.0},
        {"shut_leg_reads": 0},
        {"shut_charge_index": 0.9},
        {"shut_discharge_index": math.nan},
        {"shut_seat_most": 0.0},
        {"shut_piston_most": -1.0},
        {"shut_thermal_time": 0.0},
    ],
)
def test_a_release_or_shut_watch_setting_out_of_range_is_refused(bad: dict[str, float]) -> None:
    from device.supervision import SupervisionConfig
    from device.supervision import build as build_supervision

    with pytest.raises(ValueError, match=next(iter(bad))):
        build_supervision(SupervisionConfig(**bad), 1.0e5, 0.004)  # type: ignore[arg-type]


def _released_then_failing(
    kind: FaultKind, valve: int, after: float, config: ControllerConfig | None = None
) -> tuple[Rig, float, float]:
    """Held at home with a relaxed foot, released, and ``valve`` failing ``after`` s into
    the release; watched 3 s. (rig, largest tilt (deg) and shift (mm) from the pose at the
    fault)."""
    r = Rig(
        SimulatedHardware(PlantConfig(patient="relaxed"), seed=2),
        ControllerConfig() if config is None else config,
    )
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.hold()
    r.run(0.1, log_hz=0)
    r.set_vent(True)
    r.run(after, log_hz=0)
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    assert r.venting and r.release_stopped == (-1, "")
    hw.inject(Fault(kind, float(hw.state.time[0]), valve, 0.0))
    start = np.array(hw.state.pose[:6])
    log = r.run(3.0, log_hz=1000)
    return r, *_tilt_and_shift(start, log[:, COL["pose_x"] : COL["pose_x"] + 6])


@pytest.mark.parametrize("after", [0.5, 1.0])
@pytest.mark.parametrize(
    ("kind", "valve", "why"),
    [(FaultKind.VALVE_STUCK_CLOSED, 9, "kept"), (FaultKind.VALVE_STUCK_OPEN, 3, "lost")],
)
def test_an_exhaust_that_sticks_halfway_through_a_release_stops_it(
    kind: FaultKind, valve: int, why: str, after: float
) -> None:
    """Judged since the release began, such a chamber's loss still looked like the others'
    (measured before the recent window: stuck shut 14.3 deg, stuck open 5.6 deg and 9.1 mm,
    unseen); over the recent window it is named within about 0.1 s. Measured since: stuck
    shut 0.31-0.33 deg, 0.19-0.40 mm; stuck open 0.58-0.82 deg, 1.05-1.28 mm, refilled to
    where the others' venting would have left it (1.41-1.65 deg, 2.22-3.03 mm held at its
    pressure when named, which its leg had already left)."""
    r, tilt, shift = _released_then_failing(kind, valve, after)
    assert r.release_stopped == (valve // 2, why)
    assert r.trip == Trip.VALVE and r.trip_channel == valve // 2
    assert not r.venting
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


@pytest.mark.parametrize("after", [0.0, 0.5])
def test_a_chamber_that_emptied_first_is_refilled_to_where_the_others_are(after: float) -> None:
    """Named ``lost``, a chamber is fed back to the air the median chamber's share of loss
    would have left it (never above its pressure at the release's start), not held where
    its stuck exhaust had already taken it: its leg runs less than half as far."""
    from device.supervision import SupervisionConfig

    r, tilt, shift = _released_then_failing(FaultKind.VALVE_STUCK_OPEN, 3, after)
    where = ControllerConfig(supervision=SupervisionConfig(release_refill=False))
    r0, tilt0, shift0 = _released_then_failing(FaultKind.VALVE_STUCK_OPEN, 3, after, where)
    assert r.release_stopped == r0.release_stopped == (1, "lost")
    assert r.state.istate[ctl.I_BLEED] == r0.state.istate[ctl.I_BLEED] == ctl.HOLD_FEED + 1
    assert r.state.p_desired[1] > r0.state.p_desired[1] + 0.2e5  # fed back, not just held
    assert shift < 0.6 * shift0 and tilt < 0.6 * tilt0, (tilt, shift, tilt0, shift0)


@pytest.mark.parametrize("after", [0.5, 1.0])
@pytest.mark.parametrize(("valve", "chamber"), [(8, 4), (2, 1)])
def test_an_intake_that_sticks_halfway_through_a_release_is_held_by_its_legs_other_side(
    valve: int, chamber: int, after: float
) -> None:
    """Named at once, its chamber rises to the supply against its own exhaust; the leg's
    other chamber, half vented, is fed by what it gained since (``release_balance``).
    Measured: 1.81-2.42 deg and 2.57-4.07 mm; with the exhaust alone 2.90-6.59 deg and
    5.01-9.63 mm (the leg runs until its other side balances it)."""
    from device.supervision import SupervisionConfig

    r, tilt, shift = _released_then_failing(FaultKind.VALVE_STUCK_OPEN, valve, after)
    assert r.release_stopped == (chamber, "gained")
    assert r.state.istate[ctl.I_BLEED] == ctl.HOLD_BALANCE + chamber
    alone = ControllerConfig(supervision=SupervisionConfig(release_balance=False))
    r0, tilt0, shift0 = _released_then_failing(FaultKind.VALVE_STUCK_OPEN, valve, after, alone)
    assert r0.release_stopped == (chamber, "gained")
    assert r0.state.istate[ctl.I_BLEED] == chamber
    assert shift < 0.8 * shift0 and tilt < 0.8 * tilt0, (tilt, shift, tilt0, shift0)
    assert tilt < 2.5 and shift < 4.5, (tilt, shift)


@pytest.mark.xfail(
    strict=True,
    reason="open (issue 11): an intake that sticks open half a second into a release is "
    "held 2.15 deg / 3.54 mm off (leg 3's cap side) and 2.42 deg / 4.07 mm (leg 1's rod "
    "side), over the 2 deg / 3 mm targets: named within 6 ms, the leg moves while its "
    "other side fills, and a rod side at the supply cannot match a cap side at the supply "
    "(leg 3 runs 11 mm)",
)
@pytest.mark.parametrize("valve", [8, 2])
def test_an_intake_that_sticks_half_a_second_into_a_release_meets_the_targets(
    valve: int,
) -> None:
    r, tilt, shift = _released_then_failing(FaultKind.VALVE_STUCK_OPEN, valve, 0.5)
    assert r.release_stopped == (valve // 2, "gained")
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


def _calibrated() -> ControllerConfig:
    """The nominal unit's own start-up identification (its transducers' noise among it)."""
    from lab.experiments import calibration_of

    return ControllerConfig(calibration=calibration_of(PlantConfig(patient="relaxed")))


@pytest.mark.parametrize("chamber", [3, 4])
def test_a_transducer_frozen_as_the_platform_is_released_is_named_not_its_valve(
    chamber: int,
) -> None:
    """While the exhausts pulse, a frozen chamber reading keeps its pressure as a chamber
    whose exhaust stuck shut would: before, the release stopped 89 ms into the freeze on a
    VALVE trip for that exhaust. A live transducer behind a stuck exhaust still flickers
    by its noise, a frozen one never: the watch does not name a chamber whose reading is
    bit for bit the one before, and the still rule names the transducer (measured: 183 ms
    on chamber 3, whose reading may stand still 189 reads) while its chamber, healthy,
    vents with the others."""
    kind = FaultKind.PRESSURE_STUCK
    r, _, _ = _released_then_failing(kind, chamber, 0.3, _calibrated())
    assert r.trip == Trip.PRESSURE_SENSOR and r.trip_channel == chamber
    assert r.release_stopped == (-1, "") and r.venting
    assert plant_gauge(r).max() < VENT_BELOW  # released all the same


@pytest.mark.parametrize(("valve", "after"), [(9, 0.3), (7, 0.3), (11, 1.0)])
def test_an_exhaust_stuck_shut_is_still_named_on_a_unit_that_knows_its_transducers_noise(
    valve: int, after: float
) -> None:
    """The rule above waits for the reading's next flicker, a few reads behind a stuck
    exhaust (measured: at most 7 reads still): the valve is named as before."""
    r, tilt, shift = _released_then_failing(
        FaultKind.VALVE_STUCK_CLOSED, valve, after, _calibrated()
    )
    assert r.release_stopped == (valve // 2, "kept")
    assert r.trip == Trip.VALVE and r.trip_channel == valve // 2
    assert tilt < 2.0 and shift < 3.0, (tilt, shift)


def test_a_transducer_named_after_a_stop_is_not_judged_by_the_release() -> None:
    """After an e-stop a transducer that jumps is judged faulty (its reading is no longer
    taken, the controller keeps its last): the release watch must not take that kept
    reading for a chamber that kept its air. Before, it judged only the transducer the
    latched trip named, and stopped the release on the good exhaust of that chamber."""
    r = Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=2))
    r.move_legs(r.state.leg_x.copy())
    r.run(1.0, log_hz=0)
    r.estop()
    r.run(0.1, log_hz=0)
    r.set_vent(True)
    r.run(0.3, log_hz=0)
    hw = r.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.PRESSURE_OFFSET, float(hw.state.time[0]), 4, 1.0e5))
    r.run(3.0, log_hz=0)
    assert (r.state.istate[ctl.I_BAD_SENSORS] >> 4) & 1 and r.trip == Trip.ESTOP
    assert r.release_stopped == (-1, "") and r.venting
