"""Start-up identification: the unit's zeros, measured through the hardware interface."""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from device.calibration import Calibration, IdentificationError
from device.controller import ControllerConfig, build_params, position_kd
from device.geometry import DEFAULT_GEOMETRY
from device.hardware import SimulatedHardware
from device.identify import (
    FRICTION_SPEEDS,
    READS,
    STILL_RISK,
    SWAY_HZ,
    SWAY_SHARE,
    count_size,
    flicker_noise,
    identify,
    moving_mass,
    pressure_still_reads,
    still_reads,
)
from device.kinematics import Kinematics
from device.plant.faults import Fault, FaultKind
from device.plant.params import PARAMETERS, PlantConfig, draw_plant
from device.rig import Rig
from device.trips import Trip


@pytest.mark.parametrize("unit", [0, 5])
def test_identification_recovers_the_planted_zeros(unit: int) -> None:
    cfg = replace(draw_plant(unit), patient="absent") if unit else PlantConfig(patient="absent")
    hw = SimulatedHardware(cfg, seed=2)
    cal = identify(hw)
    planted = hw.params.sensor_offset
    gain = hw.params.sensor_gain
    # Legs: the zero within 20 um (noise of the mean, the bumper's few um, one count's
    # rounding); planted zeros are up to 1 mm.
    assert np.abs(np.array(cal.leg_zero) - planted[13:19]).max() < 20e-6
    # Chambers: the zero plus the span error at one atmosphere (0.5-2 % of 1 bar).
    expected = planted[:12] + (gain[:12] - 1.0) * hw.params.p_atm
    assert np.abs(np.array(cal.pressure_zero) - expected).max() < 300.0
    # Force/torque: nothing on the plate, so the reading is the zero.
    assert np.abs(np.array(cal.ft_zero[:3]) - planted[19:22]).max() < 0.3
    assert np.abs(np.array(cal.ft_zero[3:]) - planted[22:25]).max() < 0.02
    assert cal.identified_at
    assert not hw.state.valve_cmd.any()  # left every valve closed


def test_identification_pulls_a_stiff_sealed_platform_down_level() -> None:
    # Breakaway friction of six stiff seals outweighs the platform: it would not sink alone.
    cfg = PlantConfig(
        patient="absent",
        overrides=(
            ("friction_coulomb", 5.0),
            ("friction_breakaway_ratio", 2.0),
            ("platform_mass", 2.0),
        ),
    )
    hw = SimulatedHardware(cfg, seed=1)
    cal = identify(hw)
    assert np.abs(hw.state.pose[3:]).max() < 1e-3  # level, not tilted or twisted
    assert np.abs(np.array(cal.leg_zero) - hw.params.sensor_offset[13:19]).max() < 20e-6


def test_a_foot_on_the_plate_or_a_bad_sensor_refuses_the_calibration() -> None:
    hw = SimulatedHardware(PlantConfig(patient="absent", overrides=(("leg_offset", 5e-3),)), seed=1)
    hw.params.sensor_offset[13] = 5e-3  # this unit's leg 1 sensor slipped by 5 mm
    with pytest.raises(IdentificationError, match="leg 1 sensor reads"):
        identify(hw)


@pytest.mark.parametrize(
    ("kind", "channel", "value", "named"),
    [
        # Each names its part, not the one a healthy part's zero would point to.
        (FaultKind.LEG_STUCK, 2, 0.0, r"leg 3 sensor read .* bit for bit .* stuck"),
        (FaultKind.LEG_NOISE, 1, 0.5, r"leg 2 sensor's reading scatters .* noisy sensor"),
        (FaultKind.VALVE_STUCK_OPEN, 0, 0.0, r"leg 1 did not come down .* chamber 1 .* valves"),
        (FaultKind.VALVE_STUCK_CLOSED, 9, 0.0, r"leg 3 did not come down .* chamber 5 .* valves"),
        (FaultKind.VALVE_STUCK_CLOSED, 6, 0.0, r"^chamber 4 \(leg 2, rod side\) did not fill"),
        (FaultKind.PRESSURE_OFFSET, 12, 0.5, r"supply transducer reads \+0\.5\d bar"),
        (FaultKind.PRESSURE_OFFSET, 12, -0.4, r"supply transducer reads -0\.[34]\d bar"),
        (FaultKind.PRESSURE_STUCK, 12, 0.0, r"PRESSURE_SENSOR on supply transducer: a pressure"),
        (FaultKind.FT_DEAD, -1, 0.0, r"FORCE_SENSOR: the foot's force/torque sensor .*zero$"),
        (FaultKind.FT_DEAD, 4, 0.0, r"^force/torque channel Ty read exactly 0 through"),
        # A tenth of a valve's conductance, a cracked fitting: the valve figures took it up.
        (FaultKind.CHAMBER_LEAK, 5, 0.1, r"^chamber 6 \(leg 3, rod side\) lost [4-9]\.\d NL/min"),
        (FaultKind.CHAMBER_LEAK, 0, 0.1, r"^chamber 1 \(leg 1, cap side\) lost [3-9]\.\d NL/min"),
    ],
)
def test_a_fault_present_at_identification_is_refused_by_its_name(
    kind: FaultKind, channel: int, value: float, named: str
) -> None:
    """A technician identifying a unit with a broken part is sent to that part: a stuck
    valve that kept a leg up was refused as a slipped leg sensor, a rod side's intake stuck
    shut as all six legs not lifting by their cap sides, a dead force sensor as
    "something on the plate", and a supply transducer 1.5 bar off was accepted (no check
    reads it at rest) and judged the supply's low and loss marks on a wrong pressure; a
    leaking chamber was accepted, its leak taken up in its valves' figures, and one force
    sensor channel dead alone too (its flicker, then, not judged once it ran)."""
    hw = SimulatedHardware(PlantConfig(patient="absent"), seed=0)
    hw.inject(Fault(kind, 0.0, channel, value, math.inf))
    with pytest.raises(IdentificationError, match=named) as refused:
        identify(hw)
    assert "on the plate" not in str(refused.value)
    assert hw.state.valve_cmd.max() == 0  # every coil left released


def test_a_calibration_round_trips_and_refuses_garbage(tmp_path: Path) -> None:
    cal = Calibration(leg_zero=(1e-4,) * 6, pressure_zero=(300.0,) * 12, identified_at="x")
    path = tmp_path / "cal.json"
    cal.save(path)
    assert Calibration.load(path) == cal
    for text in (
        "{}",
        "[]",
        "nope",
        json.dumps({**json.loads(cal.to_json()), "leg_zero": [1] * 5}),
    ):
        path.write_text(text)
        with pytest.raises(IdentificationError):
            Calibration.load(path)
    bad = json.loads(cal.to_json()) | {"pressure_zero": [1e5] * 12}
    path.write_text(json.dumps(bad))
    with pytest.raises(IdentificationError, match=re.escape("of chamber 1 (leg 1, cap side)")):
        Calibration.load(path)


def test_with_its_calibration_the_controller_reads_true_leg_lengths() -> None:
    from device.kinematics import Kinematics

    cal = identify(SimulatedHardware(PlantConfig(patient="absent"), seed=9))  # the same unit
    errors = {}
    for name, config in (
        ("raw", ControllerConfig()),
        ("calibrated", ControllerConfig(calibration=cal)),
    ):
        hw = SimulatedHardware(PlantConfig(patient="absent"), seed=4)
        rig = Rig(hw, config)
        rig.run(0.05)
        true_x = Kinematics().inverse(hw.state.pose) - hw.params.min_length
        errors[name] = np.abs(rig.state.leg_x - true_x).max()
        span = np.abs(hw.params.sensor_gain[13:19] - 1.0).max() * true_x.max()
    # What is left: the spans' error (not identified), a count and the noise.
    assert errors["calibrated"] < span + 30e-6
    assert errors["raw"] > 100e-6  # the unit's own zeros (up to 0.2 mm nominal)


def test_identification_measures_what_each_valves_pulse_passes() -> None:
    """Test pulses give each valve's gain and extra time and each chamber's volume: valves
    that close 0.35 ms later (the type's slow end) are measured as passing that much more
    per pulse, and a 1 m tube (twice the design's dead volume) as the volume it holds."""
    extras = {}
    slow = (("valve_close_delay", 1.2e-3), ("tube_length", 1.0))
    for name, overrides in (("nominal", ()), ("slow closing", slow)):
        hw = SimulatedHardware(PlantConfig(patient="absent", overrides=overrides), seed=3)
        cal = identify(hw)
        assert cal.valves_identified
        assert np.abs(np.array(cal.dead_volume) - hw.params.dead_volume).max() < 2e-6
        gain = np.array(cal.valve_gain)
        # Against the observer's polytropic 1.2: a fill passes about 1.4/1.2, a discharge
        # 1.0/1.2 of the model's air (each valve's conductance within 5 %).
        assert np.all(np.abs(gain[0::2] - 1.0) < 0.2) and np.all(np.abs(gain[1::2] - 0.83) < 0.1)
        extras[name] = np.array(cal.valve_extra)
        assert not hw.state.valve_cmd.any()
    shift = extras["slow closing"] - extras["nominal"]
    true_shift = 1.2e-3 - PARAMETERS["valve_close_delay"].value
    assert abs(shift.mean() - true_shift) < 0.1e-3, shift


@pytest.mark.parametrize(
    "overrides",
    [(), (("valve_open_delay", 1.05e-3), ("valve_delay_spread", 0.15), ("valve_jitter", 0.1e-3))],
    ids=["nominal", "slow opening, most jitter"],
)
def test_identification_finds_where_each_valve_starts_to_open(
    overrides: tuple[tuple[str, float], ...],
) -> None:
    """Short test pulses bracket each valve's own opening delay: a pulse up to
    ``pulse_shut`` left it shut every time, one from ``pulse_opens`` on opened it every
    time (the jitter decides between). The straight line's extra time is the valve's
    closing less opening delay once the chambers' drift is taken out of each pulse."""
    hw = SimulatedHardware(PlantConfig(patient="absent", overrides=overrides), seed=3)
    cal = identify(hw)
    assert cal.valves_identified, cal.notes
    p = hw.params
    spread = 3.0 * p.valve_jitter + 1.0 / 7000.0  # the jitter's tails and a tick of length
    shut, opens = np.array(cal.pulse_shut), np.array(cal.pulse_opens)
    assert np.all(shut <= p.valve_open_delay + spread), shut - p.valve_open_delay
    assert np.all(opens >= p.valve_open_delay - spread), opens - p.valve_open_delay
    assert np.all(opens - shut <= 2.0 * spread + 2.0 / 7000.0), opens - shut
    extra_error = np.array(cal.valve_extra) - (p.valve_close_delay - p.valve_open_delay)
    # Measured: within 0.16 ms nominal, 0.38 ms with the most jitter (seeds of drawn builds).
    assert np.abs(extra_error).max() < (0.25e-3 if not overrides else 0.45e-3), extra_error


def test_a_calibration_without_valves_still_loads_and_bad_valves_are_refused(
    tmp_path: Path,
) -> None:
    cal = Calibration(
        valve_gain=(1.0,) * 24,
        valve_extra=(1e-4,) * 24,
        pulse_shut=(0.7e-3,) * 24,
        pulse_opens=(0.9e-3,) * 24,
        identified_at="x",
    )
    path = tmp_path / "cal.json"
    cal.save(path)
    assert Calibration.load(path) == cal and cal.valves_identified
    assert cal.valve_figures()[3, 5] == 0.9e-3  # rows gain, extra, shut, opens
    # A file from before the pulse edges were measured: its valve figures are not used.
    without_edges = {
        k: v for k, v in json.loads(cal.to_json()).items() if not k.startswith("pulse_")
    }
    path.write_text(json.dumps(without_edges))
    assert not Calibration.load(path).valves_identified
    older = {
        k: v for k, v in json.loads(cal.to_json()).items() if not k.startswith(("valve_", "pulse_"))
    }
    path.write_text(json.dumps(older))
    loaded = Calibration.load(path)
    assert not loaded.valves_identified
    figures = loaded.valve_figures()
    assert np.all(figures[0] == 1.0) and np.all(figures[1:] == 0.0)
    assert np.all(loaded.dead_volumes(7e-6) == 7e-6)
    for change, match in (
        ({"valve_gain": [1.0] * 23}, "valve_gain needs 24"),
        (
            {"valve_extra": [0.0] * 5 + [3e-3] + [0.0] * 18},
            "exhaust of chamber 3 (leg 2, cap side)",
        ),
        ({"valve_gain": [0.1] + [1.0] * 23}, "intake of chamber 1 (leg 1, cap side)"),
        ({"dead_volume": [7e-6] * 11 + [60e-6]}, "chamber 12 (leg 6, rod side) holds 60.0 cm3"),
        ({"pulse_opens": [0.9e-3] * 23}, "pulse_opens needs 24"),
        (
            {"pulse_opens": [0.9e-3] * 3 + [2.5e-3] + [0.9e-3] * 20},
            "exhaust of chamber 2 (leg 1, rod side)",
        ),
        (
            {"pulse_shut": [1.0e-3] + [0.7e-3] * 23},
            "intake of chamber 1 (leg 1, cap side) stayed shut",
        ),
    ):
        path.write_text(json.dumps(json.loads(cal.to_json()) | change))
        with pytest.raises(IdentificationError, match=re.escape(match)):
            Calibration.load(path)


@pytest.mark.parametrize("coulomb", [0.5, 2.5, 5.0])
def test_identification_measures_each_legs_seal_friction(coulomb: float) -> None:
    """A slow heave up and down: what each leg's seals hold back at the heave's speeds,
    from the lightest glass/graphite piston to the stiffest elastomer seal the plant has."""
    cfg = PlantConfig(patient="absent", overrides=(("friction_coulomb", coulomb),))
    hw = SimulatedHardware(cfg, seed=6)
    cal = identify(hw)
    p = hw.params

    def sliding(v: float) -> float:  # the plant's steady friction at speed v (LuGre)
        stribeck = (p.f_static - p.f_coulomb) * math.exp(-((v / p.v_stribeck) ** 2))
        return p.f_coulomb + stribeck + p.f_viscous * v

    expected = float(np.mean([sliding(v) for v in FRICTION_SPEEDS]))
    friction = np.array(cal.leg_friction)
    assert friction.shape == (6,)
    # Measured through the chambers' pressures at the valve end of each tube: what the
    # air's flow down the tube and the pressure loop add reads as up to 0.35 N more.
    low, high = 0.9 * expected, 1.1 * expected + 0.35
    assert np.all((friction > low) & (friction < high)), (friction, expected)
    assert not hw.state.valve_cmd.any()  # every valve closed at the end
    assert np.abs(hw.state.pose[3:]).max() < 1e-3  # and the platform back down, level


def carried_mass(hw: SimulatedHardware) -> float:
    """What the legs of ``hw``'s empty platform move in a heave at mid-stroke: the platform
    and each piston along its leg (``platform_mass + leg_mass * sum(u_z**2)``)."""
    up = Kinematics().jacobian(DEFAULT_GEOMETRY.home_pose)[:, 2]  # each leg's unit, z
    return float(hw.params.body_mass + hw.params.leg_mass * np.sum(up**2))


@pytest.mark.parametrize(
    "overrides",
    [
        (),
        (("platform_mass", 3.5),),
        (("platform_mass", 2.0), ("leg_mass", 0.35)),
        (("friction_coulomb", 5.0), ("friction_breakaway_ratio", 2.0)),
    ],
)
def test_identification_weighs_what_the_legs_move(overrides: tuple[tuple[str, float], ...]) -> None:
    """The heave's sway weighs the platform and its pistons, whatever the seals hold back:
    a stiff seal's breakaway is not weighed as mass."""
    hw = SimulatedHardware(PlantConfig(patient="absent", overrides=overrides), seed=3)
    mass = identify(hw).moving_mass
    # Over the fifty drawn builds the sway weighs 0.04-1.09 kg more than this (median 0.25;
    # what the sensors' lags and the pressure loop put in phase with the acceleration).
    assert carried_mass(hw) - 0.1 < mass < carried_mass(hw) + 0.7, (mass, carried_mass(hw))


def test_a_heavier_plate_weighs_more_and_gets_more_derivative_gain() -> None:
    light = identify(SimulatedHardware(PlantConfig(patient="absent"), seed=4))
    heavy_plant = PlantConfig(patient="absent", overrides=(("platform_mass", 3.5),))
    heavy = identify(SimulatedHardware(heavy_plant, seed=4))
    # One kilogram more: it weighed 0.69-0.82 kg more over noise seeds 1-5 (the sway reads a
    # heavier plate's extra kilogram short; 0.82 on this one).
    assert 0.6 < heavy.moving_mass - light.moving_mass < 1.2
    nominal = ControllerConfig().position_kd
    # The nominal unit, weighed on another noise seed than the reference's: within 8 %.
    assert position_kd(ControllerConfig(calibration=light)) == pytest.approx(nominal, rel=0.08)
    kd = position_kd(ControllerConfig(calibration=heavy))
    assert kd / position_kd(ControllerConfig(calibration=light)) == pytest.approx(
        heavy.moving_mass / light.moving_mass
    )
    assert kd > 1.1 * nominal  # a kilogram more of the 4.1 the legs move: about 1.15 times
    params, _ = build_params(ControllerConfig(calibration=heavy))
    assert params.kd_pos == kd  # what the loop runs with
    approach = ControllerConfig().approach_speed  # the same approach speed, at this gain
    assert params.max_error == pytest.approx(kd * approach / params.kp_pos)
    # Not identified (an older calibration), or the scaling off: the configured gain.
    assert position_kd(ControllerConfig()) == nominal
    off = ControllerConfig(calibration=heavy, moving_mass_reference=0.0)
    assert position_kd(off) == nominal


def test_a_calibration_carries_the_legs_friction_and_refuses_what_no_seal_has(
    tmp_path: Path,
) -> None:
    cal = Calibration(leg_friction=(1.2,) * 6, identified_at="x")
    path = tmp_path / "cal.json"
    cal.save(path)
    loaded = Calibration.load(path)
    assert loaded == cal and np.all(loaded.leg_frictions() == 1.2)
    older = {k: v for k, v in json.loads(cal.to_json()).items() if k != "leg_friction"}
    path.write_text(json.dumps(older))
    assert np.all(Calibration.load(path).leg_frictions() == 0.0)  # feeds nothing forward
    for change, match in (
        ({"leg_friction": [1.0] * 5}, "leg_friction needs 6"),
        ({"leg_friction": [1.0] * 5 + [40.0]}, "leg 6 holds back 40.0 N"),
        ({"leg_friction": [-1.0] + [1.0] * 5}, "leg 1 holds back"),
    ):
        path.write_text(json.dumps(json.loads(cal.to_json()) | change))
        with pytest.raises(IdentificationError, match=re.escape(match)):
            Calibration.load(path)


def test_a_calibration_carries_the_moving_mass_and_refuses_what_no_empty_plate_weighs(
    tmp_path: Path,
) -> None:
    cal = Calibration(moving_mass=4.1, identified_at="x")
    path = tmp_path / "cal.json"
    cal.save(path)
    assert Calibration.load(path) == cal
    older = {k: v for k, v in json.loads(cal.to_json()).items() if k != "moving_mass"}
    path.write_text(json.dumps(older))
    assert Calibration.load(path).moving_mass == 0.0  # not identified: the configured gain
    for value, match in (
        (12.0, "the legs move 12.00 kg"),
        (1.0, "the legs move 1.00 kg"),
        (-4.0, "the legs move -4.00 kg"),
        ("heavy", "not a calibration file"),
    ):
        path.write_text(json.dumps(json.loads(cal.to_json()) | {"moving_mass": value}))
        with pytest.raises(IdentificationError, match=re.escape(match)):
            Calibration.load(path)
    path.write_text(cal.to_json().replace("4.1", "NaN"))
    with pytest.raises(IdentificationError, match="the legs move nan kg"):
        Calibration.load(path)


@pytest.mark.parametrize(
    ("noise", "low", "high"), [(50.0, 0, 0), (100.0, 100, 400), (300.0, 20, 40)]
)
def test_a_transducers_noise_sets_how_long_its_reading_may_stand_still(
    noise: float, low: int, high: int
) -> None:
    """From the identification's steady quantised reads: the noise, and the reads in a row
    a live reading of it stays the same once in a million million stretches (169 at 100 Pa,
    28 at 300 Pa, on the transducer's 244 Pa count); at 50 Pa a live one stands still for
    seconds and is not judged so (0). Twenty places within a count each."""
    count = 1.0e6 / 4096
    rng = np.random.default_rng(7)
    for _ in range(20):
        true = 3.0e5 + rng.uniform(0.0, count) + rng.normal(0.0, noise, READS)
        readings = count * np.floor(true / count + 0.5)
        found = pressure_still_reads(readings[:, None])[0]
        assert found == 0 if high == 0 else low <= found <= high, (noise, found)
    assert count_size(np.column_stack([readings, readings + 3 * count])) == pytest.approx(count)
    assert still_reads(0.0) == 0 and flicker_noise(np.full(50, 7)) == 0.0
    # Taken 0.85 as loud as measured: at the noise itself, the chance it waits for is smaller.
    reads = still_reads(noise / count)
    if reads:
        stay = math.erf(0.5 / (noise / count * math.sqrt(2.0)))
        assert stay**reads < STILL_RISK


def test_identification_finds_how_long_each_transducer_may_stand_still() -> None:
    """The nominal transducers' 100 Pa of noise on every channel, the supply's too: each is
    judged by its flicker; the quietest a build may have (50 Pa) is not."""
    cal = identify(SimulatedHardware(PlantConfig(patient="absent"), seed=2))
    assert len(cal.pressure_still_reads) == 13
    assert all(80 <= n <= 400 for n in cal.pressure_still_reads), cal.pressure_still_reads
    # The force sensor's channels, about a count of noise each, the plate empty: judged too.
    assert len(cal.ft_still_reads) == 6
    assert all(20 <= n <= 100 for n in cal.ft_still_reads), cal.ft_still_reads
    params, _ = build_params(ControllerConfig(calibration=cal))
    assert list(params.pressure_still) == list(cal.pressure_still_reads + cal.ft_still_reads)
    quiet = PlantConfig(patient="absent", overrides=(("pressure_noise", 50.0),))
    assert sum(identify(SimulatedHardware(quiet, seed=2)).pressure_still_reads) == 0


def test_a_calibration_carries_the_still_reads_and_refuses_what_no_transducer_has(
    tmp_path: Path,
) -> None:
    cal = Calibration(
        pressure_still_reads=(150,) * 12 + (0,), ft_still_reads=(45,) * 6, identified_at="x"
    )
    path = tmp_path / "cal.json"
    cal.save(path)
    assert Calibration.load(path) == cal
    assert list(cal.still_reads()) == [150] * 12 + [0] + [45] * 6
    still = ("pressure_still_reads", "ft_still_reads")
    older = {k: v for k, v in json.loads(cal.to_json()).items() if k not in still}
    path.write_text(json.dumps(older))
    assert not Calibration.load(path).still_reads().any()  # nothing judged by its flicker
    for change, match in (
        ({"pressure_still_reads": [150] * 12}, "pressure_still_reads needs 13"),
        ({"pressure_still_reads": [150] * 12 + [1.5]}, "must be whole numbers"),
        ({"pressure_still_reads": [150] * 12 + [True]}, "must be whole numbers"),
        (
            {"pressure_still_reads": [3] + [150] * 12},
            "transducer of chamber 1 (leg 1, cap side) may stand still 3",
        ),
        ({"pressure_still_reads": [150] * 12 + [5000]}, "the supply transducer may stand"),
        ({"ft_still_reads": [45] * 5}, "ft_still_reads needs 6"),
        ({"ft_still_reads": [45] * 5 + [2]}, "force/torque channel Tz may stand still 2"),
    ):
        path.write_text(json.dumps(json.loads(cal.to_json()) | change))
        with pytest.raises(IdentificationError, match=re.escape(match)):
            Calibration.load(path)


@pytest.mark.parametrize(("mass", "weight"), [(3.5, 9.81), (2.0, -4.9)])
def test_identification_finds_what_the_legs_carry_beyond_the_model(
    mass: float, weight: float
) -> None:
    """The slow heave's static part against the load the controller figures (a 2.5 kg
    plate): a plate a kilogram heavier is about 10 N more on the legs together, half a
    kilogram lighter about 5 N less, and on each leg its share (the transducers' spans left
    exact here: with them, up to about 5 N a leg either way)."""
    overrides = (("platform_mass", mass), ("pressure_gain_error", 0.0))
    cal = identify(SimulatedHardware(PlantConfig(patient="absent", overrides=overrides), seed=3))
    bias = np.array(cal.load_bias)
    assert bias.shape == (6,)
    up = Kinematics().jacobian(DEFAULT_GEOMETRY.home_pose)[:, 2]  # each leg's unit, z
    # Measured 10.15 and -4.44 N (0.39 N on the nominal plate: what the model's pistons and
    # the pressures at the tubes' valve ends leave).
    assert float(bias @ up) == pytest.approx(weight, abs=1.0)
    share = weight / float(up.sum())
    assert np.all(np.abs(bias - share) < 0.6), (bias, share)
    params, _ = build_params(ControllerConfig(calibration=cal))
    assert params.lift_judged and np.array_equal(params.load_bias, bias)


def test_a_calibration_carries_the_load_bias_and_refuses_what_no_empty_unit_has(
    tmp_path: Path,
) -> None:
    cal = Calibration(load_bias=(1.5, -2.0, 0.5, 3.0, -4.0, 0.0), identified_at="x")
    path = tmp_path / "cal.json"
    cal.save(path)
    assert Calibration.load(path) == cal
    older = {k: v for k, v in json.loads(cal.to_json()).items() if k != "load_bias"}
    path.write_text(json.dumps(older))
    loaded = Calibration.load(path)
    assert np.all(loaded.load_biases() == 0.0)  # nothing taken out of the residuals
    params, _ = build_params(ControllerConfig(calibration=loaded))
    assert not params.lift_judged  # and the vertical cross-check does not judge
    for change, match in (
        ({"load_bias": [1.0] * 5}, "load_bias needs 6"),
        ({"load_bias": [1.0] * 5 + [35.0]}, "leg 6 pushes +35.0 N"),
        ({"load_bias": [-21.0] + [1.0] * 5}, "leg 1 pushes -21.0 N"),
    ):
        path.write_text(json.dumps(json.loads(cal.to_json()) | change))
        with pytest.raises(IdentificationError, match=re.escape(match)):
            Calibration.load(path)


@pytest.mark.parametrize("patient", ["absent", "relaxed", "resisting"])
def test_a_platform_resting_on_its_stops_homes(patient: str) -> None:
    """Where the identification leaves a unit (and a power-off): legs on their stops, vented,
    the platform below its range of motion. Homing takes it from there to home without a
    trip: a leg or a pose that starts outside its limit is judged once inside it, and the
    pressure loop fills both sides of each leg together. Before, STROKE_END tripped the
    moment homing began, and with that waived an empty platform was launched 4.6 mm in
    20 ms into its speed limit."""
    from device.identify import lower_and_vent
    from device.modes import ModeMachine
    from device.protocol.messages import DeviceMode

    hw = SimulatedHardware(PlantConfig(patient=patient), seed=1)
    lower_and_vent(hw)
    rig = Rig(hw)
    rig.run(1.0, log_hz=0)
    start = rig.state.leg_x.copy()
    assert start.min() < 0.040  # down (on the stops when the plate is empty)
    events: list[tuple[object, ...]] = []
    machine = ModeMachine(rig, lambda *e: events.append(e))
    machine.arm_home()
    for _ in range(1000):
        rig.run(0.01, log_hz=0)
        machine.step()
        if machine.mode in (DeviceMode.READY, DeviceMode.FAULT):
            break
    assert machine.mode == DeviceMode.READY and rig.trip == Trip.NONE, events[-2:]
    assert np.abs(rig.state.leg_x - 0.05).max() < 0.5e-3


def test_a_leg_or_pose_outside_its_limit_is_judged_once_it_is_inside() -> None:
    from device import safety
    from device.limits import SafetyLimits

    lim = SafetyLimits().published().as_array()
    stroke, home = 0.1, np.zeros(6)
    sensors = np.zeros(25)
    sensors[13:19] = 0.05
    sensors[13] = 0.0005  # leg 1 on its stop
    pose = np.zeros(6)
    pose[2] = -0.04  # below the range of motion
    mask = safety.outside_at_start(sensors[13:19], pose, home, stroke, lim)
    assert mask == (1 | safety.OUTSIDE_POSE)
    assert safety.check_sensors(sensors, stroke, lim, mask)[0] == 0  # waived while outside
    assert safety.check_sensors(sensors, stroke, lim, 0)[0] == int(Trip.STROKE_END)
    sensors[13] = 0.0035  # inside the 2 mm margin, not yet 2 mm beyond it: still waived
    assert safety.still_outside(sensors, pose, home, stroke, lim, mask) == mask
    sensors[13] = 0.0045
    pose[2] = -0.028  # inside the trip's margin, not yet the range itself
    mask = safety.still_outside(sensors, pose, home, stroke, lim, mask)
    assert mask == safety.OUTSIDE_POSE
    pose[2] = -0.02
    assert safety.still_outside(sensors, pose, home, stroke, lim, mask) == 0
    sensors[13] = 0.0015  # judged from now on
    assert safety.check_sensors(sensors, stroke, lim, 0)[0] == int(Trip.STROKE_END)


@pytest.mark.parametrize("reference", [-1.0, math.nan, math.inf])
def test_a_moving_mass_reference_no_unit_has_is_refused(reference: float) -> None:
    with pytest.raises(ValueError, match="moving_mass_reference"):
        build_params(ControllerConfig(moving_mass_reference=reference))


def test_the_sway_is_weighed_apart_from_friction_weight_and_a_span_error() -> None:
    """``moving_mass`` on rows made from a known heave: a mass, the plate's weight, seals
    that hold back 20 N one way each pass plus 300 N s/m, and every force read 2 % high
    plus a 6 N offset (a transducer's span and zero): only the mass, read 2 % high with the
    forces, is in phase with the sway's acceleration."""
    up = Kinematics().jacobian(DEFAULT_GEOMETRY.home_pose)[:, 2]
    omega = 2.0 * math.pi * SWAY_HZ
    mass, speed, sway = 4.6, FRICTION_SPEEDS[-1], SWAY_SHARE * FRICTION_SPEEDS[-1] / omega
    rows = []
    for index, direction in enumerate((1.0, -1.0, 1.0, -1.0), start=1):
        for t in np.arange(0.2, 0.8, 0.004):
            z = direction * speed * (t - 0.5) + sway * math.sin(omega * t)  # about home
            rate = direction * speed + sway * omega * math.cos(omega * t)
            accel = -sway * omega**2 * math.sin(omega * t)
            vertical = mass * (9.81 + accel) + 20.0 * direction + 300.0 * rate
            force = 1.02 * vertical / (6.0 * up) + 6.0  # each leg's share, read wrong
            legs = 0.5 * DEFAULT_GEOMETRY.stroke + z * up
            rows.append(np.concatenate((legs, force, [direction, index, t])))
    assert moving_mass(np.array(rows)) == pytest.approx(mass * 1.02, rel=1e-3)
