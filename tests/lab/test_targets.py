"""The paper's headline results on the simulated plant (see ``ankle bench control``).

These run the real controller against the plant for seconds of simulated time; they check
behaviour, not speed (the real-time factor is measured by the benchmark, not asserted here).
"""

import functools
import math
from dataclasses import replace

import pytest

from device import commands
from device.controller import ControllerConfig
from device.hardware import SimulatedHardware
from device.limits import SafetyLimits
from device.plant.model import SCRIPT_RAMP
from lab import experiments as ex


@pytest.mark.parametrize(("leg", "mm"), [(1, 10.0), (4, -10.0), (2, 10.0)])
def test_leg_step_meets_rise_overshoot_and_steady_error(leg: int, mm: float) -> None:
    m = ex.step(leg=leg, mm=mm).metrics
    assert m.rise_ms <= 90.0
    # The benchmark's 5 %: the peak over the whole second, which includes where the leg
    # wanders (0.1-0.3 mm) resting on its air once it has arrived (device.quiet).
    assert m.overshoot_pct <= 5.0
    assert m.steady_error_mm <= 0.3


def test_deadband_compensation_is_better_than_without() -> None:
    comp = ex.step(leg=1, mm=10.0, compensate=True).metrics
    raw = ex.step(leg=1, mm=10.0, compensate=False).metrics
    worse_settling = math.isnan(raw.settling_ms) or raw.settling_ms > comp.settling_ms
    assert worse_settling or raw.steady_error_mm > 2 * comp.steady_error_mm


def test_staircase_of_0_3_mm_is_resolved() -> None:
    assert ex.staircase(leg=1, step_mm=0.3).resolution_mm <= 0.3


@pytest.mark.parametrize("draw", [0, 22])
def test_stiff_seals_rest_on_the_staircase_within_0_3_mm(draw: int) -> None:
    """Drawn builds 0 (3.6 N of Coulomb friction, breakaway 1.6 times that) and 22 (4.1 N,
    1.3, a 3.3 kg plate): the quiet hold used to close the valves at whatever phase of the
    loop's dither they were in, 3-4 N over or under, and answered that a quantum at a time;
    the leg ran 0.3-0.4 mm on its air before the seals held it. One sized dose answers it
    before it moves (build 0: 0.25 mm, build 22: 0.19)."""
    with ex.on_plant(ex.PlantChoice(draw=draw)):
        sized = ex.staircase(leg=1, step_mm=0.3)
    assert sized.valid and sized.resolution_mm <= 0.3


def test_answered_a_quantum_at_a_time_the_same_build_rests_further_off(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Build 0, where this was found, without the sized dose: 0.40 mm (0.25 with it; 0.43
    before a leg step's approach fed the seals' friction forward). Build 38 read 0.34 mm
    (0.22 with it) until the legs that hold beside a step were kept driven through it and
    the stepping leg rested after them (0.22 since); build 22 read 0.42 mm until the
    start-up valve test found each valve's opening edges, whose longer run changed the
    friction and mass it identifies. Measured without a step's braking too: on build 0 the
    seals' breakaway throws each 0.3 mm step faster than its push's approach, and the
    braking (``approach_braking``) then keeps the unsized build to 0.20 mm on its own."""
    unsized = functools.partial(ControllerConfig, rest_dose_extra_max=0, approach_braking=0.0)
    monkeypatch.setattr(ex, "ControllerConfig", unsized)
    with ex.on_plant(ex.PlantChoice(draw=0)):
        assert ex.staircase(leg=1, step_mm=0.3).resolution_mm > 0.3


def test_pitch_follows_7_hz_within_3_db() -> None:
    assert ex.sine("pitch", 2.0, 7.0).gain_db >= -3.0
    assert abs(ex.sine("pitch", 2.0, 1.0).gain_db) < 1.0


@pytest.mark.parametrize("k", [20.0, 50.0, 100.0])
def test_rendered_pitch_stiffness_is_within_5_percent(k: float) -> None:
    assert ex.impedance("pitch", k=k, b=1.0, torque=min(10.0, k * 0.3)).error_pct <= 5.0


def test_a_sweep_stops_at_the_first_trip_and_reports_no_roll_off(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Every sine the device accepts stays below its 0.4 m/s leg speed limit, so a rig whose
    # limit is 0.1 m/s stands in for a device that trips: 2 deg pitch at 2 Hz moves the legs
    # at about 0.04 m/s, at 6 Hz at about 0.13 m/s. The device plans no leg past 0.64 of its
    # limit (device.commands.LEG_SPEED_SHARE) and would refuse the 6 Hz sine up front; here
    # the trip is only the stand-in, so that planning check is widened for this rig alone.
    monkeypatch.setattr(commands, "LEG_SPEED_SHARE", 10.0)
    slow = SafetyLimits(leg_speed_limit=0.1)
    r = ex.sweep("pitch", 2.0, frequencies=(2.0, 6.0, 8.0), limits=slow)
    assert r.stopped_hz == 6.0 and r.frequencies == (2.0, 6.0)
    assert r.tripped and r.trip == "LEG_SPEED" and not r.valid
    assert math.isnan(r.gains_db[-1])  # the tripped frequency has no gain
    assert r.bandwidth_kind == "lower_bound" and r.bandwidth_hz == 2.0


def test_dynamic_impedance_recovers_k_and_b_on_pitch() -> None:
    r = ex.impedance_dynamic("pitch", k=50.0, b=1.0, torque=5.0, hz=(0.5, 1.0, 2.0))
    assert r.valid and not r.tripped
    j = r.joint
    # K and B within 5 %. The platform lags the admittance command by about 11 ms, which a
    # foot feels as K times that of extra damping (B rendered 1.5 before the controller
    # learnt the lag); the law alone now renders that much less, and never below the
    # envelope's least damping (0.4 at K 50) above 3 Hz.
    assert r.stiffness_error_pct <= 5.0, j
    assert r.damping_error_pct <= 5.0, j
    assert abs(j.law_stiffness - 50.0) <= 2.5 and 0.2 <= j.law_damping <= 0.8, j
    # The plate measures the device's impedance; the patient's muscles also work against
    # the relaxed ankle's own 15 N m/rad in parallel.
    assert 12.0 <= j.patient_stiffness - j.stiffness <= 18.0, j


def test_a_build_whose_loop_lags_most_renders_its_damping_with_the_floor_only_above_3_hz(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Drawn build 34's loop lags 13-14 ms: for B = 1 at K = 50 the law must render about
    0.29, below pitch's floor of 0.4. With the floor at every frequency the foot felt 1.09
    at 0.5-2 Hz; the floor now holds only above the lag corner (3 Hz), where the rings it is
    there for live, and the law's kept damping still sits on it."""
    with ex.on_plant(ex.PlantChoice(draw=34)):
        shaped = ex.impedance_dynamic("pitch", k=50.0, b=1.0, torque=5.0, hz=(0.5, 1.0, 2.0))
    flat = functools.partial(ControllerConfig, impedance_lag_corner=0.0)
    monkeypatch.setattr(ex, "ControllerConfig", flat)
    with ex.on_plant(ex.PlantChoice(draw=34)):
        floored = ex.impedance_dynamic("pitch", k=50.0, b=1.0, torque=5.0, hz=(0.5, 1.0, 2.0))
    assert shaped.valid and floored.valid
    assert shaped.damping_error_pct <= 5.0, shaped.joint
    assert floored.joint.damping >= 1.05, floored.joint


def test_a_soft_axis_renders_its_damping_with_the_lag_figured_less_the_virtual_inertia(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The range-of-motion preset, pitch K = 5, B = 0.8: the virtual inertia (0.03 kg m2)
    turns with so soft a spring that at 2 Hz the foot feels almost none of the loop's lag
    as damping. Taking out K lag rendered 0.74; figured at 2 Hz, 0.80."""
    with ex.on_plant(ex.PlantChoice()):
        banded = ex.impedance_dynamic("pitch", k=5.0, b=0.8, torque=1.5, hz=(0.5, 1.0, 2.0))
    whole = functools.partial(ControllerConfig, impedance_lag_band=0.0)
    monkeypatch.setattr(ex, "ControllerConfig", whole)
    with ex.on_plant(ex.PlantChoice()):
        k_lag = ex.impedance_dynamic("pitch", k=5.0, b=0.8, torque=1.5, hz=(0.5, 1.0, 2.0))
    assert banded.valid and k_lag.valid
    assert banded.damping_error_pct <= 3.0, banded.joint
    assert k_lag.joint.damping <= 0.8 * 0.95, k_lag.joint


def test_a_stiff_sealed_unit_renders_its_damping_with_its_friction_fed_forward(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Seals holding back 4 N per leg (the plant's range reaches 5) add to the damping a foot
    feels, most at the slowest push, where the seals' force is largest against the rate:
    the unit's identified friction, fed forward in the direction the admittance law moves
    each leg, takes it out. Measured: fed, B 0.99 (1.09 at 0.5 Hz); unfed, 1.15 (2.13 at
    0.5 Hz; 1.51 jointly while the law kept its floor at every frequency, when the floor
    added damping where the seals' hysteresis lengthens the learnt lag)."""
    choice = ex.PlantChoice(changes=(("friction_coulomb", 4.0),))
    cal = ex.calibration_of(choice.config("relaxed"))
    assert all(3.6 <= f <= 5.0 for f in cal.leg_friction), cal.leg_friction

    def dynamic() -> ex.DynamicImpedanceResult:
        with ex.on_plant(choice):
            r = ex.impedance_dynamic("pitch", k=50.0, b=1.0, torque=5.0, hz=(0.5, 1.0, 2.0))
        assert r.valid and not r.tripped
        return r

    fed = dynamic()
    monkeypatch.setattr(ex, "calibration_of", lambda cfg: replace(cal, leg_friction=()))
    unfed = dynamic()  # the same unit calibrated without the heave: no friction fed forward
    assert fed.damping_error_pct <= 5.0, fed.joint
    assert fed.stiffness_error_pct <= 5.0, fed.joint
    slow_fed, slow_unfed = fed.fits[0], unfed.fits[0]
    assert slow_fed.hz == slow_unfed.hz == 0.5
    assert slow_fed.damping <= 1.25 and slow_unfed.damping >= 1.6, (slow_fed, slow_unfed)
    assert unfed.damping_error_pct > 2.0 * fed.damping_error_pct, (fed.joint, unfed.joint)


def test_a_stiff_sealed_unit_follows_7_hz_with_its_friction_fed_forward(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Seals holding back 5 N per leg (the top of the plant's range): a 2 deg pitch sine
    at 7 Hz within 3 dB with the identified friction fed forward along the trajectory, and
    the same unit without it below (measured: -0.7 against -3.2 dB; -1.0 before the
    trajectory fed all of it, lagged)."""
    choice = ex.PlantChoice(changes=(("friction_coulomb", 5.0),))
    cal = ex.calibration_of(choice.config("relaxed"))
    with ex.on_plant(choice):
        fed = ex.sine("pitch", 2.0, 7.0)
    monkeypatch.setattr(ex, "calibration_of", lambda cfg: replace(cal, leg_friction=()))
    with ex.on_plant(choice):
        unfed = ex.sine("pitch", 2.0, 7.0)
    assert fed.valid and unfed.valid
    assert fed.gain_db >= -3.0 > unfed.gain_db, (fed.gain_db, unfed.gain_db)


FAST = SafetyLimits(axis_speed_max=(1.0, 1.0, 1.0, 10.0, 10.0, 10.0), leg_speed_limit=0.8)
"""A lab rig that accepts targets faster than the device does (its own axis limit is
0.1 m/s; its legs may plan up to 0.64 of 0.8 m/s, the device's of 0.4)."""


def test_a_flow_limited_sine_says_its_valves_saturated() -> None:
    r = ex.sine("z", 22.0, 3.0, cycles=3, limits=FAST)
    assert "valve_duty" in r.saturated and not r.tripped
    assert r.valid  # the valves' flow limit is the device's real response, not a fault
    small = ex.sine("z", 2.0, 3.0, cycles=3, limits=FAST)
    assert small.saturated == () and small.valid


def test_a_patient_pushing_past_the_range_of_motion_is_not_a_stiffness() -> None:
    # `ankle sim impedance` refuses such a push before it runs (check_impedance); a patient
    # is not bound by that: 40 N m against 20 N m/rad drives the plate into its range of
    # motion, and the run says its measurement is no stiffness.
    ax = ex._axis("pitch")
    rig = ex._impedance_rig(ax, 20.0, 1.0, seed=1)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.script_torque(ax, SCRIPT_RAMP, rig.time, 10.0, 40.0)
    rig.clear_log()
    health = ex.assess(rig, rig.run(4.5), frozenset({"range_of_motion"}))
    assert "range_of_motion" in health.saturated and not health.valid, health
    assert health.reason is not None and "range of motion" in health.reason, health


def test_an_invalid_benchmark_row_shows_no_number_and_is_not_met() -> None:
    from lab.targets import Target, table

    target = Target("x", "x (ms)", 10.0, "max")
    text = table({"x": None}, (("x", "x (ms)"),), (target,), {"x": "step: tripped LEG_SPEED"})
    assert "| x (ms) | INVALID (step: tripped LEG_SPEED) | <= 10 | NO |" in text


def test_a_measurement_with_no_number_says_so_instead_of_nan() -> None:
    from lab.targets import Target, table

    target = Target("settle", "settling (ms)", 100.0, "max")
    text = table({"settle": math.nan}, (("settle", "settling (ms)"),), (target,))
    assert "| settling (ms) | no number | <= 100 | NO |" in text
    assert "nan" not in text
    # The same read back from the benchmark's JSON, which writes NaN as null.
    text = table({"settle": None}, (("settle", "settling (ms)"),), (target,))
    assert "| settling (ms) | no number | <= 100 | NO |" in text and "None" not in text


def test_large_counts_and_figures_are_grouped_alike() -> None:
    from lab.targets import table

    rows = (("points", "points"), ("seconds", "seconds"), ("small", "small"))
    text = table({"points": 1248, "seconds": 1680.0, "small": 202}, rows, ())
    assert "| points | 1,248 |" in text and "| seconds | 1,680 |" in text
    assert "| small | 202 |" in text
