"""The controller catches its own sensor, valve and supply faults (real plant, faults injected).

Each fault kind is injected while holding at home, in the middle of a pitch exercise and
while the patient pushes. What is asserted is what the supervision achieves today, fault by
fault; the faults it does not catch yet are listed with the harm they do (the README's fault
table says the same), so a change that loses a detection, or makes an undetected fault
harmful, fails here.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from device import controller as ctl
from device import supervision, trips
from device.axes import AXES
from device.calibration import Calibration
from device.hardware import SimulatedHardware
from device.plant.faults import Fault, FaultKind
from device.plant.model import SCRIPT_RAMP
from device.plant.params import PlantConfig, draw_plant
from device.rig import Rig
from device.supervision import SupervisionConfig
from device.supervision import build as build_supervision
from device.tickloop import COL
from device.trips import Trip
from lab import experiments as ex
from lab import safety
from sessions.prescription import ExerciseKind

DETECTED: dict[FaultKind, tuple[str, float]] = {
    # kind: (trip reported, worst detection time in ms over the three situations)
    FaultKind.SUPPLY_LOSS: (Trip.SUPPLY_LOSS.name, 50.0),
    FaultKind.PRESSURE_OPEN: (Trip.PRESSURE_SENSOR.name, 5.0),
    FaultKind.PRESSURE_SHORT: (Trip.PRESSURE_SENSOR.name, 5.0),
    FaultKind.PRESSURE_STUCK: (Trip.PRESSURE_SENSOR.name, 50.0),
    FaultKind.PRESSURE_OFFSET: (Trip.PRESSURE_SENSOR.name, 5.0),
    FaultKind.LEG_OFFSET: (Trip.LEG_SENSOR.name, 5.0),
    FaultKind.LEG_NOISE: (Trip.LEG_SENSOR.name, 50.0),
    FaultKind.FT_DEAD: (Trip.FORCE_SENSOR.name, 50.0),
    FaultKind.FT_SATURATED: (Trip.FORCE_SENSOR.name, 5.0),
}
"""(A force/torque offset: the matrix's 30 N is under both rules that catch one at once;
the tests below take a jump and a creep.)"""

WATCH_S = 2.0
"""How long the runs below watch an injected fault: the benchmark's 0.5 s hides what the
faults it does not catch do over the next second."""

STILL_AT_REST = {(FaultKind.PRESSURE_STUCK, "holding"): 250.0}
"""Held at home the legs rest on their trapped air with every valve shut (device.quiet): a
transducer that stops there reads what the chamber still holds, and only its missing noise
tells it from a live one. It is named once its reading has stood still longer than the
unit's noise lets a live one's (``Calibration.pressure_still_reads``: 148-206 reads on the
nominal unit; measured 125-207 ms). Before, nothing told it until the leg was driven again."""


@pytest.mark.parametrize("scenario", safety.SCENARIOS)
@pytest.mark.parametrize("kind", list(DETECTED), ids=lambda k: k.name)
def test_a_sensor_or_supply_fault_trips_at_once_and_the_platform_stays(
    kind: FaultKind, scenario: str
) -> None:
    run = safety.run_fault(kind, scenario)
    trip, within_ms = DETECTED[kind]
    within_ms = STILL_AT_REST.get((kind, scenario), within_ms)
    assert run.detected and run.trip == trip, run
    assert run.detect_ms <= within_ms, run
    assert run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run


@pytest.mark.parametrize(
    ("kind", "channels", "trip"),
    [
        (FaultKind.PRESSURE_OPEN, range(13), Trip.PRESSURE_SENSOR),
        (FaultKind.PRESSURE_STUCK, range(12), Trip.PRESSURE_SENSOR),
        (FaultKind.LEG_OFFSET, range(6), Trip.LEG_SENSOR),
    ],
    ids=lambda v: getattr(v, "name", ""),
)
def test_every_channel_is_watched_and_named(kind: FaultKind, channels: range, trip: Trip) -> None:
    """Not only the channel of the matrix: every transducer, every leg, mid-exercise."""
    for channel in channels:
        run = safety.run_fault(kind, "exercise", seed=channel + 2, channel=channel)
        assert run.detected and run.trip == trip.name and run.channel == channel, run
        # 1.5 mm: measured up to 1.05 mm on the plant with tube delays (1.0 before), within
        # the fault benchmark's 3 mm.
        assert run.detect_ms <= 50.0 and run.excursion_mm <= 1.5, run


@pytest.mark.parametrize("scenario", safety.SCENARIOS)
def test_one_force_torque_channel_dead_alone_is_named(scenario: str) -> None:
    """The matrix kills the whole sensor; one channel alone reading zero (its wire off) was
    named only where it carried a load (force along z, pitch while pushing): the others
    read a live channel's near-zero and were never named. Its missing noise names it once
    its reading has stood still longer than the unit's noise lets a live one's
    (``Calibration.ft_still_reads``)."""
    for channel in range(6):
        run = safety.run_fault(FaultKind.FT_DEAD, scenario, seed=channel + 2, channel=channel)
        assert run.detected and run.trip == Trip.FORCE_SENSOR.name, run
        assert run.channel == channel, run
        assert run.detect_ms <= 100.0, run
        assert run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run


def test_a_drooping_supply_holds_the_exercise_before_it_can_no_longer_carry_the_foot() -> None:
    for scenario in safety.SCENARIOS:
        # A regulator droops under flow: it takes 0.44-0.48 s to reach the low mark (475 ms
        # held at rest, with the valves shut); the run is watched, and the detection timed,
        # from there.
        run = safety.run_fault(FaultKind.SUPPLY_DROOP, scenario)
        assert run.detected and run.trip == "SUPPLY_LOW (hold)", run
        # From the regulator's output crossing the low mark: 32-40 ms measured.
        assert run.detect_ms <= 50.0, run
        # Held as the service holds it (every valve shut): measured 0.31 deg and 0.43 mm.
        assert run.excursion_deg <= 1.0 and run.excursion_mm <= 1.0, run


OPEN_SINCE_THE_HONEST_PLANT = (
    "open (issue 12): on the plant with sensor latency, tube delays and leaks, and with the "
    "outer-loop integral, the platform moves further before this fault is caught"
)


@pytest.mark.parametrize(
    ("exercise", "chamber", "bar"),
    [
        # What each was named before the force balance judged a leg that carries the
        # residual alone: the leg's length sensor at 759 ms; the force/torque sensor
        # ("torque about roll") at 1,270 ms; the chamber's air at once, then the leg's length
        # sensor at 1,526 ms; the force/torque sensor at 1,638 ms.
        (ExerciseKind.ISOMETRIC, 7, 0.3),
        (ExerciseKind.ROM_ASSESSMENT, 2, 0.3),
        (ExerciseKind.STRENGTH, 2, 0.3),
        (ExerciseKind.PASSIVE_ROM, 4, -0.45),
    ],
    ids=lambda v: str(getattr(v, "value", v)),
)
def test_a_transducer_a_little_off_is_named_on_its_own_leg(
    exercise: ExerciseKind, chamber: int, bar: float
) -> None:
    """A pressure transducer 0.3-0.45 bar off: under the jump rule (0.8 bar a read) and the
    30 N force-balance limit (12-20 N on its leg), which the position loop's integral makes
    up while the leg stands on its target. Its leg alone carries the force balance's
    residual; that names the leg's forces (its transducers, valves, tubes), not the
    force/torque sensor nor the leg's length sensor. Measured over 600 such runs (0.3 bar
    either way on five chambers, six exercises, the nominal unit and four drawn builds):
    326 tripped FORCE_BALANCE on the leg, 274 were flagged by the chamber's air, none named
    another part; first named in 88 ms at the median and 372 ms at worst."""
    rig = safety._rig("relaxed", 1)
    safety.start_exercise(rig, exercise)
    rig.run(3.0, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.PRESSURE_OFFSET, float(hw.state.time[0]), chamber, bar))
    t0 = rig.time
    named_s = math.nan
    leg = chamber // 2
    while rig.trip == Trip.NONE and rig.time - t0 < 1.5:
        rig.run(0.004, log_hz=0)
        if math.isnan(named_s) and (rig.trip != Trip.NONE or rig.service_chamber >= 0):
            named_s = rig.time - t0
    # Named within 0.5 s: a FORCE_BALANCE trip on its leg, or first the chamber's air (the
    # offset's step reads as air that came from nowhere: a service warning on that chamber,
    # the loop holding its leg while the segment finishes), and no other trip after.
    assert named_s <= 0.5, named_s
    assert rig.trip in (Trip.NONE, Trip.FORCE_BALANCE), (rig.trip, rig.trip_channel)
    if rig.trip == Trip.FORCE_BALANCE:
        assert rig.trip_channel == leg and trips.where(int(rig.trip), leg) == f"leg {leg + 1}"
    else:
        assert rig.service_chamber == chamber, rig.service_chamber


@pytest.mark.parametrize("scenario", ["exercise", "pushing"])
def test_a_stuck_leg_sensor_is_caught_once_the_leg_is_driven(scenario: str) -> None:
    """Leg 2 (the matrix's default). Measured: 107-179 ms, at most 1.04 deg and 2.62 mm
    (pushing); with the error rule at 1 mm (leg_stuck_error) it was 151-227 ms and up to
    1.95 deg and 4.71 mm."""
    run = safety.run_fault(FaultKind.LEG_STUCK, scenario)
    assert run.detected and run.trip == Trip.LEG_SENSOR.name and run.channel == 2, run
    assert run.detect_ms <= 250.0 and run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run


@pytest.mark.parametrize("leg", range(6))
def test_a_stuck_leg_sensor_mid_exercise_is_caught_on_every_leg(leg: int) -> None:
    """The target runs away from the frozen reading as the pitch sine goes on. Measured:
    123-199 ms on legs 2-5 and 435-459 ms on legs 0 and 1, whose length pitch hardly
    changes; at most 1.18 deg and 2.80 mm (leg 4). With the error rule at 1 mm, legs 0 and
    1 went unseen within 0.5 s and leg 4 moved the platform 5.19 mm."""
    run = safety.run_fault(FaultKind.LEG_STUCK, "exercise", channel=leg)
    assert run.detected and run.trip == Trip.LEG_SENSOR.name and run.channel == leg, run
    assert run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run


@pytest.mark.parametrize(("leg", "mm"), [(0, 10.0), (1, 10.0), (0, -10.0), (3, 3.0)])
def test_a_leg_sensor_frozen_at_rest_is_named_when_its_leg_is_stepped(leg: int, mm: float) -> None:
    """Frozen while the platform rests, then its leg is stepped: the model's platform stands
    where the frozen reading puts it, and the sideways force check tripped first (18 ms into
    the step), naming the force plate (force along x). The trip now names the leg."""
    with ex.injected((Fault(FaultKind.LEG_STUCK, 0.0, leg),)):
        r = ex.step(leg=leg + 1, mm=mm)
    assert r.health.trip == Trip.LEG_SENSOR.name and r.health.part == f"leg {leg + 1}", r.health


@pytest.mark.parametrize(
    ("channel", "value", "part"),
    [
        (0, 80.0, "force along x"),
        (1, -80.0, "force along y"),
        (2, -80.0, "force along z"),
        (3, 8.0, "torque about roll"),
        (4, -8.0, "torque about pitch"),
        (5, 8.0, "torque about yaw"),
    ],
)
def test_an_offset_on_any_force_sensor_channel_is_caught_by_the_six_legs_together(
    channel: int, value: float, part: str
) -> None:
    """An offset that creeps in (eight steps 10 ms apart, each under the jump rule): each leg
    carries a share too small for its own balance check; summed as a wrench at the ankle
    the legs disagree with the sensor, and the trip names the component."""
    import dataclasses

    from device.controller import ControllerConfig
    from device.rig import Rig

    default = ControllerConfig()
    # The cross-check alone: on an axis the platform holds, the following check may stop a
    # creeping force offset first (by the motion it causes); both ways are asserted.
    blind = dataclasses.replace(
        default.supervision, following_translation=math.inf, following_rotation=math.inf
    )
    caught = {}
    for name, config in (
        ("cross-check", dataclasses.replace(default, supervision=blind)),
        ("device", default),
    ):
        rig = Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=channel + 3), config)
        safety._start(rig, "exercise")
        rig.run(0.5, log_hz=0)
        hw = rig.hardware
        assert isinstance(hw, SimulatedHardware)
        t0 = float(hw.state.time[0])
        for step in range(8):
            hw.inject(Fault(FaultKind.FT_OFFSET, t0 + 0.01 * step, channel, value / 8))
        rig.run(0.3, log_hz=0)
        caught[name] = (rig.trip, trips.where(rig.trip, rig.trip_channel))
    assert caught["cross-check"] == (Trip.FORCE_SENSOR, part), caught
    assert caught["device"][0] in (Trip.FORCE_SENSOR, Trip.FOLLOWING), caught


@pytest.mark.parametrize("calibrated", [True, False])
def test_an_offset_the_vertical_allowance_forgives_is_not_mistaken_for_a_fault(
    calibrated: bool,
) -> None:
    """The other side of the threshold: 10 N on Fz either way (the vertical check's floor)
    acts like a patient pushing 10 N, on the unit with and without its load bias; 20 N was
    named in 2 of 4 runs on the calibrated one (held and mid-exercise, either way)."""
    for scenario in ("holding", "exercise"):
        for newtons in (10.0, -10.0):
            rig = _force_offset(scenario, 2, newtons, 0.5, calibrated=calibrated)
            assert rig.trip == Trip.NONE, (scenario, newtons, rig.trip)


@pytest.mark.parametrize("scenario", safety.SCENARIOS)
def test_a_vertical_force_sensor_offset_is_caught_by_the_vertical_cross_check(
    scenario: str,
) -> None:
    """30 N on Fz acts like a foot pushing down 30 N, under the wrench cross-check's 45 N:
    it went unnamed in every situation. With the unit's load bias taken out of the legs'
    residual (the plate's true weight, the transducers' spans), what is left vertically is
    the sensor's error beside the seals' friction: named in 22-56 ms (56 as the legs settled,
    the check not yet armed at 0.1 s; 28 since it arms at 40 ms), the platform 0.3-1 mm off."""
    run = safety.run_fault(FaultKind.FT_OFFSET, scenario, channel=2)
    assert run.detected and run.trip == Trip.FORCE_SENSOR.name and run.channel == 2, run
    assert run.detect_ms <= 80.0 and run.excursion_mm <= 2.0, run


AIR_FAULTS = (FaultKind.VALVE_STUCK_OPEN, FaultKind.VALVE_STUCK_CLOSED, FaultKind.CHAMBER_LEAK)


@pytest.mark.parametrize("kind", AIR_FAULTS, ids=lambda k: k.name)
def test_a_leak_or_a_stuck_valve_is_caught_by_the_chambers_air(kind: FaultKind) -> None:
    """The loop holds the leg (the other chamber, or more air, makes up for it), so the
    chamber's air balance gives it away: a service warning naming the chamber (or a VALVE
    trip when a valve driven hard moved nothing), and the platform stays where it should."""
    caught = 0
    for scenario in safety.SCENARIOS:
        run = safety.run_fault(kind, scenario)
        # Measured: a stuck-open intake while holding tilts the platform 1.17 deg and moves
        # it 1.39 mm from where the run without the fault was at its VALVE trip, its exhaust
        # bleeding it (2.20 mm with every valve closed): the issue's bound is 2 deg and 3 mm.
        assert run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run
        if run.detected:
            caught += 1
            assert run.trip in ("AIR_BALANCE (service)", Trip.VALVE.name), run
            assert run.channel == 4 and run.detect_ms <= 500.0, run
        else:
            assert run.trip == Trip.NONE.name, run
    # Measured on the calibrated unit, whose air checks know each valve's pulse: a
    # stuck-open intake and a 0.5 C leak are named everywhere (7-23 ms), a stuck-closed
    # exhaust wherever the loop tells it to open (25-39 ms; held at home it never is).
    least = {FaultKind.VALVE_STUCK_OPEN: 3, FaultKind.CHAMBER_LEAK: 3}.get(kind, 2)
    assert caught >= least, kind


_UNTESTED_VALVES = Calibration().valve_figures()
"""Gains, extra times and pulse edges of valves the start-up test did not measure."""


def _air_window(cap: tuple[int, float], rod: tuple[int, float]) -> int:
    """One air-balance window of leg 0, whose chambers' valves are driven ``slots`` every
    period and whose measured air follows ``share`` of what those slots are figured to move
    (the piston still, the volume standing in for the air); what check_air names at its
    end (-1: nothing)."""
    from device import supervision

    q = Rig(SimulatedHardware()).params.sup
    counters = np.zeros(supervision.N_COUNTERS, dtype=np.int64)
    monitor = np.zeros(supervision.N_MONITOR)
    supply, pressure = 6.0e5, 3.0e5  # gauge: both ways are far from their ends
    named = -1
    for period in range(q.air_window + 1):
        for c, (slots, share) in enumerate((cap, rod)):
            figured = math.copysign(max(0, abs(slots) - q.air_open_after) * q.air_per_slot, slots)
            volume = 1.0e-4 + share * figured * period / (pressure + q.atm)
            found = supervision.check_air(
                monitor, counters, c, slots, pressure, volume, supply, q, _UNTESTED_VALVES
            )
            assert found == -1 or period == q.air_window, (period, c)
            named = max(named, int(found))
    return named


def test_a_pulse_is_read_by_where_its_valve_starts_to_open() -> None:
    """A valve the start-up test left shut up to 0.7 ms and opened every time from 0.9 ms:
    a shorter pulse is expected to pass nothing, a longer one its line's worth (length plus
    the extra time), and one near the edges either, half of it give or take that half. A
    valve not tested is read by its line alone."""
    from device import supervision

    q = Rig(SimulatedHardware()).params.sup
    margin = q.obs_edge_margin
    extra, shut, opens = -0.2e-3, 0.7e-3, 0.9e-3
    assert supervision.pulse_seconds(0.5e-3, extra, shut, opens, q) == (0.0, 0.0)
    assert supervision.pulse_seconds(1.2e-3, extra, shut, opens, q) == pytest.approx((1e-3, 0.0))
    for near in (shut - 0.5 * margin, 0.8e-3, opens + 0.5 * margin):
        expected, unsure = supervision.pulse_seconds(near, extra, shut, opens, q)
        assert expected == pytest.approx(0.5 * (near + extra)) and unsure == expected
    assert supervision.pulse_seconds(0.5e-3, extra, 0.0, 0.0, q) == pytest.approx((0.3e-3, 0.0))
    assert supervision.pulse_seconds(0.1e-3, extra, 0.0, 0.0, q) == (0.0, 0.0)


def test_near_the_supply_the_expected_flow_forgives_the_transducers_spans() -> None:
    """An intake held open a period: while it is choked, the transducers' span errors move
    its flow by about their own share; a chamber 0.14 bar under the supply, whose flow hangs
    on the difference of two readings, by most of it (measured: 85 %)."""
    from device import supervision

    q = Rig(SimulatedHardware()).params.sup
    supply = 6.87e5
    choked, unsure, _ = supervision.pulse_air(0, 28, 3.0e5, supply, q, _UNTESTED_VALVES)
    assert 0.0 < unsure <= 1.5 * q.obs_span * choked
    near, unsure, _ = supervision.pulse_air(0, 28, supply - 0.14e5, supply, q, _UNTESTED_VALVES)
    assert 0.0 < near < 0.5 * choked and unsure >= 0.75 * near


def test_the_air_balance_judges_a_legs_two_chambers_together() -> None:
    """A chamber that fell short of its valves is named only when its mirror, driven the
    other way, did not fall short as well (both short: the leg's valves pass less than the
    figure, or air crossed the piston) or when its own air went against its valves."""
    assert _air_window((20, 1.0), (-20, 1.0)) == -1  # all adds up
    assert _air_window((20, 0.1), (-20, 0.9)) == 0  # a leak to the room, a valve stuck shut
    assert _air_window((20, 0.9), (-20, 0.05)) == 1
    assert _air_window((20, 0.1), (-20, 0.1)) == -1  # mirrors both short: the valves
    assert _air_window((20, -0.2), (-20, 0.1)) == 0  # against its valves: its own fault
    assert _air_window((20, 0.1), (-20, -0.3)) == 1  # both short: the one further against
    assert _air_window((20, 0.1), (0, 0.0)) == 0  # no mirror to ask
    assert _air_window((20, 0.1), (20, 0.1)) == 0  # both filling: not mirrors
    assert _air_window((7, 0.0), (-7, 1.0)) == -1  # minimum pulses: too little air to judge
    assert _air_window((9, 0.0), (-9, 1.0)) == 0  # 3 Pa m3 figured, none of it came


def test_the_air_balance_counts_a_pulse_near_its_valves_opening_delay_both_ways() -> None:
    """Valves whose pulses open them from 0.9 ms on and leave them shut up to 0.7 ms: a
    cap side told every other period to take in 10 slots (1.4 ms, surely open) and to let
    out 6 (0.86 ms, either), whose air stays where it was. Counted by what is sure alone
    the window is one-sided and the chamber short of it; the exhaust pulses may have let
    out as much as the intakes brought, and the window is not judged. The same intakes
    alone, the air still not following, name the chamber."""
    from device import supervision

    q = Rig(SimulatedHardware()).params.sup
    tested = np.array([np.ones(24), np.zeros(24), np.full(24, 0.7e-3), np.full(24, 0.9e-3)])

    def window(pattern: tuple[int, int]) -> int:
        counters = np.zeros(supervision.N_COUNTERS, dtype=np.int64)
        monitor = np.zeros(supervision.N_MONITOR)
        named = -1
        for period in range(q.air_window + 1):
            slots = pattern[period % 2]
            for c, driven in ((0, slots), (1, 0)):  # the rod side undriven: no mirror
                found = supervision.check_air(
                    monitor, counters, c, driven, 3.0e5, 1.0e-4, 6.0e5, q, tested
                )
                named = max(named, int(found))
        return named

    assert window((10, -6)) == -1
    assert window((10, 0)) == 0


def test_a_leak_that_drags_its_mirror_short_is_named_itself() -> None:
    """Half a valve's leak from rod chamber 5, injected 0.37 s later in the pitch exercise
    than the fault matrix does: at the second window's end the cap's exhaust had moved 0.01
    of its figure and the leaking rod's intake -0.47, and the cap, asked first, was named
    (the unit without its calibration, where this was found)."""
    rig = safety._rig("relaxed", 1, calibrated=False)
    safety._start(rig, "exercise")
    rig.run(0.87, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.CHAMBER_LEAK, float(hw.state.time[0]), 5, 0.5, math.inf))
    rig.run(0.5, log_hz=0)
    assert rig.service_chamber == 5 and rig.trip == Trip.NONE, (rig.service_chamber, rig.trip)


def test_a_leg_whose_slow_valves_dither_both_chambers_is_not_taken_for_a_leak() -> None:
    """Drawn build 8 (the ensemble's slowest valves), a passive range-of-motion exercise
    against a resisting foot (the leg step's friction fed forward): a leg's chambers
    dithered in turns (cap in 8 slots, out 14, the rod its mirror) and each window fell
    short of the rough figure on both sides, which named the cap as leaking at 8.05 s."""
    from lab.experiments import calibration_of
    from lab.safety import start_exercise
    from sessions.prescription import ExerciseKind

    plant = draw_plant(8, "resisting")
    config = ctl.ControllerConfig(calibration=calibration_of(plant))
    rig = Rig(SimulatedHardware(plant, seed=8), config=config)
    start_exercise(rig, ExerciseKind("passive_rom"))
    rig.run(9.0 - rig.time, log_hz=0)
    assert rig.service_chamber == -1 and rig.trip == Trip.NONE, (rig.service_chamber, rig.trip)


def test_an_exhaust_stuck_open_while_holding_is_held_not_let_run() -> None:
    """Every exhaust. The legs rest on shut chambers, so the air leaving shows at once; told
    to take it back in, the chamber lost it (or stalled). Tripping there closed every valve
    and left the open exhaust alone to move the leg: valve 11, 13.5 mm and 11.4 deg within
    0.5 s. It is a service warning, and the loop outruns the leak; where the following
    check trips first (valve 3 on this seed: 34 ms, before the air checks had named the
    chamber, 9.6 deg and 15.5 mm with every valve shut), the chamber's own intake holds it
    at its pressure at the trip (the test after next). Measured: every exhaust named within
    21 ms, the platform at most 1.03 deg and 1.63 mm off."""
    for valve in range(1, 24, 2):
        run = safety.run_fault(FaultKind.VALVE_STUCK_OPEN, "holding", channel=valve)
        assert run.detected and run.detect_ms <= 50.0, run
        if run.trip == "AIR_BALANCE (service)":
            assert run.channel == valve // 2, run
        else:
            rig, *_ = safety._run(FaultKind.VALVE_STUCK_OPEN, "holding", 1, valve)
            assert rig.state.istate[ctl.I_BLEED] == ctl.HOLD_FEED + valve // 2, run
        assert run.excursion_deg <= 1.5 and run.excursion_mm <= 2.5, run


def _holding_with(
    supervision: SupervisionConfig, valve: int, calibrated: bool = True
) -> tuple[Rig, safety.FaultRun]:
    """Valve ``valve`` stuck open while holding, on a device with these thresholds: the rig
    0.5 s after the fault, and the run watched for 2 s."""

    unit, config = safety._rig, ctl.ControllerConfig(supervision=supervision)

    def rig(patient: str, seed: int, calibrated: bool = True) -> Rig:
        return unit(patient, seed, calibrated, config)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(safety, "_rig", rig)
        r, *_ = safety._run(FaultKind.VALVE_STUCK_OPEN, "holding", 1, valve, calibrated=calibrated)
        run = safety.run_fault(
            FaultKind.VALVE_STUCK_OPEN, "holding", channel=valve, after=2.0, calibrated=calibrated
        )
    return r, run


def test_a_leak_that_wakes_a_resting_leg_is_named_by_the_air_and_the_drift_together() -> None:
    """Valve 15 stuck open while holding: leg 3 rested 0.15 mm off its target (where the
    approach's fed friction left it) and drifted out of its rest at 0.5 mm, 20 ms in, while
    its rod chamber's air had been over the observer's tolerance for 2 periods (5 needed).
    The loop then holds the leg against the leak with 7-15 slot pulses the observer cannot
    tell from what the valve type's timing allows (0.8-1.0 of its tolerance): without the
    drift as a second witness the chamber is named only by the 0.2 s air windows, at the
    first window's end (201 ms; 1.2 s while only windows of 3 Pa m3 were judged). That is
    the unit without its calibration; with it, the observer knows each valve's own air per
    pulse and forgives less, and names the chamber in 21 ms with or without the drift."""
    run = safety.run_fault(FaultKind.VALVE_STUCK_OPEN, "holding", channel=15, calibrated=False)
    assert run.trip == "AIR_BALANCE (service)" and run.channel == 7, run
    assert run.detect_ms <= 50.0, run
    alone = SupervisionConfig(observer_wake_periods=SupervisionConfig().observer_periods)
    _, late = _holding_with(alone, 15, calibrated=False)
    assert late.trip == "AIR_BALANCE (service)" and late.detect_ms > 150.0, late
    assert late.excursion_deg <= 1.0 and late.excursion_mm <= 1.5, late


def test_an_exhaust_that_beats_the_air_checks_to_a_trip_is_held_by_its_intake() -> None:
    """Valve 3 stuck open while holding, on a device whose air checks see nothing (an
    observer that forgives everything, windows never judged): the leg leaves the following
    bound and the FOLLOWING trip closes every valve. With every valve shut the open exhaust
    alone moved the platform 9.6 deg and 15.5 mm (measured when the air checks lost this
    race to the trip); the chamber's own intake holds it at its trip pressure. (No valve is
    held to its own pulses either: the answer rule forgives everything too.)"""
    blind = SupervisionConfig(observer_floor=1.0e9, air_min_expected=1.0e9, answer_floor=1.0e9)
    r, run = _holding_with(blind, 3)
    assert run.trip == Trip.FOLLOWING.name and run.detect_ms <= 50.0, run
    assert r.state.istate[ctl.I_BLEED] == ctl.HOLD_FEED + 1
    assert r.state.valves[[v for v in range(24) if v != 2]].sum() == 0
    assert run.excursion_deg <= 1.5 and run.excursion_mm <= 2.5, run


@pytest.mark.parametrize("valve", [0, 12, 20])
def test_a_stuck_open_intake_is_bled_through_its_exhaust_after_the_trip(valve: int) -> None:
    """The three intakes that moved the platform most while holding. With every valve
    closed at the VALVE trip the supply filled the chamber through the stuck intake: 2.44,
    2.34 and 2.17 deg, 4.27, 4.40 and 3.22 mm. Its exhaust open while the chamber is above
    its pressure at the trip: 1.45, 1.00 and 1.44 deg, 2.35, 1.90 and 2.58 mm."""
    rig, _, detect, _, _ = safety._run(FaultKind.VALVE_STUCK_OPEN, "holding", 1, valve)
    c = valve // 2
    assert rig.trip == Trip.VALVE and rig.trip_channel == c and detect <= 0.05
    assert rig.state.istate[ctl.I_BLEED] == c
    assert rig.state.valves[0::2].sum() == 0, "an intake opened after the trip"
    others = [v for v in range(1, 24, 2) if v != 2 * c + 1]
    assert rig.state.valves[others].sum() == 0
    run = safety.run_fault(FaultKind.VALVE_STUCK_OPEN, "holding", channel=valve)
    assert run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run


def _bleed(
    istate: np.ndarray, pressure: np.ndarray, held: np.ndarray, air: np.ndarray, x: float
) -> np.ndarray:
    """One tick of ``ctl.bleed`` with every leg at ``x`` (m): the valves it opens."""
    valves = np.zeros(24, dtype=np.uint8)
    dead = np.full(12, 7.3e-6)
    area_cap, area_ann = 5.0e-4, 4.0e-4
    sup = build_supervision(SupervisionConfig(), 1.01325e5, 0.004)
    ctl.bleed(
        istate, pressure, held, valves, air, np.full(6, x), dead, area_cap, area_ann,
        0.1, 7.0e5 + 1.01325e5, sup,
    )  # fmt: skip
    return valves


def test_the_bleed_opens_only_the_tripped_chambers_exhaust_and_only_above_its_pressure() -> None:
    istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
    pressure = np.full(12, 3.0e5)
    held = np.full(12, 2.9e5)
    air = np.full(12, np.nan)
    istate[ctl.I_TRIP], istate[ctl.I_BLEED] = Trip.VALVE, 4
    assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == [9]
    assert held[4] == 2.9e5 and held[0] == 3.0e5  # the others held where they were
    pressure[4] = 2.9e5  # at the trip's pressure (a frozen reading stays there): shut
    assert not _bleed(istate, pressure, held, air, 0.05).any()


def test_a_chamber_held_both_ways_opens_one_valve_outside_its_band_and_none_inside() -> None:
    """``HOLD_BOTH`` (the loop's service chamber when the valves shut): its exhaust above the
    held pressure's band, its intake below it, neither within it (a reading's noise never
    makes the two take turns), and no intake on a supply transducer the trip named."""
    istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
    held = np.full(12, 3.0e5)
    air = np.full(12, np.nan)
    istate[ctl.I_TRIP], istate[ctl.I_TRIP_CHANNEL] = Trip.VALVE, 5
    istate[ctl.I_BLEED] = ctl.HOLD_BOTH + 5
    for offset, opened in (
        (0.0, []),
        (0.9 * ctl.HOLD_BAND, []),
        (-0.9 * ctl.HOLD_BAND, []),
        (1.1 * ctl.HOLD_BAND, [11]),
        (-1.1 * ctl.HOLD_BAND, [10]),
    ):
        pressure = np.full(12, 3.0e5)
        pressure[5] += offset
        assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == opened, offset
        air[:] = np.nan  # each call its first after the trip
        held[:] = 3.0e5
    istate[ctl.I_TRIP], istate[ctl.I_TRIP_CHANNEL] = Trip.PRESSURE_SENSOR, ctl.SUPPLY_CHANNEL
    pressure = np.full(12, 3.0e5)
    pressure[5] -= 2.0 * ctl.HOLD_BAND
    assert not _bleed(istate, pressure, held, air, 0.05).any()


@pytest.mark.parametrize(
    ("kind", "channel"),
    [
        (FaultKind.VALVE_STUCK_OPEN, 1),  # leg 1's cap-side exhaust
        (FaultKind.VALVE_STUCK_OPEN, 15),  # leg 4's rod-side exhaust
        (FaultKind.VALVE_STUCK_OPEN, 2),  # leg 1's rod-side intake
        (FaultKind.CHAMBER_LEAK, 4),
    ],
)
def test_the_loops_service_chamber_is_held_the_moment_the_valves_shut(
    kind: FaultKind, channel: int
) -> None:
    """A leak or a valve stuck open mid-exercise: the air checks name the chamber
    (``AIR_BALANCE``, a service warning) and the loop outruns it while the segment finishes.
    When the segment ends every valve shuts (READY), and the fault alone moved the leg: the
    shut-valve watch named it only after its first window, by which time an exhaust stuck
    open had let its leg sink 8.5-10.3 mm and the platform tilt 4.6-5.2 deg. Now the
    chamber is named (VALVE) on the first read with the valves shut and held by its own
    valves; the platform moves no more than a healthy one does as the exercise stops
    (0.2-0.45 deg, 0.4-0.7 mm, seeds 1-3)."""
    rig, *_ = safety._run(kind, "exercise", 1, channel, after=0.5)
    c = channel // 2 if kind == FaultKind.VALVE_STUCK_OPEN else channel
    before = rig.trip
    assert rig.service_chamber == c and before == Trip.NONE
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    start = hw.state.pose.copy()
    rig.hold()  # what the device's modes do when the segment ends
    rig.run(0.002, log_hz=0)
    assert rig.trip == Trip.VALVE and rig.trip_channel == c
    assert rig.state.istate[ctl.I_BLEED] == ctl.HOLD_BOTH + c
    moved = np.zeros(6)
    for _ in range(500):
        rig.run(0.002, log_hz=0)
        moved = np.maximum(moved, np.abs(hw.state.pose - start))
        others = [v for v in range(24) if v // 2 != c]
        assert rig.state.valves[others].sum() == 0
    assert math.degrees(moved[3:].max()) <= 1.2 and 1e3 * moved[:3].max() <= 1.5, moved


@pytest.mark.parametrize(
    ("kind", "channel"),
    [
        (FaultKind.VALVE_STUCK_OPEN, 7),  # leg 2's rod-side exhaust
        (FaultKind.VALVE_STUCK_OPEN, 14),  # leg 4's rod-side intake
        (FaultKind.CHAMBER_LEAK, 9),
    ],
)
def test_an_estop_holds_the_chamber_the_air_checks_named(kind: FaultKind, channel: int) -> None:
    """A leak or a valve stuck open mid-exercise, named by the air checks (the loop outruns
    it), then the patient presses the e-stop: every valve closed let the fault alone turn
    the platform 5.4-11.8 deg and drop it 7.6-17.1 mm in 2 s. The e-stop's event names the
    chamber, and its own valves hold it: the platform gives no more than a healthy one's
    e-stop there (0.36 deg, 0.41 mm) and the fault's worst (0.88 deg, 1.05 mm)."""
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind

    rig, *_ = safety._run(kind, "exercise", 1, channel, after=0.3)
    c = channel // 2 if kind == FaultKind.VALVE_STUCK_OPEN else channel
    before = rig.trip
    assert rig.service_chamber == c and before == Trip.NONE
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    start = hw.state.pose.copy()
    machine.estop()
    assert machine.mode == DeviceMode.ESTOP and events[-1][0] == EventKind.ESTOP
    part = trips.where(Trip.AIR_BALANCE, c)
    assert str(events[-1][5]).startswith(f"emergency stop; {part} held by its own valves")
    rig.run(0.002, log_hz=0)
    assert rig.trip == Trip.ESTOP
    assert rig.state.istate[ctl.I_BLEED] == ctl.HOLD_BOTH + c
    moved = np.zeros(6)
    opened = 0
    for _ in range(1000):
        rig.run(0.002, log_hz=0)
        moved = np.maximum(moved, np.abs(hw.state.pose - start))
        others = [v for v in range(24) if v // 2 != c]
        assert rig.state.valves[others].sum() == 0
        opened += int(rig.state.valves[2 * c : 2 * c + 2].sum())
    assert opened > 0, "the chamber's own valves never opened: the fault ran alone"
    assert math.degrees(moved[3:].max()) <= 1.2 and 1e3 * moved[:3].max() <= 1.5, moved


def test_an_estop_with_no_chamber_named_closes_every_valve() -> None:
    """Where nothing was named and nothing fails after, a healthy e-stop mid-exercise opens
    no valve afterwards, and its event says only that it stopped."""
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode

    rig, *_ = safety._run(None, "exercise", 1, after=0.3)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.estop()
    assert machine.mode == DeviceMode.ESTOP and events[-1][5] == "emergency stop"
    for _ in range(250):
        rig.run(0.002, log_hz=0)
        assert rig.state.valves.sum() == 0
    assert rig.state.istate[ctl.I_BLEED] == -1


@pytest.mark.parametrize(
    ("kind", "channel"),
    [
        (FaultKind.VALVE_STUCK_OPEN, 1),  # leg 1's cap-side exhaust
        (FaultKind.VALVE_STUCK_OPEN, 8),  # leg 3's cap-side intake
        (FaultKind.CHAMBER_LEAK, 4),
    ],
)
def test_a_valve_that_fails_after_an_estop_is_held_and_said(kind: FaultKind, channel: int) -> None:
    """The e-stop shut every valve; 0.3 s later a valve sticks open or a chamber starts to
    leak, with the patient's foot still on the plate. Left so, measured over 3 s at home:
    exhausts and leaks 8.2-15.1 deg and 14.4-20.2 mm, intakes 2.5-4.6 deg and 3.7-7.7 mm.
    The chamber is held by its own valves, as after any other trip, and an event names it
    for the technician."""
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind

    rig = safety._rig("relaxed", 1)
    safety._start(rig, "holding")
    rig.run(0.5, log_hz=0)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.estop()
    assert machine.mode == DeviceMode.ESTOP
    for _ in range(150):
        rig.run(0.002, log_hz=0)
        machine.step()
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    assert rig.held_chamber == -1 and not rig.state.valves.any()
    start = hw.state.pose.copy()
    value = 0.5 if kind == FaultKind.CHAMBER_LEAK else 0.0
    hw.inject(Fault(kind, float(hw.state.time[0]), channel, value))
    c = channel // 2 if kind == FaultKind.VALVE_STUCK_OPEN else channel
    moved = np.zeros(6)
    for _ in range(1500):
        rig.run(0.002, log_hz=0)
        machine.step()
        moved = np.maximum(moved, np.abs(hw.state.pose - start))
        others = [v for v in range(24) if v // 2 != c]
        assert rig.state.valves[others].sum() == 0
    assert machine.mode == DeviceMode.ESTOP and rig.trip == Trip.ESTOP
    assert rig.held_chamber == c
    said = [e for e in events if e[0] == EventKind.FAULT]
    assert len(said) == 1 and said[0][4] == float(c), events
    said_text = str(said[0][5])
    assert said_text.startswith(f"VALVE on {trips.where(Trip.VALVE, c)}: its air reading moved")
    assert math.degrees(moved[3:].max()) <= 2.0 and 1e3 * moved[:3].max() <= 3.0, moved


@pytest.mark.parametrize(
    ("kind", "channel", "trip"),
    [
        (FaultKind.FT_DEAD, -1, Trip.FORCE_SENSOR),
        (FaultKind.PRESSURE_STUCK, 4, Trip.PRESSURE_SENSOR),
    ],
)
def test_a_valve_that_fails_after_a_sensor_trip_is_held_and_said(
    kind: FaultKind, channel: int, trip: Trip
) -> None:
    """A sensor fails mid-exercise and trips; 0.5 s later leg 4's rod-side exhaust sticks
    open. The faulty sensor stayed faulty, and each read that named it again was dropped
    whole: every reading froze at the trip, the hold never saw the chamber empty, and the
    platform turned 14.5-14.6 deg and moved 19-19.6 mm with no event (a 10 deg, 0.5 Hz pitch
    sine). The readings of the
    sensors still believed are taken after the trip: the chamber is held by its intake, as
    after an e-stop, and named in 12 ms; the platform moves at most 0.68 deg and 0.87 mm
    over 2 s."""
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind

    rig, *_ = safety._run(kind, "exercise", 1, channel, after=0.5)
    assert rig.trip == trip and rig.held_chamber == -1, rig.trip
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.step()
    assert machine.mode == DeviceMode.FAULT
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    start = hw.state.pose.copy()
    hw.inject(Fault(FaultKind.VALVE_STUCK_OPEN, float(hw.state.time[0]), 15, 0.0))
    moved = np.zeros(6)
    for _ in range(1000):
        rig.run(0.002, log_hz=0)
        machine.step()
        moved = np.maximum(moved, np.abs(hw.state.pose - start))
    assert rig.trip == trip and rig.held_chamber == 7
    said = [e for e in events if e[0] == EventKind.FAULT and e[3] == Trip.VALVE]
    assert len(said) == 1 and said[0][4] == 7.0, events
    assert math.degrees(moved[3:].max()) <= 1.0 and 1e3 * moved[:3].max() <= 1.5, moved


@pytest.mark.parametrize(
    ("kind", "channel", "value"),
    [
        (FaultKind.CHAMBER_LEAK, 7, 0.2),
        (FaultKind.VALVE_STUCK_OPEN, 15, 0.0),
        (FaultKind.CHAMBER_LEAK, 6, 0.2),
    ],
)
def test_a_chamber_that_fails_after_its_legs_sensor_tripped_is_named_and_held(
    kind: FaultKind, channel: int, value: float
) -> None:
    """Leg 4's length sensor is 3 mm off mid-exercise and trips LEG_SENSOR; 0.2 s later one
    of its chambers leaks or its exhaust sticks open. Both its chambers were skipped by the
    hold after the trip (their air needs the leg's length): never named, the platform turned
    10-14 deg and moved 17-22 mm. Their two pressures say how far the leg moved each on its
    own, and a chamber losing air says the other way: named, and held by its intake."""
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind

    rig, *_ = safety._run(FaultKind.LEG_OFFSET, "exercise", 1, 3, after=0.2)
    assert rig.trip == Trip.LEG_SENSOR and rig.trip_channel == 3, rig.trip
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.step()
    assert machine.mode == DeviceMode.FAULT
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    start = hw.state.pose.copy()
    hw.inject(Fault(kind, float(hw.state.time[0]), channel, value))
    moved = np.zeros(6)
    for _ in range(400):
        rig.run(0.002, log_hz=0)
        machine.step()
        moved = np.maximum(moved, np.abs(hw.state.pose - start))
    chamber = channel // 2 if kind == FaultKind.VALVE_STUCK_OPEN else channel
    assert rig.held_chambers == [chamber], rig.held_chambers
    said = [e for e in events if e[0] == EventKind.FAULT and e[3] == Trip.VALVE]
    assert len(said) == 1 and said[0][4] == float(chamber), events
    assert math.degrees(moved[3:].max()) <= 2.0 and 1e3 * moved[:3].max() <= 3.0, moved


def test_after_a_supply_loss_nothing_feeds_and_the_event_says_so() -> None:
    """The supply is lost mid-exercise (SUPPLY_LOSS); 0.3 s later chamber 4 leaks. The hold
    named it with "its own valves hold it", and its intake was to feed it from what was left
    in the supply's line: no intake can hold a chamber without a supply (the platform turns
    13.4 deg either way). Its event says nothing can hold it, and no intake opens."""
    from device.modes import ModeMachine
    from device.protocol.messages import EventKind

    rig, *_ = safety._run(FaultKind.SUPPLY_LOSS, "exercise", 1, after=0.3)
    assert rig.trip == Trip.SUPPLY_LOSS, rig.trip
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.step()
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.CHAMBER_LEAK, float(hw.state.time[0]), 3, 0.3))
    opened = 0
    for _ in range(500):
        rig.run(0.001, log_hz=0)
        machine.step()
        opened |= int(rig.state.valves[0::2].any())
    assert rig.held_chambers == [3], rig.held_chambers
    said = [e for e in events if e[0] == EventKind.FAULT and e[3] == Trip.VALVE]
    assert len(said) == 1 and said[0][4] == 3.0, events
    assert "nothing can hold it" in str(said[0][5]), said
    assert not opened


def test_two_valves_stuck_open_on_two_legs_are_each_held_and_said() -> None:
    """Leg 3's cap-side and leg 4's rod-side exhausts stick open together mid-exercise: the
    air checks name chamber 5, the air of two legs trips SUPPLY_LOSS, and the hold after it
    kept one chamber: chamber 5 was held, chamber 8 emptied and the platform turned 12 deg
    in pitch and 15 in yaw within 0.25 s (a 10 deg, 0.5 Hz pitch sine). Each chamber whose
    air moves with every valve shut is held by its own valves and named by its own event:
    at most 0.39 deg and 1.12 mm from where the trip stopped it over 1.5 s."""
    from device.modes import ModeMachine
    from device.protocol.messages import EventKind

    rig = safety._rig("relaxed", 1)
    safety._start(rig, "exercise")
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    start = hw.state.pose.copy()
    for valve in (8, 15):
        hw.inject(Fault(FaultKind.VALVE_STUCK_OPEN, float(hw.state.time[0]), valve, 0.0))
    moved = np.zeros(6)
    for _ in range(750):
        rig.run(0.002, log_hz=0)
        machine.step()
        if rig.trip != Trip.NONE:
            moved = np.maximum(moved, np.abs(hw.state.pose - start))
        else:
            start = hw.state.pose.copy()
    assert rig.trip != Trip.NONE
    said = [float(str(e[4])) for e in events if e[0] == EventKind.FAULT and e[3] == Trip.VALVE]
    assert sorted(said) == [4.0, 7.0], events
    assert sorted(rig.held_chambers) == [4, 7], rig.held_chambers
    assert math.degrees(moved[3:].max()) <= 2.0 and 1e3 * moved[:3].max() <= 3.0, moved


def test_homing_with_a_leaking_chamber_ends_in_a_valve_fault_that_holds_it() -> None:
    """A leak of half a valve's conductance on chamber 5 struck while homing lifted the
    platform off its stops: the air checks name it (SERVICE), homing finishes under control,
    and as it ends (every valve shut) the same chamber is named by a VALVE fault and held
    by its own valves. Before, the leak alone sank its leg over the shut-valve watch's
    first window: 3.0-3.6 deg and 4.8-6.8 mm from the homed pose."""
    from device.identify import lower_and_vent
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode, EventKind

    hw = SimulatedHardware(PlantConfig(patient="relaxed"), seed=1)
    lower_and_vent(hw)
    rig = Rig(hw, safety._rig("relaxed", 1).config)
    rig.run(1.0, log_hz=0)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.arm_home()
    rig.run(1.0, log_hz=0)
    hw.inject(Fault(FaultKind.CHAMBER_LEAK, float(hw.state.time[0]), 4, 0.5))
    homed: np.ndarray | None = None
    moved = 0.0
    for _ in range(3000):
        rig.run(0.001, log_hz=0)
        machine.step()
        if homed is None and machine.mode != DeviceMode.HOMING:
            homed = hw.state.pose.copy()
        if homed is not None:
            moved = max(moved, float(np.abs(hw.state.pose - homed)[3:].max()))
        if machine.mode == DeviceMode.FAULT and homed is not None:
            break
    kinds = [e[0] for e in events]
    assert EventKind.SERVICE in kinds and EventKind.HOMED in kinds, events
    service = events[kinds.index(EventKind.SERVICE)]
    assert service[4] == 4.0 and "homing ends under control" in str(service[5]), service
    assert machine.mode == DeviceMode.FAULT and events[-1][0] == EventKind.FAULT, events[-2:]
    assert rig.trip == Trip.VALVE and rig.trip_channel == 4
    assert rig.state.istate[ctl.I_BLEED] == ctl.HOLD_BOTH + 4
    for _ in range(500):
        rig.run(0.002, log_hz=0)
        assert homed is not None
        moved = max(moved, float(np.abs(hw.state.pose - homed)[3:].max()))
    assert math.degrees(moved) <= 1.0, math.degrees(moved)


def test_after_any_trip_a_chamber_whose_air_moves_with_every_valve_shut_is_held() -> None:
    """An exhaust stuck open empties its chamber: its intake feeds it back to its pressure
    at the trip. A stuck intake fills it: its exhaust bleeds it. A leg that only sinks onto
    its air moves no air, nor does air a worn piston seal lets from one side to the other,
    a transducer named by the trip is never followed, and an e-stop is a trip like any
    other here."""
    for trip in (Trip.FOLLOWING, Trip.LEG_SPEED, Trip.ESTOP):
        istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
        istate[ctl.I_TRIP], istate[ctl.I_BLEED] = trip, -1
        pressure, held, air = np.full(12, 3.0e5), np.zeros(12), np.full(12, np.nan)
        assert not _bleed(istate, pressure, held, air, 0.05).any()  # records the trip
        # Every leg sinks 5 mm: the caps shrink and rise, the rod sides grow and fall, the
        # air in each the same.
        sunk = pressure.copy()
        for k in range(12):
            before = 7.3e-6 + (5.0e-4 * 0.05 if k % 2 == 0 else 4.0e-4 * 0.05)
            after = 7.3e-6 + (5.0e-4 * 0.045 if k % 2 == 0 else 4.0e-4 * 0.055)
            sunk[k] = (3.0e5 + 1.01325e5) * before / after - 1.01325e5
        assert not _bleed(istate, sunk, held, air, 0.045).any()
        assert istate[ctl.I_BLEED] == -1
        emptied = pressure.copy()
        emptied[3] = 1.5e5
        assert list(np.flatnonzero(_bleed(istate, emptied, held, air, 0.05))) == [6]
        assert istate[ctl.I_BLEED] == ctl.HOLD_FEED + 3
        emptied[3] = 3.0e5  # back at its pressure at the trip: shut
        assert not _bleed(istate, emptied, held, air, 0.05).any()
    istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
    istate[ctl.I_TRIP], istate[ctl.I_BLEED] = Trip.FOLLOWING, -1
    pressure, held, air = np.full(12, 3.0e5), np.zeros(12), np.full(12, np.nan)
    _bleed(istate, pressure, held, air, 0.05)
    pressure[8] = 4.5e5
    assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == [17]
    # A sensor the trip named is not followed: the leg's (its chambers' volumes are
    # unknown; leg 4 holds chambers 8 and 9), or the supply's (no intake feeds on it).
    for trip, channel, chamber, moved in (
        (Trip.LEG_SENSOR, 4, 8, 4.5e5),
        (Trip.PRESSURE_SENSOR, 12, 3, 1.5e5),
    ):
        istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
        istate[ctl.I_TRIP], istate[ctl.I_TRIP_CHANNEL], istate[ctl.I_BLEED] = (
            trip, channel, -1,
        )  # fmt: skip
        pressure, held, air = np.full(12, 3.0e5), np.zeros(12), np.full(12, np.nan)
        _bleed(istate, pressure, held, air, 0.05)
        pressure[chamber] = moved
        assert not _bleed(istate, pressure, held, air, 0.05).any(), (trip, channel)
    # Air past a piston: the rod side of leg 4 gains what its cap side loses (same volumes
    # here), the leg's sum unchanged: no valve of its own is to blame, none opens.
    istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
    istate[ctl.I_TRIP], istate[ctl.I_BLEED] = Trip.ESTOP, -1
    pressure, held, air = np.full(12, 3.0e5), np.zeros(12), np.full(12, np.nan)
    _bleed(istate, pressure, held, air, 0.05)
    areas = (5.0e-4 * 0.05, 4.0e-4 * 0.05)
    passed = 0.15 * (3.0e5 + 1.01325e5) * (7.3e-6 + areas[1])  # 15 % of the rod side's air
    pressure[9] += passed / (7.3e-6 + areas[1])
    pressure[8] -= passed / (7.3e-6 + areas[0])
    assert not _bleed(istate, pressure, held, air, 0.05).any()
    assert istate[ctl.I_BLEED] == -1
    pressure[8] = 3.0e5 + 1.5e5  # ...but the cap side filling too is air from outside
    assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == [17]
    istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
    istate[ctl.I_TRIP], istate[ctl.I_TRIP_CHANNEL], istate[ctl.I_BLEED] = (
        Trip.PRESSURE_SENSOR, 8, -1,
    )  # fmt: skip
    pressure, held, air = np.full(12, 3.0e5), np.zeros(12), np.full(12, np.nan)
    _bleed(istate, pressure, held, air, 0.05)
    pressure[8] = 4.5e5  # the named transducer drifting
    assert not _bleed(istate, pressure, held, air, 0.05).any()


def test_every_chamber_whose_air_moves_after_a_trip_is_held_by_its_own_valves() -> None:
    """Two faults on two legs: the first chamber found was the only one held, and the
    second's air ran on with every valve shut. Each is held, each by a valve of its own
    (``I_HELD_MORE`` beside ``I_BLEED``), and a chamber whose transducer is judged faulty
    after the trip is neither followed nor held."""
    istate = np.zeros(ctl.N_ISTATE, dtype=np.int64)
    istate[ctl.I_TRIP], istate[ctl.I_BLEED] = Trip.FOLLOWING, -1
    pressure, held, air = np.full(12, 3.0e5), np.zeros(12), np.full(12, np.nan)
    _bleed(istate, pressure, held, air, 0.05)  # records the trip
    pressure[3] = 1.5e5  # an exhaust stuck open
    assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == [6]
    assert istate[ctl.I_BLEED] == ctl.HOLD_FEED + 3
    pressure[8] = 4.5e5  # then an intake stuck open on another leg
    assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == [6, 17]
    assert istate[ctl.I_BLEED] == ctl.HOLD_FEED + 3
    assert istate[ctl.I_HELD_MORE] == 1 << 8
    pressure[10] = 1.5e5  # and a third
    assert list(np.flatnonzero(_bleed(istate, pressure, held, air, 0.05))) == [6, 17, 20]
    pressure[3], pressure[8], pressure[10] = 3.0e5, 3.0e5, 3.0e5  # each back: all shut
    assert not _bleed(istate, pressure, held, air, 0.05).any()
    pressure[8] = 4.5e5
    istate[ctl.I_BAD_SENSORS] = 1 << 8  # its transducer judged faulty since
    assert not _bleed(istate, pressure, held, air, 0.05).any()
    pressure[1] = 1.5e5  # nor is a chamber on a leg sensor judged faulty followed
    istate[ctl.I_BAD_SENSORS] |= 1 << 13
    assert not _bleed(istate, pressure, held, air, 0.05).any()


@pytest.mark.parametrize("scenario", safety.SCENARIOS)
@pytest.mark.parametrize("valve", [0, 8, 22])
def test_a_stuck_open_intake_is_caught_within_50_ms_or_does_nothing(
    scenario: str, valve: int
) -> None:
    """The exhaust fighting a stuck-open intake is told to let out air the chamber does not
    lose: the observer's residual is about the whole flow, far outside its tolerance. A
    chamber that already sits near the supply (a rod side, valve 22 mid-exercise) takes no
    air through it: nothing to observe, and nothing moves."""
    run = safety.run_fault(FaultKind.VALVE_STUCK_OPEN, scenario, channel=valve)
    if valve != 22:
        assert run.detected, run
    if run.detected:
        assert run.channel == valve // 2 and run.detect_ms <= 50.0, run
    else:
        assert run.excursion_deg <= 0.2 and run.excursion_mm <= 0.3, run


@pytest.mark.parametrize("scenario", ["exercise", "pushing", "settling"])
def test_every_valve_stuck_shut_while_the_legs_move_is_named_by_its_own_pulses(
    scenario: str,
) -> None:
    """The loop keeps asking a stuck-shut valve for short pulses (about 10 slots) while its
    leg's other chamber does the work. Held to its own pulses (the answer rule), the valve
    is named within three of them: measured 11-47 ms over the 72 runs, the platform at most
    0.45 deg and 1.08 mm off. Before, the air observer, whose tolerance counts every pulse of
    the chamber, named them in 51-331 ms and missed four within 0.5 s."""
    for valve in range(24):
        run = safety.run_fault(FaultKind.VALVE_STUCK_CLOSED, scenario, channel=valve)
        assert run.detected and run.detect_ms <= 50.0, run
        assert run.trip in ("AIR_BALANCE (service)", Trip.VALVE.name), run
        assert run.channel == valve // 2, run
        assert not run.dormant and run.excursion_deg <= 1.0 and run.excursion_mm <= 1.5, run


def test_a_leak_as_the_legs_settle_is_named_by_what_its_intake_brings() -> None:
    """As the legs settle the loop's pulses are few and short: a 0.5 C leak took the air
    observer 51-399 ms there (one chamber not within 0.5 s). Its intake's pulses bring air
    the chamber does not keep, and the answer rule names it in 11-23 ms."""
    for chamber in range(12):
        run = safety.run_fault(FaultKind.CHAMBER_LEAK, "settling", channel=chamber)
        assert run.detected and run.detect_ms <= 50.0, run
        assert run.trip == "AIR_BALANCE (service)" and run.channel == chamber, run


def _pulses_answered(
    intake_share: float,
    lag: int = 0,
    identified: bool = True,
    config: SupervisionConfig | None = None,
    periods: int = 30,
) -> int:
    """Chamber 0 at 3 bar (gauge) and a still piston, its intake and its exhaust pulsed 12
    slots in turn, as the loop does mid-exercise; its exhaust passes what it should, its
    intake ``intake_share`` of it, arriving ``lag`` periods late. The first period (from 1)
    in which check_air_flow names the chamber, 0 if none does."""
    from device import supervision

    cfg = SupervisionConfig() if config is None else config
    q = build_supervision(cfg, 1.0e5, 0.004, identified=identified)
    valves = np.zeros((4, 24))
    valves[supervision.V_GAIN] = 1.0
    if identified:
        valves[supervision.V_SHUT] = 0.5e-3
        valves[supervision.V_OPENS] = 0.7e-3
    counters = np.zeros(supervision.N_COUNTERS, dtype=np.int64)
    monitor = np.zeros(supervision.N_MONITOR)
    volume, supply, pressure = 4.0e-5, 6.0e5, 3.0e5
    coming = [0.0] * (lag + 1)
    supervision.check_air_flow(monitor, counters, 0, 0, pressure, volume, supply, q, valves)
    for period in range(1, periods + 1):
        slots = 12 if period % 2 else -12
        air, _, _ = supervision.pulse_air(0, slots, pressure + q.atm, supply + q.atm, q, valves)
        if slots > 0:
            coming[lag] += intake_share * air
            arrived = coming.pop(0)
            coming.append(0.0)
        else:
            arrived = air + coming.pop(0)
            coming.append(0.0)
        pressure += arrived * q.obs_k / volume  # what that air does to a still chamber
        named = supervision.check_air_flow(
            monitor, counters, 0, slots, pressure, volume, supply, q, valves
        )
        if named:
            return period
    return 0


def test_a_valve_is_held_to_its_own_pulses() -> None:
    """A valve that passes nothing is named by the third of its pulses; one that passes its
    air, or three quarters of it, or passes it a period late (the air reaches the
    transducer within its own period or the next), is not. A valve whose opening edge the
    start-up identification did not measure is not held so (a short pulse may have passed
    nothing at all), and the air observer alone, whose tolerance counts the healthy
    exhaust's pulses too, takes longer."""
    assert 0 < _pulses_answered(0.0) <= 6
    assert 0 < _pulses_answered(-0.2) <= 6  # a leak taking more than the pulses bring
    assert _pulses_answered(1.0) == 0
    assert _pulses_answered(0.75) == 0
    assert _pulses_answered(1.0, lag=1) == 0
    assert _pulses_answered(0.0, identified=False, periods=6) == 0
    observer_alone = SupervisionConfig(answer_floor=1.0e9)
    assert _pulses_answered(0.0, config=observer_alone, periods=6) == 0


def test_a_fault_that_made_no_difference_yet_is_counted_as_dormant() -> None:
    """Held at home, the legs rest with every valve shut: an intake stuck shut there is
    never told to open, and a leg sensor that freezes on a resting leg reads where the leg
    is. Nothing can tell either from a healthy part, and the benchmark says so beside
    counting it as missed; a fault that moved something is never dormant. Neither stays
    hidden once used: the exercise that follows names the valve by its own pulses (measured
    17-45 ms over the 24 valves) and the sensor by its leg running from it (78-195 ms over
    the six legs), the platform at most 0.28 deg / 1.0 mm and 1.01 deg / 1.96 mm off the
    same exercise without the fault."""
    run = safety.run_fault(FaultKind.VALVE_STUCK_CLOSED, "holding", channel=0)
    assert not run.detected and run.dormant, run
    assert run.excursion_deg <= 0.1 and run.excursion_mm <= 0.1, run
    assert run.used_trip in ("AIR_BALANCE (service)", Trip.VALVE.name), run
    assert run.used_detect_ms <= 50.0 and run.used_excursion_mm <= 1.0, run
    frozen = safety.run_fault(FaultKind.LEG_STUCK, "holding", channel=5)
    assert not frozen.detected and frozen.dormant, frozen
    assert frozen.used_trip == Trip.LEG_SENSOR.name and frozen.used_detect_ms <= 250.0, frozen
    assert frozen.used_excursion_deg <= 2.0 and frozen.used_excursion_mm <= 3.0, frozen
    moved = safety.run_fault(FaultKind.LEG_STUCK, "exercise", channel=0)
    assert not moved.dormant, moved  # its leg moved on under the frozen reading
    assert moved.detected and moved.used_trip == "" and math.isnan(moved.used_detect_ms), moved


def test_a_stuck_closed_exhaust_is_caught_while_the_patient_pushes() -> None:
    """Named as what it is, before the first air-balance window ends. Measured: 25 ms by
    the answer rule on the calibrated unit, 0.11 deg, 0.31 mm (77 ms by the air observer
    alone; 401 ms by the windows
    with the type's range, 601 ms when only windows told to move 3 Pa m3 were judged).
    Before the frozen-pressure rule looked at every read, this run was a PRESSURE_SENSOR
    trip at 489 ms: the live transducer of a chamber whose exhaust was stuck shut read the
    same at ten period ends running and was named as frozen."""
    run = safety.run_fault(FaultKind.VALVE_STUCK_CLOSED, "pushing", after=1.0)
    window_ms = SupervisionConfig().air_window_periods * 4.0  # 4 ms control periods
    assert run.detected and run.detect_ms < window_ms, run
    assert run.trip in ("AIR_BALANCE (service)", Trip.VALVE.name) and run.channel == 4, run
    assert run.excursion_deg <= 1.0 and run.excursion_mm <= 1.0, run


def test_a_service_warning_stops_new_motion_until_a_technician_rearms() -> None:
    from device import commands
    from device.commands import CommandError, Context
    from device.geometry import DEFAULT_GEOMETRY
    from device.limits import SafetyLimits
    from device.protocol import messages as m
    from device.protocol.messages import DeviceMode, NackCode

    ctx = Context(SafetyLimits().published(), DEFAULT_GEOMETRY, DeviceMode.READY, service=True)
    for command in (m.ArmHome(), m.Resume()):
        with pytest.raises(CommandError) as err:
            commands.check(command, ctx)
        assert err.value.code == NackCode.SERVICE_NEEDED
    commands.check(m.Rearm(), ctx)  # allowed in READY only because service is needed
    commands.check(m.HoldCmd(), ctx)
    moving = Context(ctx.limits, ctx.geometry, DeviceMode.ACTIVE, service=True)
    with pytest.raises(CommandError) as err:
        commands.check(m.Rearm(), moving)  # never while a segment runs
    assert err.value.code == NackCode.WRONG_MODE


def test_healthy_exercises_do_not_trip_the_supervision() -> None:
    # The nominal plant and draw 11, whose valves' timing is furthest from the type's.
    runs = safety.healthy_runs(seeds=(1,), seconds=4.0, draws=(11,))
    assert runs
    supervision_trips = {
        Trip.PRESSURE_SENSOR.name,
        Trip.SUPPLY_LOSS.name,
        Trip.SUPPLY_HIGH.name,
        Trip.LEG_SENSOR.name,
        Trip.FORCE_SENSOR.name,
        Trip.FORCE_BALANCE.name,
        Trip.VALVE.name,
    }
    for r in runs:
        assert r.trip not in supervision_trips and not r.supply_low and not r.service, r
        assert r.residual_max_n < 0.7 * 30.0, r
        assert r.wrench_force_max_n < 45.0 and r.wrench_torque_max_nm < 5.5, r
        assert 0.0 < r.turn_share_max < 1.0, r
        assert 0.0 < r.lift_share_max < 0.6, r  # measured at most 0.42 (builds 0-73)
        assert 0.0 < r.air_flow_max < 0.75, r  # measured at most 0.55 (builds 0-49)
        # The answer rule's share over the lowest answer share judged: measured at most
        # 0.70 (builds 0-49, 53-54); the isometric hold's legs rest, and nothing is judged.
        assert r.answer_max < 0.8 and (r.answer_max > 0.0 or r.exercise == "isometric"), r
        # A leg that carries the force balance's residual alone, against its floor.
        assert r.steady_share_max < 0.6, r
    assert all(math.isfinite(r.residual_max_n) for r in runs)


def test_through_the_service_a_fault_event_names_the_part_and_low_air_holds() -> None:
    """The device service on a pty: an open pressure wire is a FAULT event naming the chamber;
    a drooping supply holds the exercise, and resuming waits for the air to come back."""
    import asyncio
    import threading

    from device.client import CommandRefused, DeviceClient, build_segment
    from device.hardware import SimulatedHardware
    from device.protocol import messages as m
    from device.protocol.messages import DeviceMode, EventKind, NackCode
    from device.rig import Rig
    from device.service import WATCHDOG_MS_MAX, DeviceService, ServiceConfig
    from device.transport import PtyLink
    from tests.device.test_service import PITCH

    hardware = SimulatedHardware(PlantConfig(patient="relaxed"), seed=4)
    link = PtyLink()
    # The longest watchdog the device allows: a host stall on a machine shared with other
    # tests must neither stop the homing nor pass for the supply's hold.
    service = DeviceService(Rig(hardware), link, ServiceConfig(watchdog_ms=WATCHDOG_MS_MAX))
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()

    async def main() -> None:
        dev = await DeviceClient.connect(link.name)
        try:
            seen: list[m.Event] = []

            async def collect() -> None:
                async for event in dev.events():
                    seen.append(event)

            collector = asyncio.create_task(collect())

            async def next_event(kind: EventKind) -> m.Event:
                for _ in range(200):
                    found = [e for e in seen if e.kind == kind]
                    if found:
                        return found[-1]
                    await asyncio.sleep(0.01)
                raise AssertionError(f"no {kind.name} event in {seen}")

            assert dev.hello is not None
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            await dev.start_segment(build_segment(dev.hello, 1, 30.0, {"pitch": PITCH}))
            await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=2.0)
            await asyncio.sleep(0.3)
            hardware.inject(Fault(FaultKind.SUPPLY_DROOP, float(hardware.state.time[0]), -1, 3.5))
            await dev.wait_for_mode(DeviceMode.HOLD, timeout=5.0)
            e = await next_event(EventKind.SUPPLY_LOW)
            assert "air supply low" in e.text and e.value < 4.5e5
            with pytest.raises(CommandRefused) as err:
                await dev.resume()
            assert err.value.nack.code == NackCode.SUPPLY_LOW
            # The air comes back: after it has held for a while, resuming works again.
            hardware.clear_faults()
            await asyncio.sleep(1.5)
            await dev.resume()
            await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=2.0)
            hardware.inject(Fault(FaultKind.PRESSURE_OPEN, float(hardware.state.time[0]), 7))
            await dev.wait_for_mode(DeviceMode.FAULT, timeout=2.0)
            e = await next_event(EventKind.FAULT)
            assert e.code == Trip.PRESSURE_SENSOR
            assert e.text == "PRESSURE_SENSOR on chamber 8 (leg 4, rod side)"
            collector.cancel()
        finally:
            await dev.close()

    try:
        asyncio.run(main())
    finally:
        service.stop()
        thread.join(5.0)
        service.shutdown()
    assert not thread.is_alive()


def test_a_supply_lost_at_rest_is_said_once_each_time_and_flagged_until_it_recovers() -> None:
    """READY at home and the compressor stops: nothing moves, so nothing is held, but the
    device says so once (a SUPPLY_LOW event, the mode unchanged) and flags it in every
    telemetry message until the air is back, so that the station can tell the patient
    before an exercise is refused for it; a second loss is said again."""
    import asyncio

    from device.client import CommandRefused, DeviceClient, build_segment
    from device.protocol import messages as m
    from device.protocol.messages import DeviceMode, EventKind, NackCode
    from device.service import WATCHDOG_MS_MAX, ServiceConfig
    from tests.device.service_thread import service_in_thread
    from tests.device.test_service import PITCH

    hardware = SimulatedHardware(PlantConfig(patient="relaxed"), seed=5)
    config = ServiceConfig(watchdog_ms=WATCHDOG_MS_MAX)

    async def main(path: str) -> None:
        dev = await DeviceClient.connect(path)
        seen: list[m.Event] = []

        async def collect() -> None:
            async for event in dev.events():
                seen.append(event)

        async def flagged(low: bool, timeout: float) -> None:
            deadline = asyncio.get_running_loop().time() + timeout
            while True:
                latest = dev.latest
                if latest is not None and bool(latest.flags & m.TelemetryFlags.SUPPLY_LOW) == low:
                    return
                assert asyncio.get_running_loop().time() < deadline, f"flag never {low}"
                await asyncio.sleep(0.02)

        def lows() -> list[m.Event]:
            return [e for e in seen if e.kind == EventKind.SUPPLY_LOW]

        collector = asyncio.create_task(collect())
        try:
            assert dev.hello is not None
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=20.0)
            await flagged(False, 1.0)
            for episode in (1, 2):
                hardware.inject(Fault(FaultKind.SUPPLY_LOSS, float(hardware.state.time[0]), -1))
                await flagged(True, 5.0)
                await asyncio.sleep(0.5)  # long low: still said once
                assert len(lows()) == episode, seen
                e = lows()[-1]
                assert e.mode_from == e.mode_to == DeviceMode.READY
                assert "nothing starts until it recovers" in e.text and e.value < 4.5e5, e
                with pytest.raises(CommandRefused) as err:
                    await dev.start_segment(
                        build_segment(dev.hello, episode, 5.0, {"pitch": PITCH})
                    )
                assert err.value.nack.code == NackCode.SUPPLY_LOW
                hardware.clear_faults()
                await flagged(False, 10.0)
                assert dev.mode == DeviceMode.READY
        finally:
            collector.cancel()
            await dev.close()

    with service_in_thread(hardware, config) as link:
        asyncio.run(main(link.name))


def test_a_leg_resting_short_of_a_still_target_is_not_taken_for_a_stuck_sensor() -> None:
    """Draw 2 of the ensemble, ROM assessment against a resisting foot: stiff seals hold a
    leg 1.0-1.1 mm short of its target for longer than the stuck rule's 33 reads while the
    target creeps by less than 0.1 mm. It tripped LEG_SENSOR before the error rule asked
    for a target that ran away from the frozen reading."""
    from sessions.prescription import ExerciseKind

    rig = safety._drawn_rig("resisting", 2)
    safety.start_exercise(rig, ExerciseKind.ROM_ASSESSMENT)
    rig.run(10.0, log_hz=0)
    assert rig.trip == Trip.NONE, (rig.trip, rig.trip_channel)


def test_a_leg_sensor_frozen_a_count_from_a_held_target_does_not_wind_the_loop_up() -> None:
    """Seed 1, leg 2: the reading froze one count (24 um) short of the held target. The
    outer integral used to grow on that error by 3.6 N a second until the leg broke free
    and ran 20 mm (9 deg) before the force sensor cross-check tripped at 953 ms. An error
    the sensor cannot resolve is no longer integrated (ControllerConfig.
    position_integral_deadband), so the loop leaves the leg where it was."""
    run = safety.run_fault(FaultKind.LEG_STUCK, "holding", channel=2, after=WATCH_S)
    assert run.excursion_deg <= 0.5 and run.excursion_mm <= 1.0, run


def test_a_leg_sensor_frozen_while_holding_leaves_the_platform_where_it_was() -> None:
    """Every leg, watched 2 s. Before the quiet hold the loop drove a leg whose reading had
    stopped on nothing but its air and friction, and some ran off (seed 1, leg 3: 8.3 deg,
    26 mm before the force cross-check tripped at 2.4 s). Resting, the leg is held by its
    shut chambers' air. Its doses also follow the load it should carry, and the foot pushes
    back on a platform that moves: following without limit, leg 3 was dosed out 20 mm
    unseen (5.4 deg, 17.5 mm in 2 s). Now a leg whose reading does not move gets at most
    ControllerConfig.rest_blind_doses (measured: at most 0.09 deg, 0.25 mm)."""
    for leg in range(6):
        run = safety.run_fault(FaultKind.LEG_STUCK, "holding", channel=leg, after=WATCH_S)
        assert run.excursion_deg <= 0.5 and run.excursion_mm <= 1.0, run


@pytest.mark.parametrize("scenario", safety.SCENARIOS)
def test_a_stuck_closed_exhaust_is_caught_within_seconds_and_moves_nothing(scenario: str) -> None:
    """The loop hardly uses that exhaust, yet each short pulse it asks of it passes nothing
    where this build's valve would pass its measured share: the answer rule names it
    (measured: 25-39 ms; 73-77 ms by the air observer alone, 0.4-1.1 s by the air windows
    with the type's range); the leg
    stays within a millimetre meanwhile. Held at home, the legs rest with every valve
    shut and the fault is not seen, nor does it move anything, until the leg is driven."""
    run = safety.run_fault(FaultKind.VALVE_STUCK_CLOSED, scenario, after=WATCH_S)
    if scenario != "holding":
        assert run.detected and run.channel == 4, run
    assert run.excursion_deg <= 1.0 and run.excursion_mm <= 1.0, run


@pytest.mark.xfail(
    strict=True,
    reason="open (issue 11): a leg sensor frozen on leg 0 or 1 while the patient pushes is "
    "not detected (legs 2-5 are caught in 55-107 ms): pitch hardly changes those legs' "
    "targets, and once the blind bound stops the compensation pulling them nothing is out "
    "of balance; the platform stays within 0.8 deg and 2.3 mm (the test below)",
)
def test_a_leg_sensor_frozen_while_the_patient_pushes_is_caught_on_every_leg() -> None:
    for leg in range(6):
        run = safety.run_fault(FaultKind.LEG_STUCK, "pushing", channel=leg, after=1.0)
        assert run.detected and run.excursion_deg <= 2.0 and run.excursion_mm <= 3.0, run


def _blind_bound_off(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fault runs of lab.safety on a controller whose compensation follows a still leg as
    any other (the bound of SupervisionConfig.leg_blind_reads never applies)."""
    from device.controller import ControllerConfig

    config = ControllerConfig(supervision=SupervisionConfig(leg_blind_reads=10**9))
    unit = safety._rig
    monkeypatch.setattr(
        safety,
        "_rig",
        lambda patient, seed, calibrated=True: unit(patient, seed, calibrated, config),
    )


@pytest.mark.parametrize("leg", [0, 1])
def test_a_leg_sensor_frozen_while_the_patient_pushes_does_not_let_the_leg_run(
    leg: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Legs 0 and 1, which the push does not betray (above), watched 2 s. The load
    compensation followed the foot's reaction to the tilt the frozen leg made and handed it
    to that leg, which has no position feedback left and yielded further: 6.2-6.7 deg and
    25-27 mm. Now a leg whose reading stands still is given at most
    SupervisionConfig.leg_blind_band more or less than it was while its reading moved
    (measured: 0.66-0.76 deg, 2.0-2.2 mm, settled)."""
    run = safety.run_fault(FaultKind.LEG_STUCK, "pushing", channel=leg, after=WATCH_S)
    assert run.excursion_deg <= 1.0 and run.excursion_mm <= 3.0, run
    _blind_bound_off(monkeypatch)
    unbounded = safety.run_fault(FaultKind.LEG_STUCK, "pushing", channel=leg, after=WATCH_S)
    assert unbounded.excursion_deg >= 4.0 and unbounded.excursion_mm >= 15.0, unbounded


def _frozen_while_settling(leg: int, config: ctl.ControllerConfig) -> Rig:
    """A rig whose legs were sent to mid stroke 50 ms before ``leg``'s sensor froze (the
    step is a fraction of a millimetre from where the platform rests at start-up), watched
    2 s."""
    rig = Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=1), config)
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(0.051, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.LEG_STUCK, float(hw.state.time[0]), leg, 0.0))
    rig.run(WATCH_S, log_hz=1000)
    return rig


@pytest.mark.parametrize("leg", [1, 2, 4])
def test_a_leg_sensor_frozen_while_the_legs_settle_is_caught_before_the_leg_runs(leg: int) -> None:
    """Frozen a few counts short of its target as the legs settle at mid stroke, the leg is
    pushed by the loop's integral and its seals' friction fed forward, its target never
    moves again (the error rule waits for one that runs away) and the foot's reaction to
    the tilt grows the load the compensation hands it: before the blind bound legs 1, 2
    and 4 ran 21-30 mm (3.4-5.2 deg) before a VALVE or LEG_SENSOR trip at 247-370 ms. Now
    the leg stops 5-6 mm off, balanced against the foot by the loop's push, and that push
    beyond the load it is given (15 N) names it (223-471 ms measured)."""
    rig = _frozen_while_settling(leg, ctl.ControllerConfig())
    assert rig.trip == Trip.LEG_SENSOR and rig.trip_channel == leg, (rig.trip, rig.trip_channel)
    log = rig.log
    off = np.abs(log[:, COL[f"leg_x{leg}"]] - log[:, COL[f"leg_target{leg}"]]).max()
    tilt = np.degrees(np.abs(log[:, [COL["pose_roll"], COL["pose_pitch"]]]).max())
    assert off <= 7.0e-3 and tilt <= 1.5, (off, tilt)


def test_the_compensation_a_still_leg_is_given_is_bounded_and_what_it_withholds_counts() -> None:
    """The rule by itself: while a leg's reading moves its compensation is all of the load;
    once it has stood still for leg_blind_reads reads, at most leg_blind_band from what it
    was last given, the rest recorded as withheld; withheld force counts with the loop's
    push toward the stuck rule's leg_stuck_force, so a still leg left that far out of
    balance is stuck, and one left less is not."""
    q = Rig(SimulatedHardware()).params.sup
    counters = np.zeros(supervision.N_COUNTERS, dtype=np.int64)
    monitor = np.zeros(supervision.N_MONITOR)
    leg = 3
    assert supervision.blind_load(monitor, counters, leg, 20.0, q) == 20.0  # moving: all
    counters[supervision.C_LEG_STILL + leg] = q.leg_blind_reads
    assert supervision.blind_load(monitor, counters, leg, 23.0, q) == 23.0  # within the band
    given = supervision.blind_load(monitor, counters, leg, -40.0, q)
    assert given == pytest.approx(20.0 - q.leg_blind_band)
    assert monitor[supervision.M_BLIND + leg] == pytest.approx(given + 40.0)
    assert supervision.blind_load(monitor, counters, leg, 60.0, q) == 20.0 + q.leg_blind_band
    counters[supervision.C_LEG_STILL + leg] = 0  # the reading moved: followed again
    assert supervision.blind_load(monitor, counters, leg, 60.0, q) == 60.0
    assert monitor[supervision.M_BLIND + leg] == 0.0

    def reads(withheld: float, push: float = 0.0, friction: float = 0.0) -> tuple[int, int]:
        seals = np.full(6, friction)
        counters[:] = 0
        monitor[:] = 0.0
        sensors = np.full(25, 3.0e5)  # chambers at 2 bar gauge
        sensors[12] = 7.0e5  # the supply at 6
        sensors[13:19] = 0.05
        sensors[19:25] = [0.1, 0.2, 0.3, 0.01, 0.02, 0.03]
        target, zero = np.full(6, 0.05), np.zeros(25)
        still = np.zeros(19, dtype=np.int64)  # the transducers' and channels' flicker not judged
        found = (0, -1)
        for n in range(q.leg_stuck_reads + 2):
            sensors[13:19] += 24.0e-6  # every leg but ``leg`` moves a count a read
            sensors[13 + leg] = 0.05
            sensors[19] += 0.01 * (-1) ** n  # a live force sensor
            monitor[supervision.M_BLIND + leg] = withheld
            monitor[supervision.M_PUSH + leg] = push
            code, channel = supervision.check_reading(
                monitor, counters, sensors, q, True, target, zero, seals, still
            )
            if code != 0:
                return int(code), int(channel)
        return found

    assert reads(-(q.leg_stuck_force + 1.0)) == (int(Trip.LEG_SENSOR), leg)
    assert reads(-(q.leg_stuck_force - 1.0)) == (0, -1)
    # The loop's own push beyond the load it is given counts as before, whatever the
    # compensation withholds (the leg may be held in balance by a load it has not been
    # seen to carry).
    assert reads(-(q.leg_stuck_force + 1.0), push=q.leg_stuck_force + 1.0) == (
        int(Trip.LEG_SENSOR),
        leg,
    )
    # A unit whose seals were identified: 1.5 times their breakaway, above a floor, if less.
    lighter = q.leg_stuck_floor + q.leg_stuck_seals * 1.2
    assert lighter < q.leg_stuck_force
    assert reads(0.0, push=lighter + 0.5, friction=1.2) == (int(Trip.LEG_SENSOR), leg)
    assert reads(0.0, push=lighter - 0.5, friction=1.2) == (0, -1)
    assert reads(0.0, push=q.leg_stuck_force - 0.5, friction=5.0) == (0, -1)  # at most 15 N
    for bad in ({"leg_blind_reads": 0}, {"leg_blind_band": -1.0}, {"leg_blind_band": math.nan}):
        with pytest.raises(ValueError, match="leg_blind"):
            build_supervision(SupervisionConfig(**bad), 1.0e5, 0.004)


def _force_offset(
    scenario: str, channel: int, newtons: float, seconds: float, calibrated: bool = True
) -> Rig:
    """A rig in ``scenario`` watched ``seconds`` after its force sensor's ``channel`` took an
    offset of ``newtons``."""
    rig, _, _, _, _ = safety._run(None, scenario, seed=1, calibrated=calibrated)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.FT_OFFSET, float(hw.state.time[0]), channel, newtons))
    rig.run(seconds, log_hz=0)
    return rig


def test_a_force_sensor_bias_that_jumps_is_caught_before_the_legs_push_against_it() -> None:
    """80 N on Fx or Fy at once: before the jump rule, the load compensation pushed a held
    platform 12-16 mm sideways against a load that was not there before the wrench
    cross-check tripped (50-66 ms)."""

    for channel in (0, 1, 2):
        rig = _force_offset("holding", channel, 80.0, 0.003)
        assert rig.trip == Trip.FORCE_SENSOR and rig.trip_channel == channel, rig.trip


def test_a_sideways_force_sensor_offset_under_its_limit_never_names_a_leg_sensor() -> None:
    """Fy 10 N off while roll renders 15 N m/rad against a 2 N m push (the impedance
    experiment): the load compensation hands the phantom force to the held legs and the
    loop holds them against it, several legs at once. Leg 5 stood 0.6 mm short of its
    target for 33 reads with the loop pushing it 10 N, and the stuck rule named its length
    sensor (717 ms after the offset): a technician sent to a good sensor. A push the loop
    shares with other legs counts only as it grows while the leg stands still."""
    from device.plant.model import SCRIPT_RAMP

    with ex.injected((Fault(FaultKind.FT_OFFSET, 1.5, 1, 10.0),)):
        rig = ex._impedance_rig(3, 15.0, 1.3, 1)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.script_torque(3, SCRIPT_RAMP, rig.time, 0.5, 2.0)
    rig.run(2.0, log_hz=0)
    assert rig.trip != Trip.LEG_SENSOR, (rig.trip, rig.trip_channel)


@pytest.mark.parametrize("scenario", safety.SCENARIOS)
def test_a_sideways_force_sensor_offset_is_caught_by_the_sideways_cross_check(
    scenario: str,
) -> None:
    """30 N on Fx or Fy, under the jump rule and the wrench cross-check: the load
    compensation pushes the platform against a load that is not there. The following check
    used to stop it at 46-130 ms, 3-8 mm off; the legs' residual less the platform's
    inertial force and the seals' friction names the sensor within 14-18 ms (the platform
    then 0.2-4.5 mm off, most of it the momentum it had when the valves shut)."""
    for channel in (0, 1):
        run = safety.run_fault(FaultKind.FT_OFFSET, scenario, channel=channel)
        assert run.detected and run.trip == Trip.FORCE_SENSOR.name, run
        assert run.channel == channel, run  # the component the false force is on: x or y
        assert run.detect_ms <= 25.0 and run.excursion_mm <= 5.0, run


def test_a_sideways_force_sensor_offset_as_the_legs_settle_enters_slower_until_it_is_judged() -> (
    None
):
    """When the sideways check armed 0.1 s after a new command, 50 ms into the move that
    starts every session it was not yet armed: the false 30 N entered the compensation at
    500 N/s and had pushed the platform 2.65 (Fx) and 4.81 mm (Fy) when it was named at
    52 ms. While the check is not armed a jump enters at
    ControllerConfig.load_side_slew_unwatched (measured: 0.51 and 0.32 mm). Since the checks
    arm at 40 ms (supervision.SIDE_ARM_PERIODS) it is named in 16-20 ms."""
    for channel in (0, 1):
        run = safety.run_fault(FaultKind.FT_OFFSET, "settling", channel=channel)
        assert run.detected and run.trip == Trip.FORCE_SENSOR.name and run.channel == channel
        assert run.excursion_mm <= 1.0 and run.excursion_deg <= 1.5, run
        assert run.detect_ms <= 50.0, run


@pytest.mark.parametrize("channel", range(2, 6))
def test_a_force_or_torque_offset_as_the_legs_settle_is_named_within_50_ms(channel: int) -> None:
    """The checks that take the platform's inertia out wait 40 ms after a new command
    (supervision.SIDE_ARM_PERIODS), not 0.1 s: 30 N on Fz or 3 N m on a torque channel 50 ms
    into the move that starts every session, named in 16-28 ms (52-56 ms when they waited
    0.1 s); Fx and Fy in the test above."""
    run = safety.run_fault(FaultKind.FT_OFFSET, "settling", channel=channel)
    assert run.detected and run.trip == Trip.FORCE_SENSOR.name and run.channel == channel, run
    assert run.detect_ms <= 50.0, run


def test_a_smaller_sideways_force_sensor_offset_is_caught_too() -> None:
    """20 N mid-exercise on the unit without its calibration: named by its component within
    two periods of the issue's 50 ms (18-54 ms measured: Fx in 50-54 ms since the admittance
    law figures the lag's damping at 2 Hz, 46 before; the matrix's 30 N in 14-34 ms). With
    the calibration, 30-54 ms: the seals' friction, taken out, no longer adds to the offset
    on this seed (the same holds for 15 N at home, below: Fx +15 N went unnamed for a second
    there, 2.96 mm). Under the 18 N limit an offset acts as a push of its size would."""
    for channel in (0, 1):
        rig = _force_offset("exercise", channel, 20.0, 0.058, calibrated=False)
        assert rig.trip == Trip.FORCE_SENSOR and rig.trip_channel == channel, rig.trip


def test_a_15_newton_sideways_offset_at_home_is_caught_through_the_inertia_allowance(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The allowance for the platform's inertial model grows with the measured angular
    acceleration, and at rest that is noise (up to about 19 rad/s2): with no floor under it
    the allowance stood at 1-3 N, and 15 N on Fx at home, caught in 254-278 ms otherwise,
    was not caught within a second (the unit without its calibration: with it, see above)."""
    for newtons in (-15.0, 15.0):
        monkeypatch.setitem(safety.FAULTS, FaultKind.FT_OFFSET, (0, newtons))
        run = safety.run_fault(
            FaultKind.FT_OFFSET, "holding", channel=0, after=1.0, calibrated=False
        )
        assert run.detected and run.trip == Trip.FORCE_SENSOR.name, (newtons, run)
        assert run.channel == 0 and run.detect_ms <= 500.0, (newtons, run)


def test_a_sideways_force_sensor_offset_moves_a_held_platform_at_most_3_mm() -> None:
    for seed in (1, 2, 3, 4):
        for channel in (0, 1):
            run = safety.run_fault(
                FaultKind.FT_OFFSET, "holding", seed=seed, channel=channel, after=1.0
            )
            assert run.detected and run.excursion_mm <= 3.0, run


def test_a_sideways_force_sensor_offset_moves_an_exercising_platform_at_most_3_mm() -> None:
    """30 N on Fx or Fy is named in 14-18 ms; what moves the platform is what the load
    compensation had fed the legs by then, trapped as the valves shut (3.7-4.5 mm when the
    jump entered at once; 0.4-1.7 mm with ``load_side_jump``)."""
    for scenario in ("exercise", "pushing"):
        for channel in (0, 1):
            run = safety.run_fault(FaultKind.FT_OFFSET, scenario, channel=channel)
            assert run.detected and run.excursion_mm <= 3.0, run


def _pushed(
    scenario: str, axis: int, rate: float, size: float, config: ctl.ControllerConfig | None = None
) -> tuple[Rig, np.ndarray]:
    """The calibrated nominal unit in ``scenario``, a foot ramping a push along ``axis``
    (0-2 a force, N; 3-5 a torque, N m) at ``rate`` per second to ``size`` from 0.1 s on;
    the rig and its log of the 0.6 s that follow."""
    rig = safety._rig("relaxed", 1, config=config)
    safety._start(rig, scenario)
    rig.clear_log()
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    if axis < 3:
        hw.script_force(axis, SCRIPT_RAMP, rig.time + 0.1, rate, size)
    else:
        hw.script_torque(axis, SCRIPT_RAMP, rig.time + 0.1, rate, size)
    return rig, rig.run(0.6)


@pytest.mark.parametrize("axis", [0, 1])
def test_a_real_sideways_push_however_fast_is_held_and_compensated(axis: int) -> None:
    """A foot pushing 30 N sideways, at 1,000 to 20,000 N/s, on a held platform at home and
    under a pitch exercise: no trip, the platform within 3 mm of its command (2.7 mm at the
    most measured, about as without ``load_side_jump``), and the legs take the whole load
    once the push stands (the slow entry of a jump ends)."""
    for rate in (1000.0, 20000.0):
        for scenario in ("holding", "exercise"):
            rig, log = _pushed(scenario, axis, rate, 30.0)
            where = f"{'xy'[axis]} at {rate:g} N/s while {scenario}"
            assert rig.trip == Trip.NONE, where
            pose = log[:, COL[f"pose_{'xy'[axis]}"]]
            cmd = log[:, COL[f"pose_cmd_{'xy'[axis]}"]]
            assert np.abs(pose - cmd).max() <= 3.0e-3, where
            taken = rig.state.monitor[supervision.M_LOAD_SIDE + axis]
            assert rig.state.wrench[axis] == pytest.approx(taken, abs=1e-9), where
            assert abs(taken) > 20.0, where  # the push is there, and taken in full


def test_a_foot_that_kicks_is_no_force_sensor_fault() -> None:
    """A real push is in the force sensor and in the platform's motion alike: the sideways
    cross-check sees neither. A foot kicking each rotational axis rendered at K 20 (a torque
    ramp of 300 N m per second to 10 N m) on the nominal unit and on drawn build 11, whose
    seals hold 4.5 N each (identified and taken out): no trip, and the sideways residual
    stays under half its limit (the worst kick of a wider set read 10.5 N against 18,
    without the inertial force and the friction 19.5 N)."""
    from device import supervision
    from device.plant.model import SCRIPT_RAMP

    limit = SupervisionConfig().side_force_limit
    for draw in (None, 11):
        for axis in (3, 4, 5):
            rig = safety._rig("relaxed", 1) if draw is None else safety._drawn_rig("relaxed", draw)
            rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
            rig.run(0.5, log_hz=0)
            K, B = np.zeros(6), np.zeros(6)
            K[axis], B[axis] = 20.0, 1.5
            rig.set_impedance(K, B, [i == axis for i in range(6)])
            rig.track({})
            hw = rig.hardware
            assert isinstance(hw, SimulatedHardware)
            hw.script_torque(axis, SCRIPT_RAMP, rig.time + 0.2, -300.0, 10.0)
            rig.state.monitor[supervision.M_SIDE_PEAK] = 0.0
            rig.run(1.5, log_hz=0)
            assert rig.trip == Trip.NONE, (draw, axis, rig.trip)
            peak = float(rig.state.monitor[supervision.M_SIDE_PEAK])
            assert 0.0 < peak < 0.5 * limit, (draw, axis, peak)


@pytest.mark.parametrize(
    ("draw", "axis", "k", "b", "sine"),
    [
        (1, 3, 10.0, 1.5, True),
        (2, 4, 20.0, 1.0, True),
        (27, 4, 5.0, 2.0, False),
        (27, 3, 10.0, 1.5, True),
        (27, 4, 50.0, 1.0, False),
        (27, 3, 0.0, 2.0, True),
        (26, 4, 0.0, 2.0, True),
    ],
)
def test_a_foot_that_kicks_a_drawn_build_trips_no_cross_check(
    draw: int, axis: int, k: float, b: float, sine: bool
) -> None:
    """The plate swings fast (build 2, pitch at K 5: 10 deg in 45 ms), and before the force
    balance and the wrench cross-check took each leg's share of the platform's inertial
    force out, these tripped: drawn build 1, roll at K 10, an 8 N m sine at 3 Hz:
    FORCE_SENSOR (roll); build 2, pitch at K 20, the same sine: FORCE_SENSOR (pitch); build
    27, pitch at K 5, a torque ramp of -300 N m/s to 15 N m: FORCE_BALANCE on leg 2. Build
    27's plate weighs 3.39 kg against the model's 2.5: the same kicks in roll (the sine) and
    pitch (the ramp, K 50) then read 18.1-18.6 N sideways, FORCE_SENSOR naming x or y,
    until the sideways limit allowed for the inertial model's errors as the plate turns
    (``side_mass_uncertainty``). The moment cross-check's hardest: an 8 N m sine at 3 Hz
    swinging build 27's roll or build 26's pitch at K 0 (200 deg/s; viscous seals of 19-20
    N s/m), 0.75 and 0.72 of its allowance. A limit of the range of motion or of the legs'
    speed may stop such a kick; a sensor's cross-check must not."""
    from device.plant.model import SCRIPT_RAMP, SCRIPT_SINE

    rig = safety._drawn_rig("relaxed", draw)
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(0.5, log_hz=0)
    K, B = np.zeros(6), np.zeros(6)
    K[axis], B[axis] = k, b
    rig.set_impedance(K, B, [i == axis for i in range(6)])
    rig.track({})
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    if sine:
        hw.script_torque(axis, SCRIPT_SINE, rig.time + 0.2, 8.0, 3.0)
    else:
        hw.script_torque(axis, SCRIPT_RAMP, rig.time + 0.2, -300.0, 15.0)
    rig.run(2.0, log_hz=0)
    assert rig.trip not in (Trip.FORCE_SENSOR, Trip.FORCE_BALANCE), (rig.trip, rig.trip_channel)


def _at_mid_stroke() -> tuple[ctl.ControllerParams, np.ndarray, np.ndarray]:
    """The nominal controller's parameters, its Jacobian with every leg at mid stroke (rows:
    each leg's unit vector and moment arm) and the plate's centre of mass there."""
    from device.kinematics import Kinematics, leg_vectors, twist_jacobian

    rig = Rig(SimulatedHardware())
    p = rig.params
    pose = Kinematics(rig.geometry).forward(
        rig.geometry.min_length + np.full(6, 0.5 * rig.geometry.stroke)
    )
    L, U, A, J = np.empty(6), np.empty((6, 3)), np.empty((6, 3)), np.empty((6, 6))
    leg_vectors(pose, p.base, p.plat, L, U, A)
    twist_jacobian(U, A, J)
    return p, J, p.body_com.copy()


def test_the_inertia_allowance_counts_only_turning_above_the_noise_floor() -> None:
    """``side_allowance`` by itself, at the platform's home pose: nothing for a translation
    however hard, nor for a turn within the noise floor; above it, what the model's errors
    would leave, growing with the angular acceleration beyond the floor and never more than
    the three errors' sum at that acceleration."""
    p, J, r = _at_mid_stroke()
    q = p.sup

    def allowance(accel: list[float]) -> float:
        return float(ctl.side_allowance(J, r, np.array(accel), p.body_mass, q))

    assert allowance([50.0, -50.0, 80.0, 0.0, 0.0, 0.0]) == 0.0  # translation only
    assert allowance([0.0, 0.0, 0.0, 0.9 * q.side_turn_floor, 0.0, 0.0]) == 0.0
    above = [allowance([0.0, 0.0, 0.0, 0.0, q.side_turn_floor + d, 0.0]) for d in (10, 100, 200)]
    assert 0.0 < above[0] < above[1] < above[2]
    assert above[2] == pytest.approx(2.0 * above[1], rel=1e-9)  # linear beyond the floor
    # A pitch acceleration of 200 rad/s2 beyond the floor: the plate's mass error at its
    # centre of mass, the centre's error and each piston's, at most.
    arm = float(np.hypot(r[0], r[2]))
    legs = sum(abs(J[i, 4]) * math.hypot(J[i, 0], J[i, 1]) for i in range(6))
    bound = 200.0 * (
        q.side_mass_tol * arm
        + (p.body_mass + q.side_mass_tol) * q.side_com_tol
        + q.side_leg_mass_tol * legs
    )
    assert above[2] == pytest.approx(bound, rel=1e-9)


def test_the_moment_allowance_follows_each_legs_seals_and_the_turning() -> None:
    """``turn_allowance`` by itself, at the platform's home pose: legs at rest may hold
    ``turn_stick`` times their identified friction, sliding legs ``turn_slip`` times it and
    their viscous share, each times its moment arm; a leg with no identified friction counts
    the plausible top; the inertial model's share grows with the turning beyond the floor."""
    p, J, r = _at_mid_stroke()
    q = p.sup
    arms = np.abs(J[:, 3:6])  # leg x axis
    friction = np.array([1.0, 1.2, 0.8, 1.5, 1.0, 0.9])

    def allowance(rate: np.ndarray, seals: np.ndarray, turn: float = 0.0) -> np.ndarray:
        out = np.empty(3)
        accel = np.array([0.0, 0.0, 0.0, 0.0, turn, 0.0])
        ctl.turn_allowance(J, r, accel, rate, seals, p.body_mass, p.body_inertia, q, out)
        return out

    # This rig has no calibration: each leg also counts what its unread transducer zeros
    # may make its chambers seem to push (10 kPa each way over both areas: 9.3 N).
    assert q.zero_hold == pytest.approx(10.0e3 * (p.area_cap + p.area_annulus))
    assert 9.0 < q.zero_hold < 9.6
    read = ctl.ControllerConfig(calibration=Calibration(identified_at="2026-01-01T00:00:00+00:00"))
    assert ctl.build_params(read)[0].sup.zero_hold == 0.0  # zeros read: nothing allowed for
    zeros = q.zero_hold * arms.sum(axis=0)
    floor = q.turn_floor + zeros
    rest = allowance(np.zeros(6), friction)
    assert rest == pytest.approx(floor + q.turn_stick * friction @ arms, rel=1e-12)
    fast = np.full(6, 0.2)  # every leg sliding (tanh(20) is 1 to 1e-17)
    sliding = allowance(fast, friction)
    held = q.turn_slip * friction + q.turn_viscous * fast
    assert sliding == pytest.approx(floor + held @ arms, rel=1e-12)
    unknown = allowance(np.zeros(6), np.zeros(6))
    seals = np.full(6, q.turn_friction_unidentified)
    assert unknown == pytest.approx(floor + q.turn_stick * seals @ arms, rel=1e-12)
    assert (unknown > rest).all()
    # Turning within the acceleration's noise adds nothing; beyond it, linearly.
    assert allowance(np.zeros(6), friction, 0.9 * q.side_turn_floor) == pytest.approx(rest)
    beyond = [allowance(np.zeros(6), friction, q.side_turn_floor + d) - rest for d in (100, 200)]
    assert (beyond[0] > 0.0).all()
    assert beyond[1] == pytest.approx(2.0 * beyond[0], rel=1e-9)


def test_the_wrench_allowance_counts_unidentified_seals_the_way_they_slide() -> None:
    """``wrench_allowance`` by itself, every leg at mid stroke: nothing where each leg's
    friction was identified; where none was, sliding seals oppose their legs' motion, so in
    a heave (all legs one way) their shares add along z, and in a turn (the legs both ways)
    they largely cancel; sticking seals count their breakaway either way."""
    p, J, _ = _at_mid_stroke()
    q = p.sup
    none = np.zeros(6)
    heave = np.full(6, 0.02)  # every leg sliding up (tanh(2) = 0.96)
    assert ctl.wrench_allowance(J, heave, np.full(6, 1.0), q) == (0.0, 0.0)
    up, _ = ctl.wrench_allowance(J, heave, none, q)
    turn = np.array([0.02, -0.02, 0.02, -0.02, 0.02, -0.02])
    across, _ = ctl.wrench_allowance(J, turn, none, q)
    still, _ = ctl.wrench_allowance(J, none, none, q)
    top, norms = q.turn_friction_unidentified, np.linalg.norm(J[:, :3], axis=1)
    assert still == pytest.approx(q.turn_stick * top * norms.sum(), rel=1e-12)
    assert up > 1.5 * across, (up, across)
    assert up < still  # a sliding seal holds its Coulomb friction, a stuck one its breakaway


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("answer_window", 0.0),
        ("answer_share", 0.0),
        ("answer_share", 1.5),
        ("answer_share", math.nan),
        ("answer_min_air", 0.0),
        ("answer_periods", 0),
        ("answer_dead_volume_error", -1.0e-6),
        ("answer_floor", math.inf),
        ("supply_frozen_reads", -1),
        ("supply_draw_air", 0.0),
        ("supply_draw_air", math.nan),
        ("supply_draw_edge", -1e-3),
        ("turn_floor", 0.0),
        ("turn_floor", math.inf),
        ("turn_stick", -0.1),
        ("turn_slip", math.nan),
        ("turn_viscous", -1.0),
        ("turn_friction_unidentified", math.inf),
        ("pressure_zero_unidentified", -1.0),
        ("pressure_zero_unidentified", math.nan),
        ("turn_periods", 0),
        ("ft_torque_step", 0.0),
        ("ft_torque_step", math.nan),
    ],
)
def test_a_moment_check_setting_out_of_its_range_is_refused_by_name(
    field: str, value: float
) -> None:
    with pytest.raises(ValueError, match=field):
        build_supervision(SupervisionConfig(**{field: value}), 1.0e5, 0.004)  # type: ignore[arg-type]


@pytest.mark.parametrize("scenario", ["holding", "exercise", "pushing"])
def test_a_torque_offset_is_named_before_it_turns_the_platform(scenario: str) -> None:
    """3 N m on any torque channel (under the jump rule's 4 N m and the wrench cross-check's
    5.5 N m) acts on the loop as a patient's torque would, but the legs do not carry it: on
    the calibrated unit the moment cross-check names it in 10-14 ms, the platform within
    0.8 deg and 1 mm. Before, on a compliant axis it turned the platform 3.7 deg unnamed;
    on a held one the pressures it set, trapped at the trip, turned it 2.9 deg after it
    (``load_turn_jump``)."""
    for channel in (3, 4, 5):
        run = safety.run_fault(FaultKind.FT_OFFSET, scenario, channel=channel)
        assert run.detected and run.trip == "FORCE_SENSOR" and run.channel == channel, run
        assert run.detect_ms <= 30.0 and run.excursion_deg <= 1.2, run
        assert run.excursion_mm <= 1.5, run


@pytest.mark.parametrize("channel", [3, 4, 5])
def test_a_smaller_or_creeping_torque_offset_at_another_moment_is_named_too(channel: int) -> None:
    """Not the matrix's 3 N m at its moment: -2 N m 0.73 s into the pitch exercise, and 3 N m
    that creeps in over 0.3 s (0.2 N m every 20 ms, under the step that slows the held
    axes' entry): each named by the moment check on its own axis within a second. Under the
    allowance (1.5 N m on roll, under its 1.8 N m at rest) an offset acts as a patient's torque
    of its size."""
    for creep in (False, True):
        rig = safety._rig("relaxed", 1)
        safety._start(rig, "exercise")
        rig.run(0.73, log_hz=0)
        hw = rig.hardware
        assert isinstance(hw, SimulatedHardware)
        t0 = float(hw.state.time[0])
        if creep:
            for k in range(15):
                hw.inject(Fault(FaultKind.FT_OFFSET, t0 + 0.02 * k, channel, 0.2))
        else:
            hw.inject(Fault(FaultKind.FT_OFFSET, t0, channel, -2.0))
        rig.run(1.0, log_hz=0)
        assert (rig.trip, rig.trip_channel) == (Trip.FORCE_SENSOR, channel), (creep, rig.trip)


def test_without_a_calibration_the_moment_check_allows_for_the_heaviest_seals() -> None:
    """Uncalibrated, no friction is taken out and no transducer zero subtracted: the
    allowance counts each leg's seals at the plausible top (5 N) and its chambers' zeros
    at the type's band (10 kPa each way, 9.3 N a leg). The same 3 N m on pitch
    mid-exercise is then within it and not named (it was at 54 ms before the zeros were
    allowed for, and drawn builds 47 and 48 tripped healthy 1-1.4 % over the allowance):
    the foot plate turns as a patient's 3 N m would turn it against K = 30."""
    rig = safety._rig("relaxed", 1, calibrated=False)
    safety._start(rig, "exercise")
    rig.run(0.5, log_hz=0)
    allow = rig.state.monitor[supervision.M_TURN_ALLOW : supervision.M_TURN_ALLOW + 3]
    assert allow.min() > 5.0, allow  # 3.0-3.7 N m with the seals alone
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.FT_OFFSET, float(hw.state.time[0]), 4, safety.FT_TORQUE_OFFSET))
    rig.run(0.5, log_hz=0)
    assert rig.trip == Trip.NONE


def test_an_uncalibrated_unit_with_the_heaviest_seals_moves_to_mid_stroke() -> None:
    """Drawn build 200 (seals of 4.4 N, 1.9 times that to break away, a plate 0.7 kg over
    its model), uncalibrated: the joint move that starts every session heaves all six legs
    together, and their seals alone put 47 N of residual force at the ankle, over the
    wrench check's 45 N: it tripped FORCE_SENSOR there, and in the start-up identification's
    slow heave. The check now allows for the seals and the zeros nothing identified."""
    from device.plant.params import draw_plant

    rig = Rig(SimulatedHardware(draw_plant(200, "relaxed"), seed=200), ctl.ControllerConfig())
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(1.0, log_hz=0)
    assert rig.trip == Trip.NONE, rig.trip
    assert rig.state.monitor[supervision.M_WRENCH_PEAK] > 45.0  # the old limit, passed


@pytest.mark.parametrize("axis", [3, 4, 5])
def test_a_real_twist_however_fast_enters_the_compensation_as_it_comes(axis: int) -> None:
    """A foot twisting 5 N m about a held axis at 300 (a kick) or 600 N m/s (faster than a
    foot twists), at home and under a pitch exercise: its reading never steps as an offset
    does (``ft_torque_step``), so it enters the load compensation at once, exactly as with
    no slow entry at all; no trip, and the legs take the whole moment. Slowed per pose
    period instead, the 600 N m/s twist pushed a held yaw 2.3-2.7 deg off and tripped
    FOLLOWING."""
    import dataclasses

    for rate in (300.0, 600.0):
        for scenario in ("holding", "exercise"):
            if scenario == "exercise" and axis == 4:
                continue  # pitch is the exercise's compliant axis: the foot's to move
            poses = []
            for config in (None, dataclasses.replace(ctl.ControllerConfig(), load_turn_slew=1e9)):
                rig, log = _pushed(scenario, axis, rate, 5.0, config)
                where = f"{AXES[axis]} at {rate:g} N m/s while {scenario}"
                assert rig.trip == Trip.NONE, (where, rig.trip, rig.trip_channel)
                taken = rig.state.monitor[supervision.M_LOAD_TURN + axis - 3]
                assert abs(taken) > 4.5, (where, taken)  # the twist is there, taken in full
                poses.append(log[:, COL[f"pose_{AXES[axis]}"]])
            np.testing.assert_array_equal(poses[0], poses[1], err_msg=where)


def test_the_following_check_waits_for_the_platform_to_be_on_command_and_for_the_air() -> None:
    """The rule by itself: nothing counts until the platform has been within the bound for
    FOLLOW_ARM_PERIODS (a resumed segment starts wherever the hold left it, a stepping leg
    slows as it arrives); then two pose periods past it trip, naming the axis; a chamber
    whose air does not add up holds the trip back (the loop, not closed valves, must hold a
    stuck-open valve)."""
    import numpy as np

    from device import supervision
    from device.rig import Rig

    q = Rig(SimulatedHardware()).params.sup
    counters = np.zeros(supervision.N_COUNTERS, dtype=np.int64)
    monitor = np.zeros(supervision.N_MONITOR)
    command, rate, held = np.zeros(6), np.zeros(6), np.zeros(6)
    off = np.zeros(6)
    off[1] = 1.5 * q.following_translation

    def check(pose: np.ndarray) -> int:
        return int(supervision.check_following(monitor, counters, pose, command, rate, held, q))

    def arm() -> None:
        supervision.disarm_following(counters)
        for _ in range(supervision.FOLLOW_ARM_PERIODS):
            assert check(command) == -1

    for _ in range(5):
        assert check(off) == -1  # not armed
    for _ in range(supervision.FOLLOW_ARM_PERIODS - 1):
        assert check(command) == -1
    assert check(off) == -1 and check(off) == -1  # one period short of armed: starts again
    arm()
    assert check(off) == -1  # one period
    assert check(off) == 1  # y
    # A commanded speed widens the bound by the loop's lag: the same error is no fault.
    rate[1] = q.following_translation / q.following_lag
    arm()
    for _ in range(2 + q.following_periods):
        assert check(off) == -1
    rate[1] = 0.0
    monitor[:] = 0.0  # the command's speed, remembered as it decays, forgotten here
    arm()
    counters[supervision.C_OBS_OVER + 5] = 1
    for _ in range(2 + q.following_periods):
        assert check(off) == -1
    counters[supervision.C_OBS_OVER + 5] = 0
    assert check(off) == -1
    assert check(off) == 1
    # An axis that renders an impedance is the foot's to move: not judged.
    tilted = np.zeros(6)
    tilted[4] = 3.0 * q.following_rotation
    held[4] = 1.0
    arm()
    for _ in range(2 + q.following_periods):
        assert check(tilted) == -1
    held[4] = 0.0
    assert check(tilted) == -1
    assert check(tilted) == 4
    assert trips.where(Trip.FOLLOWING, 1) == "y"
    assert trips.where(Trip.FOLLOWING, 6 + 2) == "leg 3"


def test_a_fast_sine_the_device_accepts_does_not_trip_the_following_check() -> None:
    """A 2 deg pitch sine at 8 Hz lags its command by about 1 deg and moves the ankle
    sideways 1.7 mm with it: the bound grows with the command's speed and the rotation's
    own error, so the device does not refuse by a trip what it accepted."""
    from lab import experiments

    result = experiments.sine("pitch", 2.0, 8.0)
    assert not result.health.tripped, result.health


def test_a_transducer_frozen_on_a_true_value_is_named_by_its_missing_noise() -> None:
    """A reading that stops where the air is (the supply, or a chamber held at home with
    every valve shut) says nothing wrong by its value; on the calibrated unit it is named
    once it has stood still longer than the transducer's noise lets a live one, and a unit
    whose transducers are too quiet to tell (50 Pa, the quietest a build may have) is not
    judged so. Measured: 125-207 ms on the nominal unit (100 Pa), the supply's 207."""
    for channel in (12, 5):
        run = safety.run_fault(FaultKind.PRESSURE_STUCK, "holding", channel=channel)
        assert run.detected and run.trip == Trip.PRESSURE_SENSOR.name, run
        assert run.channel == channel and run.detect_ms <= 250.0, run
        still = safety._rig("relaxed", 1).config.calibration.pressure_still_reads[channel]
        # The reading may already have stood still a few reads when it froze.
        assert still - 40.0 <= run.detect_ms <= still + 2.0, (run, still)
    assert "frozen without its noise" in trips.describe(int(Trip.PRESSURE_SENSOR))
    quiet = PlantConfig(patient="relaxed", overrides=(("pressure_noise", 50.0),))
    from lab.experiments import calibration_of

    cal = calibration_of(quiet)
    assert not any(cal.pressure_still_reads)
    config = dataclasses.replace(ctl.ControllerConfig(), calibration=cal)
    rig = Rig(SimulatedHardware(quiet, seed=1), config)
    safety._start(rig, "holding")
    rig.run(0.1, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.PRESSURE_STUCK, float(hw.state.time[0]), 12, 0.0, math.inf))
    rig.run(1.0, log_hz=0)
    assert rig.trip == Trip.NONE  # a live 50 Pa reading stands still for seconds too


@pytest.mark.parametrize("scenario", ["exercise", "pushing", "settling"])
@pytest.mark.parametrize("noise", [50.0, 100.0])
def test_a_frozen_supply_transducer_is_named_while_intakes_draw(
    scenario: str, noise: float
) -> None:
    """Every intake that draws dips the manifold behind the regulator, so a live supply
    reading moves while the legs move, however quiet its transducer: frozen, it is named
    within 20 draws (measured 21 ms; 207 ms by its missing noise alone, and never on a
    transducer of 50 Pa, too quiet for that rule). Healthy, the reading stood still
    through at most one drawing period over the library, on quiet transducers too."""
    from lab.experiments import calibration_of

    plant = PlantConfig(patient="relaxed", overrides=(("pressure_noise", noise),))
    config = dataclasses.replace(ctl.ControllerConfig(), calibration=calibration_of(plant))
    rig = Rig(SimulatedHardware(plant, seed=1), config)
    safety._start(rig, scenario)
    rig.run(0.05 if scenario == "settling" else 0.5, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.inject(Fault(FaultKind.PRESSURE_STUCK, float(hw.state.time[0]), 12, 0.0, math.inf))
    t0 = rig.time
    while rig.trip == Trip.NONE and rig.time - t0 < 0.5:
        rig.run(0.001, log_hz=0)
    assert rig.trip == Trip.PRESSURE_SENSOR and rig.trip_channel == 12
    assert rig.time - t0 <= 0.05


@pytest.mark.parametrize(("build", "patient"), [(99, "resisting"), (81, "relaxed")])
def test_a_live_supply_reading_behind_intakes_that_draw_next_to_nothing_is_not_frozen(
    build: int, patient: str
) -> None:
    """Both drawn builds have transducers too quiet to flicker. Build 99 opens its valves
    late: in the isometric hold the doses barely open its intakes and the manifold does not
    dip a count, and counted by the pulses' length its supply's reading was named frozen
    4.3 s into a healthy hold with a resisting foot. On build 81 an intake held open fills
    a chamber that has all but reached the supply, whose transducer reads 0.08 bar above
    the manifold: counted at the flow the readings say, named frozen 8.0 s in. Counted by
    the air the intakes surely drew (past their identified opening edges, at the least
    flow the readings allow), both holds run on; a frozen reading in motion is still named
    in 21 ms (the test above)."""
    from lab.experiments import calibration_of

    plant = draw_plant(build, patient)
    cal = calibration_of(plant)
    assert not any(cal.pressure_still_reads)  # the flicker rule cannot judge these units
    rig = Rig(SimulatedHardware(plant, seed=build), ctl.ControllerConfig(calibration=cal))
    safety.start_exercise(rig, ExerciseKind.ISOMETRIC)
    rig.run(10.0, log_hz=0)
    assert rig.trip == Trip.NONE and not rig.supply_low and rig.service_chamber < 0
    # Doses that pass next to nothing are not counted, whatever their length says.
    q, valves = rig.params.sup, rig.params.valves
    supply, chamber = 7.0e5, 5.5e5
    at_edge = round(valves[supervision.V_OPENS, 0] / q.slot_time)
    assert supervision.drawn_surely(0, at_edge, chamber, supply, q, valves) == 0.0
    assert supervision.drawn_surely(0, at_edge + 6, chamber, supply, q, valves) > q.supply_draw_air
    assert supervision.drawn_surely(0, -20, chamber, supply, q, valves) == 0.0  # an exhaust
    # A chamber the readings cannot tell from the supply: nothing surely flows in.
    assert supervision.drawn_surely(0, 28, supply * 0.99, supply, q, valves) == 0.0


@pytest.mark.parametrize("scenario", ["exercise", "pushing"])
def test_a_supply_lost_behind_a_frozen_supply_transducer_is_found_by_the_legs_air(
    scenario: str,
) -> None:
    """A frozen supply transducer reads like a healthy supply. While intakes draw it is
    named at once (the test above); were it to go unnamed (the drawing rule off here, on a
    unit without its calibration, so that neither that rule nor its flicker judges it) it
    is harmless until the supply fails, which it then cannot say. The chambers' air of two
    legs can: a SUPPLY_LOSS trip on the channel that says the air found it, within 100
    ms."""
    blind = SupervisionConfig(supply_frozen_reads=0)
    rig = safety._rig("relaxed", 1, False, ctl.ControllerConfig(supervision=blind))
    safety._start(rig, scenario)
    rig.run(0.5, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    t0 = float(hw.state.time[0])
    hw.inject(Fault(FaultKind.PRESSURE_STUCK, t0, 12, 0.0, math.inf))
    rig.run(0.5, log_hz=0)
    unseen = (rig.trip, rig.service_chamber)
    assert unseen == (Trip.NONE, -1), unseen  # frozen alone: nothing to see
    hw.inject(Fault(FaultKind.SUPPLY_LOSS, float(hw.state.time[0]), -1, 0.0, math.inf))
    rig.run(0.1, log_hz=0)
    assert rig.trip == Trip.SUPPLY_LOSS, (rig.trip, rig.service_chamber)
    assert "two legs" in trips.where(rig.trip, rig.trip_channel)


def test_every_fault_event_names_its_part_within_the_wire_s_120_bytes() -> None:
    """The FAULT event's text travels in 120 bytes and is cut there: the part a trip names
    (``trips.where``), on any channel a trip gives, always fits with the code before it
    (the sentence after it only when that fits too)."""
    for trip in Trip:
        for channel in range(-1, 20):
            text = trips.event_text(trip, channel)
            assert len(text.encode()) <= 120, text
            part = trips.where(trip, channel)
            assert text.startswith(trip.name + (f" on {part}" if part else "")), text
