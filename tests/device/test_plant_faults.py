"""Faults injected into the real plant: each shows only from its time on, and only where it
should (a sensor fault never changes the physics; a physical fault shows in the physics)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from device.hardware import SimulatedHardware
from device.kinematics import Kinematics
from device.plant.faults import (
    MAX_FAULTS,
    Fault,
    FaultKind,
    describe,
    format_fault,
    parse_fault,
)
from device.plant.params import PARAMETERS, PlantConfig

TICK = 1.0 / 7000.0
KIN = Kinematics()
CLEAN = (
    ("valve_seat_leak", 0.0),
    ("piston_leak", 0.0),
    ("regulator_droop", 0.0),
    ("valve_jitter", 0.0),
    *((name, 0.0) for name in ("pressure_delay", "leg_delay", "ft_delay")),
    *((name, 1e6) for name in ("pressure_bandwidth", "leg_bandwidth", "ft_bandwidth")),
    *(
        (name, 0.0)
        for name in (
            "pressure_offset",
            "pressure_gain_error",
            "leg_offset",
            "leg_gain_error",
            "ft_force_offset",
            "ft_torque_offset",
            "ft_gain_error",
        )
    ),
)
"""A plant without leaks, supply droop, valve jitter, sensor latency or sensor errors: what
each fault does shows alone."""


@dataclass
class Run:
    t: NDArray[np.float64]  # (n,) plant time of each sample (s)
    sensors: NDArray[np.float64]  # (n, 25) what the controller would read
    pressure: NDArray[np.float64]  # (n, 12) true chamber pressures (Pa abs)
    supply: NDArray[np.float64]  # (n,) true supply at the valves (Pa abs)
    legs: NDArray[np.float64]  # (n, 6) true piston displacements (m)
    hw: SimulatedHardware


def run(
    faults: tuple[str, ...] = (),
    seconds: float = 0.2,
    valves: tuple[int, ...] = (),
    patient: str = "absent",
    seed: int = 7,
) -> Run:
    """Run the plant with ``valves`` energised, sampling every sensor at 1 kHz."""
    hw = SimulatedHardware(PlantConfig(patient=patient, overrides=CLEAN), seed=seed)
    for spec in faults:
        hw.inject(parse_fault(spec))
    v = np.zeros(24, dtype=np.uint8)
    v[list(valves)] = 1
    hw.write_valves(v)
    rows: list[list[NDArray[np.float64]]] = [[], [], [], [], [], []]
    out = np.zeros(25)
    s = hw.state
    for k in range(round(seconds * 7000)):
        if k % 7 == 0:
            hw.read_sensors(out)
            rows[0].append(np.array([s.time[0]]))
            rows[1].append(out.copy())
            rows[2].append(s.pressure.copy())
            rows[3].append(s.supply[:1].copy())
            rows[4].append(KIN.inverse(s.pose) - hw.params.min_length)
        hw.wait_tick()
    t, sensors, pressure, supply, legs = (np.array(r) for r in rows[:5])
    return Run(t[:, 0], sensors, pressure, supply[:, 0], legs, hw)


# -- the vocabulary ----------------------------------------------------------------------


def test_parse_reads_every_part_of_a_spec() -> None:
    f = parse_fault("ft_offset@1:2=15")
    assert f == Fault(FaultKind.FT_OFFSET, 1.0, 2, 15.0)
    f = parse_fault(" Leg-Noise@2+0.3:4=0.5 ")
    assert (f.kind, f.time, f.duration, f.channel, f.value) == (
        FaultKind.LEG_NOISE,
        2.0,
        0.3,
        4,
        0.5,
    )
    assert f.end == pytest.approx(2.3)
    assert parse_fault("supply_loss@0.5") == Fault(FaultKind.SUPPLY_LOSS, 0.5)
    assert parse_fault("SUPPLY_DROOP@1").value == 3.5  # default droop, bar gauge
    assert parse_fault("chamber_leak@1:6").value == 0.1  # default, fraction of a valve's C
    assert parse_fault("ft_dead@0").channel == -1  # all six channels
    assert parse_fault("pressure_open@0.5:12").channel == 12  # the supply transducer


@pytest.mark.parametrize(
    "spec",
    [
        "supply_loss@0.5",
        "supply_droop@1.25=4",
        "pressure_open@0.5:3",
        "pressure_short@0:12",
        "pressure_stuck@0.1+0.2:0",
        "pressure_offset@2:11=-0.25",
        "leg_stuck@1.2:2",
        "leg_offset@1:5=2.5",
        "leg_noise@2+0.3:4=0.5",
        "ft_dead@3",
        "ft_saturated@3:5",
        "ft_offset@1:2=15",
        "valve_stuck_open@0.5:23",
        "valve_stuck_closed@0.5:0",
        "chamber_leak@1:6=0.2",
    ],
)
def test_format_and_parse_round_trip(spec: str) -> None:
    fault = parse_fault(spec)
    assert parse_fault(format_fault(fault)) == fault
    assert format_fault(fault) == format_fault(parse_fault(format_fault(fault)))
    assert describe(fault).startswith(("at ", "from "))


@pytest.mark.parametrize(
    ("spec", "complaint"),
    [
        ("bogus@1", "unknown kind 'bogus'; kinds: supply_loss, supply_droop"),
        ("supply_loss", "needs the form KIND@TIME"),
        ("supply_loss@soon", "time 'soon' is not a number"),
        ("supply_loss@-1", "time must be a finite number of seconds >= 0"),
        ("supply_loss@nan", "time must be"),
        ("supply_loss@1:3", "supply_loss takes no channel, got channel 3"),
        ("pressure_open@1", "needs a pressure transducer 0..11"),
        ("pressure_open@1:13", "channel 13 is not a pressure transducer"),
        ("pressure_open@1:two", "channel 'two' is not a whole number"),
        ("leg_stuck@1:6", "channel 6 is not a leg 0..5"),
        ("leg_stuck@1:2=3", "leg_stuck takes no value"),
        ("leg_offset@1:2", "leg_offset needs =VALUE (mm)"),
        ("leg_noise@1+0:2=1", "duration must be > 0"),
        ("leg_noise@1:2=-1", "noise in mm rms and must be > 0"),
        ("ft_dead@1:6", "channel 6 is not a force/torque channel"),
        ("valve_stuck_open@1:24", "channel 24 is not a valve 0..23"),
        ("chamber_leak@1:12", "channel 12 is not a chamber 0..11"),
        ("chamber_leak@1:3=0", "chamber_leak: value is the leak's conductance"),
        ("supply_droop@1=12", "drooped pressure, 0..9 bar gauge"),
        ("pressure_offset@1:2=inf", "value must be a finite number"),
    ],
)
def test_bad_specs_are_refused_with_a_sentence(spec: str, complaint: str) -> None:
    with pytest.raises(ValueError, match="fault ") as e:
        parse_fault(spec)
    message = str(e.value)
    assert complaint in message
    assert "\n" not in message and repr(spec) in message


def test_describe_names_the_part_in_words() -> None:
    # The channel as --fault counts it (from 0), the part as the device's events name it.
    said = describe(parse_fault("pressure_open@0.5:3"))
    assert "channel 3, the transducer of chamber 4 (leg 2, rod side)" in said
    assert "supply pressure transducer" in describe(parse_fault("pressure_open@0.5:12"))
    said = describe(parse_fault("valve_stuck_open@0:7"))
    assert "channel 7, the exhaust of chamber 4 (leg 2, rod side)" in said
    assert "the length sensor of leg 1" in describe(parse_fault("leg_stuck@1:0"))
    assert "force/torque channel Fz" in describe(parse_fault("ft_offset@1:2=15"))
    assert "for 0.3 s" in describe(parse_fault("leg_noise@2+0.3:4=0.5"))


def test_the_table_refuses_a_fault_too_many_and_a_droop_that_is_none() -> None:
    hw = SimulatedHardware(PlantConfig())
    for k in range(MAX_FAULTS):
        hw.inject(Fault(FaultKind.LEG_OFFSET, 1.0, k % 6, 1.0))
    with pytest.raises(ValueError, match="fault table is full"):
        hw.inject(Fault(FaultKind.FT_DEAD, 1.0))
    hw.clear_faults()
    hw.inject(Fault(FaultKind.FT_DEAD, 1.0))
    with pytest.raises(ValueError, match=r"supply is set to 5\.98675 bar gauge"):
        hw.inject(Fault(FaultKind.SUPPLY_DROOP, 1.0, -1, 6.0))


# -- no fault: the plant is what it was -----------------------------------------------------


def test_with_no_fault_the_same_seed_repeats_bit_for_bit() -> None:
    def final(seed: int) -> tuple[float, float, float]:
        hw = SimulatedHardware(PlantConfig(), seed=seed)
        out = np.zeros(25)
        v = np.zeros(24, np.uint8)
        for k in range(2100):
            if k % 7 == 0:
                hw.read_sensors(out)
            if k % 200 == 0:
                v[:] = 0
                v[(k // 200) % 24] = 1
            hw.write_valves(v)
            hw.wait_tick()
        return float(hw.state.pressure[0]), float(hw.state.pose[2]), float(out[21])

    assert final(3) == final(3)
    assert final(3) != final(4)  # the noise and the valves' jitter follow the seed


def test_a_fault_not_yet_due_changes_nothing() -> None:
    # The fault path runs (the table is not empty) but nothing in it acts yet.
    valves = (0, 3, 9, 14)
    healthy = run((), 0.1, valves)
    waiting = run(
        ("supply_loss@5", "chamber_leak@5:1", "valve_stuck_open@5:2", "ft_dead@5"), 0.1, valves
    )
    for a, b in (
        (healthy.sensors, waiting.sensors),
        (healthy.pressure, waiting.pressure),
        (healthy.legs, waiting.legs),
        (healthy.supply, waiting.supply),
    ):
        assert np.array_equal(a, b)


# -- sensor faults: what is read changes, the physics does not -------------------------------

MOVING = (8, 11)  # leg 2: cap intake on, rod exhaust on: it extends
T0 = 0.0505  # between two 1 kHz samples: the first faulty sample is unambiguous


def sensor_fault_run(
    spec: str, patient: str = "absent", seconds: float = 0.15
) -> tuple[Run, Run, NDArray[np.bool_]]:
    """(healthy twin, faulty run, mask of samples from T0 on) with the same noise."""
    healthy = run((), seconds, MOVING, patient)
    faulty = run((spec,), seconds, MOVING, patient)
    for a, b in (
        (healthy.pressure, faulty.pressure),
        (healthy.legs, faulty.legs),
        (healthy.supply, faulty.supply),
    ):
        assert np.array_equal(a, b), "a sensor fault changed the physics"
    after = faulty.t >= T0
    assert np.array_equal(healthy.sensors[~after], faulty.sensors[~after]), "acted before t0"
    return healthy, faulty, after


def only_channels_differ(healthy: Run, faulty: Run, channels: list[int]) -> None:
    others = [k for k in range(25) if k not in channels]
    assert np.array_equal(healthy.sensors[:, others], faulty.sensors[:, others])


def test_pressure_open_reads_zero_while_the_chamber_keeps_its_pressure() -> None:
    healthy, faulty, after = sensor_fault_run(f"pressure_open@{T0}:3")
    assert np.all(faulty.sensors[after, 3] == 0.0)
    assert np.all(faulty.pressure[after, 3] > 2e5)  # the air is still there
    only_channels_differ(healthy, faulty, [3])


def test_pressure_short_reads_full_scale() -> None:
    healthy, faulty, after = sensor_fault_run(f"pressure_short@{T0}:12")
    assert np.all(faulty.sensors[after, 12] == 1e6 * 4095 / 4096)
    assert np.array_equal(faulty.supply, healthy.supply)  # the supply itself is untouched
    only_channels_differ(healthy, faulty, [12])


def test_pressure_stuck_freezes_while_the_chamber_fills() -> None:
    healthy, faulty, after = sensor_fault_run(f"pressure_stuck@{T0}:4")  # leg 2 cap, filling
    frozen = faulty.sensors[after, 4]
    assert np.all(frozen == frozen[0])
    assert frozen[0] == healthy.sensors[after, 4][0]  # the reading it had at t0
    assert np.ptp(faulty.pressure[after, 4]) > 0.5e5  # while the truth moved by > 0.5 bar
    only_channels_differ(healthy, faulty, [4])


def test_pressure_offset_adds_its_bars_within_one_count() -> None:
    healthy, faulty, after = sensor_fault_run(f"pressure_offset@{T0}:1=0.5")
    lsb = 1e6 / 4096
    diff = faulty.sensors[after, 1] - healthy.sensors[after, 1]
    assert np.all(np.abs(diff - 0.5e5) <= lsb / 2 + 1e-6)
    only_channels_differ(healthy, faulty, [1])


def test_leg_stuck_reads_constant_while_the_leg_moves() -> None:
    healthy, faulty, after = sensor_fault_run(f"leg_stuck@{T0}:2")
    reading = faulty.sensors[after, 13 + 2]
    assert np.all(reading == reading[0])
    assert np.ptp(faulty.legs[after, 2]) > 2e-3  # the piston travelled more than 2 mm
    assert np.ptp(healthy.sensors[after, 13 + 2]) > 2e-3
    only_channels_differ(healthy, faulty, [15])


def test_leg_offset_adds_its_millimetres_within_one_count() -> None:
    healthy, faulty, after = sensor_fault_run(f"leg_offset@{T0}:0=2")
    lsb = 0.1 / 4096
    diff = faulty.sensors[after, 13] - healthy.sensors[after, 13]
    assert np.all(np.abs(diff - 2e-3) <= lsb / 2 + 1e-9)
    only_channels_differ(healthy, faulty, [13])


def test_leg_noise_is_a_burst_of_the_given_rms() -> None:
    healthy = run((), 0.3, MOVING)
    faulty = run(("leg_noise@0.1+0.1:1=0.5",), 0.3, MOVING)
    assert np.array_equal(healthy.legs, faulty.legs)
    burst = (faulty.t >= 0.1) & (faulty.t < 0.2)
    err = faulty.sensors[burst, 14] - faulty.legs[burst, 1]
    assert 0.4e-3 < np.std(err) < 0.6e-3  # 100 samples of 0.5 mm rms
    quiet = faulty.t >= 0.2
    err = faulty.sensors[quiet, 14] - faulty.legs[quiet, 1]
    assert np.abs(err).max() < 0.05e-3  # the burst is over: 5 um noise and 24 um counts
    assert np.array_equal(healthy.sensors[faulty.t < 0.1], faulty.sensors[faulty.t < 0.1])


def test_ft_dead_reads_zeros() -> None:
    healthy, faulty, after = sensor_fault_run(f"ft_dead@{T0}", "relaxed")
    assert np.all(faulty.sensors[after, 19:25] == 0.0)
    # The foot still bears on the healthy sensor (its force crosses zero once while the
    # valves throw the platform about).
    assert np.mean(np.abs(healthy.sensors[after, 21]) > 5.0) > 0.95
    only_channels_differ(healthy, faulty, list(range(19, 25)))


def test_ft_saturated_reads_full_scale() -> None:
    healthy, faulty, after = sensor_fault_run(f"ft_saturated@{T0}")
    fxy, fz, t = (PARAMETERS[n].value for n in ("force_range_xy", "force_range_z", "torque_range"))
    assert np.all(faulty.sensors[after, 19:25] == [fxy, fxy, fz, t, t, t])
    healthy, faulty, after = sensor_fault_run(f"ft_saturated@{T0}:2")
    assert np.all(faulty.sensors[after, 21] == fz)
    only_channels_differ(healthy, faulty, [21])


def test_ft_offset_adds_its_newtons_within_one_count() -> None:
    healthy, faulty, after = sensor_fault_run(f"ft_offset@{T0}:2=15", "relaxed")
    diff = faulty.sensors[after, 21] - healthy.sensors[after, 21]
    assert np.all(np.abs(diff - 15.0) <= 1 / 32 + 1e-9)
    only_channels_differ(healthy, faulty, [21])


def test_a_fault_with_a_duration_ends() -> None:
    healthy = run((), 0.15, MOVING)
    faulty = run(("leg_offset@0.05+0.05:3=5",), 0.15, MOVING)
    during = (faulty.t >= 0.05) & (faulty.t < 0.1)
    assert np.all(faulty.sensors[during, 16] - healthy.sensors[during, 16] > 4.9e-3)
    assert np.array_equal(faulty.sensors[~during], healthy.sensors[~during])


# -- physical faults -------------------------------------------------------------------------


def test_supply_loss_vents_the_supply_within_tens_of_milliseconds() -> None:
    r = run(("supply_loss@0.05",), 0.2)  # valves closed
    before = r.t < 0.05
    assert np.all(r.supply[before] == 7e5)
    assert np.all(np.abs(r.sensors[before, 12] - 7e5) < 1000.0)
    t_below = r.t[np.argmax(r.supply < 2e5)] - 0.05
    assert 0.02 < t_below < 0.06  # choked blowdown of 50 cm3 through C = 2 dm3/(s bar)
    late = r.t > 0.05 + 0.1
    assert np.all(r.supply[late] < 1.1e5)
    assert np.all(r.sensors[late, 12] < 1.1e5)
    # Closed valves hold the chambers: the cylinders do not notice.
    assert np.abs(r.pressure[-1] - r.pressure[0]).max() < 0.02e5


def test_after_supply_loss_an_open_intake_empties_its_chamber() -> None:
    r = run(("supply_loss@0.02",), 0.3, valves=(0,))
    peak = r.pressure[:, 0].max()
    assert peak > 4.5e5  # filled while the supply was there
    assert r.pressure[-1, 0] < 2.0e5  # then blew back through the intake into the vented line


def test_supply_droop_settles_at_its_gauge_pressure() -> None:
    r = run(("supply_droop@0.05=3.5",), 3.0)
    assert np.all(r.supply[r.t < 0.05] == 7e5)
    # Half a second later it has fallen by about 1 - 1/e of the 2.5 bar step.
    at = np.argmax(r.t >= 0.55)
    assert 7e5 - 0.75 * 2.5e5 < r.supply[at] < 7e5 - 0.5 * 2.5e5
    assert r.supply[-1] == pytest.approx(4.5e5 + 1325, abs=0.05e5)
    assert r.sensors[-1, 12] == pytest.approx(4.5e5 + 1325, abs=0.05e5)


def test_a_cleared_supply_fault_recovers_to_its_setting() -> None:
    hw = SimulatedHardware(PlantConfig(patient="absent", overrides=CLEAN))
    hw.inject(parse_fault("supply_loss@0"))
    for _ in range(700):
        hw.wait_tick()
    assert hw.state.supply[0] < 2e5
    hw.clear_faults()
    for _ in range(3500):
        hw.wait_tick()
    assert hw.state.supply[0] == pytest.approx(7e5, abs=100.0)  # refilled through the line


def test_valve_stuck_open_fills_the_chamber_with_its_coil_off() -> None:
    r = run(("valve_stuck_open@0.05:0",), 0.15)  # intake of leg 0's cap side, coils off
    p0 = r.pressure[0, 0]
    assert np.abs(r.pressure[r.t < 0.05, 0] - p0).max() < 0.01e5
    assert r.pressure[-1, 0] > p0 + 1.5e5
    assert r.pressure[-1, 0] < 7e5 + 1.0


def test_valve_stuck_closed_holds_the_chamber_with_its_coil_on() -> None:
    healthy = run((), 0.1, valves=(2,))  # intake of leg 0's rod side
    stuck = run(("valve_stuck_closed@0:2",), 0.1, valves=(2,))
    assert healthy.pressure[-1, 1] > healthy.pressure[0, 1] + 1.5e5
    assert abs(stuck.pressure[-1, 1] - stuck.pressure[0, 1]) < 0.05e5
    assert stuck.hw.state.valve_open[2] == 0.0 and stuck.hw.state.valve_cmd[2] == 1.0


def test_a_leak_empties_a_closed_chamber_and_the_leg_gives_way() -> None:
    healthy = run((), 0.35)
    leaky = run(("chamber_leak@0.05:1",), 0.35)  # leg 0 rod side, valves closed
    before = leaky.t < 0.05
    assert np.array_equal(healthy.pressure[before], leaky.pressure[before])
    assert np.ptp(healthy.pressure[:, 1]) < 0.01e5 and np.ptp(healthy.legs[:, 0]) < 0.1e-3
    # Measured: 4.01 -> 3.51 bar abs in 0.3 s, the leg extends 7 mm as its rod side empties.
    assert leaky.pressure[-1, 1] < leaky.pressure[0, 1] - 0.3e5
    assert leaky.legs[-1, 0] - leaky.legs[0, 0] > 4e-3
    # A leak of twice the conductance empties it faster.
    faster = run(("chamber_leak@0.05:1=0.2",), 0.35)
    assert faster.pressure[-1, 1] < leaky.pressure[-1, 1] - 0.2e5


def test_fault_times_are_plant_time_and_channels_are_zero_based() -> None:
    hw = SimulatedHardware(PlantConfig())
    hw.inject(Fault(FaultKind.PRESSURE_OPEN, 2 * TICK, 0))
    out = np.zeros(25)
    hw.read_sensors(out)
    assert out[0] > 0.0
    hw.wait_tick()
    hw.wait_tick()
    hw.read_sensors(out)
    assert out[0] == 0.0 and out[1] > 0.0
    assert math.isnan(hw.state.faults[0, 5])  # a stuck reading is kept only for stuck kinds


def test_the_controller_sees_a_sensor_fault_in_the_compiled_loop() -> None:
    # Through Rig (controller and plant compiled together, tickloop.run_sim): before t0 the
    # controller's leg reading is the true piston; at t0 it jumps 2 mm, more than a leg moves
    # between two reads, and the controller names leg 1's sensor (its last good reading is
    # then kept: a sensor named faulty is not read again until a re-arm).
    from device import tickloop
    from device.rig import Rig
    from device.safety import Trip

    hw = SimulatedHardware(PlantConfig(), seed=11)
    rig = Rig(hw)
    rig.run(0.05)
    rig.move_legs(rig.state.leg_x.copy())
    rig.run(0.2)
    t0 = float(hw.state.time[0]) + 0.0505
    hw.inject(Fault(FaultKind.LEG_OFFSET, t0, 1, 2.0))
    log = rig.run(0.2)
    t = log[:, tickloop.COL["t"]]
    seen_minus_true = log[:, tickloop.COL["leg_meas1"]] - log[:, tickloop.COL["leg_x1"]]
    assert np.abs(seen_minus_true[t < t0]).max() < 0.1e-3
    assert (rig.trip, rig.trip_channel) == (Trip.LEG_SENSOR, 1)
    tripped = t[log[:, tickloop.COL["trip"]] == int(Trip.LEG_SENSOR)]
    assert t0 <= tripped.min() <= t0 + 0.002  # at the first read past t0 (1 kHz)
    assert np.abs(seen_minus_true).max() < 0.1e-3
