"""Physics of the plant simulation: each piece against what physics says it must do."""

import itertools
import math

import numpy as np
import pytest

from device.kinematics import Kinematics
from device.plant import model
from device.plant.params import (
    PARAMETERS,
    PlantConfig,
    PlantParams,
    build_params,
    parameter_table_markdown,
)

P = build_params()
P_ABSENT = build_params(PlantConfig(patient="absent"))
TIGHT = (("valve_seat_leak", 0.0), ("piston_leak", 0.0))
"""A plant without leaks, for tests of what holds still."""
TICK = 1.0 / 7000.0


def closed_valves() -> np.ndarray:
    return np.zeros(24, dtype=np.uint8)


def run(s: model.PlantState, p: PlantParams, ticks: int, valves: np.ndarray | None = None) -> None:
    if valves is not None:
        model.write_valves(s, p, valves)
    for _ in range(ticks):
        model.plant_tick(s, p)


def test_iso6358_choked_flow_and_rating() -> None:
    choked = model.iso6358_mass_flow(7e5, 1e5, 1.0, P)
    assert choked == pytest.approx(P.conductance * P.rho_anr * 7e5, rel=1e-6)
    # Rated flow of the Matrix valve: about 100 NL/min (6 bar gauge in, 5 bar gauge out).
    rated = model.iso6358_mass_flow(7e5 + 1325, 6e5 + 1325, 1.0, P) / P.rho_anr * 60e3
    assert 70.0 < rated < 130.0


def test_iso6358_flow_is_continuous_signed_and_zero_at_balance() -> None:
    assert model.iso6358_mass_flow(5e5, 5e5, 1.0, P) == 0.0
    assert model.iso6358_mass_flow(3e5, 5e5, 1.0, P) == pytest.approx(
        -model.iso6358_mass_flow(5e5, 3e5, 1.0, P)
    )
    for ratio in (P.critical_ratio, P.laminar_ratio):
        lo = model.iso6358_mass_flow(5e5, 5e5 * (ratio - 1e-9), 1.0, P)
        hi = model.iso6358_mass_flow(5e5, 5e5 * (ratio + 1e-9), 1.0, P)
        assert lo == pytest.approx(hi, rel=1e-4)
    ratios = np.linspace(0.0, 1.0, 200)
    flows = [model.iso6358_mass_flow(5e5, 5e5 * r, 1.0, P) for r in ratios]
    assert all(a >= b - 1e-15 for a, b in itertools.pairwise(flows))


P_STEADY = build_params(PlantConfig(overrides=(("valve_jitter", 0.0),)))
"""Valves without jitter: each switching takes exactly its valve's own delay."""


def test_a_pulse_shorter_than_the_valve_delay_passes_nothing() -> None:
    p = P_STEADY
    s = model.new_state(p)
    before = s.pressure.copy()
    v = closed_valves()
    v[0] = 1  # intake of leg 1's cap chamber
    ticks = math.floor(p.valve_open_delay[0] / TICK) - 1
    assert ticks >= 3
    run(s, p, ticks, v)
    run(s, p, 30, closed_valves())
    assert s.valve_open.max() == 0.0
    assert s.pressure[0] == pytest.approx(before[0], rel=1e-3)


def test_a_long_pulse_opens_after_delay_plus_travel_and_fills() -> None:
    p = P_STEADY
    s = model.new_state(p)
    v = closed_valves()
    v[0] = 1
    run(s, p, math.ceil((p.valve_open_delay[0] + p.valve_travel) / TICK) + 1, v)
    assert s.valve_open[0] == pytest.approx(1.0)
    p0 = s.pressure[0]
    run(s, p, 200)
    assert s.pressure[0] > p0 + 0.5e5
    assert s.pressure[0] <= p.p_supply + 1.0


def test_a_gap_shorter_than_the_delay_never_closes_the_valve() -> None:
    p = P_STEADY
    s = model.new_state(p)
    on = closed_valves()
    on[0] = 1
    run(s, p, 14, on)
    run(s, p, math.floor(p.valve_close_delay[0] / TICK) - 1, closed_valves())
    assert s.valve_open[0] == pytest.approx(1.0)


def test_each_valve_has_its_own_delays_and_the_unit_decides_them() -> None:
    a, b = build_params(PlantConfig(unit=0)), build_params(PlantConfig(unit=1))
    spread = PARAMETERS["valve_delay_spread"].value
    for p in (a, b):
        assert len(set(p.valve_open_delay)) == 24  # every valve differs
        nominal = PARAMETERS["valve_open_delay"].value
        assert np.all(np.abs(p.valve_open_delay / nominal - 1.0) <= spread + 1e-12)
        assert np.all(p.valve_close_delay != p.valve_open_delay)
    assert not np.array_equal(a.valve_open_delay, b.valve_open_delay)
    assert np.array_equal(a.valve_open_delay, build_params(PlantConfig(unit=0)).valve_open_delay)
    assert not np.array_equal(a.sensor_offset, b.sensor_offset)


def test_jitter_varies_each_switching_around_the_valves_own_delay() -> None:
    p = build_params(PlantConfig(overrides=(("valve_jitter", 0.1e-3),)))
    s = model.new_state(p)
    model.seed(3)
    delays = []
    for _ in range(200):
        v = closed_valves()
        v[0] = 1
        model.write_valves(s, p, v)
        delays.append(s.valve_delay_now[0])
        model.write_valves(s, p, closed_valves())
    assert np.mean(delays) == pytest.approx(p.valve_open_delay[0], abs=0.03e-3)
    assert np.std(delays) == pytest.approx(0.1e-3, rel=0.2)
    assert s.valve_switches[0] == 200


def test_open_open_is_refused_by_the_valve_driver() -> None:
    s = model.new_state(P)
    v = closed_valves()
    v[0] = v[1] = 1
    model.write_valves(s, P, v)
    assert s.valve_cmd[0] == 0.0 and s.valve_cmd[1] == 0.0


def test_static_pressures_hold_the_platform_still() -> None:
    p = build_params(PlantConfig(overrides=TIGHT))
    s = model.new_state(p)
    home = s.pose.copy()
    run(s, p, 7000)
    assert np.abs(s.pose - home).max() < 1e-6


def test_a_leaking_piston_passes_air_from_the_higher_side_and_the_platform_sinks() -> None:
    p = build_params(PlantConfig(patient="absent", overrides=(("valve_seat_leak", 0.0),)))
    s = model.new_state(p)
    before = s.pressure.copy()
    z0 = s.pose[2]
    run(s, p, 7000)
    # At home the rod sides hold half the supply and the cap sides less: air goes cap-ward.
    hi = before[1::2] > before[0::2]
    assert np.all(hi)
    assert np.all(s.pressure[0::2] > before[0::2])
    assert s.pose[2] != z0


def test_the_tube_delays_the_cylinder_but_not_the_transducer_at_the_valves() -> None:
    p = build_params(PlantConfig(patient="absent", overrides=(*TIGHT, ("valve_jitter", 0.0))))
    delay = PARAMETERS["tube_length"].value / PARAMETERS["speed_of_sound"].value
    assert p.tube_steps == round(delay / (TICK / p.substeps))
    s = model.new_state(p)
    before = s.pressure[0]
    v = closed_valves()
    v[0] = 1
    opened = math.ceil((p.valve_open_delay[0] + p.valve_travel) / TICK)
    run(s, p, opened, v)
    out = np.zeros(25)
    model.read_sensors(s, p, out)
    run(s, p, math.floor(delay / TICK) - 2 - 0, v)
    assert s.pressure[0] == pytest.approx(before, abs=50.0)  # still on its way
    true = np.zeros(25)
    model.true_readings(s, p, true)
    assert true[0] > before + 0.1e5  # the transducer by the valve sees it already
    run(s, p, 10, v)
    assert s.pressure[0] > before + 0.1e5  # and then the cylinder


def test_a_sensor_reads_its_delayed_filtered_value_with_its_units_errors() -> None:
    p = build_params(
        PlantConfig(
            patient="absent",
            overrides=(*TIGHT, ("pressure_delay", 2e-3), ("pressure_bandwidth", 1e4)),
        )
    )
    s = model.new_state(p)
    out, true = np.zeros(25), np.zeros(25)
    model.seed(1)
    reads, truths = [], []
    for i in range(12):
        if i == 6:
            s.pressure[4] += 1.0e5  # a jump of one bar
        model.true_readings(s, p, true)
        truths.append(true[4])
        model.read_sensors(s, p, out)
        reads.append(out[4])
        run(s, p, 7)  # reads 1 ms apart
    for i in range(2, 12):  # each read is the true value two reads (2 ms) before
        assert reads[i] == pytest.approx(
            truths[i - 2] * p.sensor_gain[4] + p.sensor_offset[4], abs=600.0
        )
    assert reads[7] < truths[6] - 0.5e5  # the jump is not seen at once


def test_the_manifold_droops_while_intakes_draw_and_the_air_is_counted() -> None:
    p = build_params(PlantConfig(patient="absent", overrides=TIGHT))
    s = model.new_state(p)
    v = closed_valves()
    v[0:24:4] = 1  # the cap-side intake of every leg
    v[3:24:4] = 1  # and the rod-side exhaust: all six legs extend
    run(s, p, 35, v)
    assert s.supply[0] < p.p_supply - 0.2e5
    assert s.air[0] > 0.0 and s.air[1] > 0.0
    assert s.valve_switches[0] == 1 and s.valve_switches[1] == 0


def test_exhaust_vents_a_chamber_to_atmosphere() -> None:
    s = model.new_state(P_ABSENT)
    v = closed_valves()
    v[1::2] = 1  # every exhaust
    run(s, P_ABSENT, 7000, v)
    assert np.all(np.abs(s.pressure - P_ABSENT.p_atm) < 2000.0)
    # With no air the platform's weight drives every piston onto its lower end stop.
    L = Kinematics().inverse(s.pose) - P_ABSENT.min_length
    assert np.all(L < 0.5e-3)


def test_friction_holds_below_breakaway() -> None:
    p_tight = build_params(PlantConfig(patient="absent", overrides=TIGHT))
    s = model.new_state(p_tight)
    # Add 1.0 N along leg 1 (below the 1.5 N breakaway): the piston must not slide.
    s.pressure[0] += 1.0 / p_tight.area_cap
    x0 = Kinematics().inverse(s.pose)[0]
    run(s, p_tight, 3500)
    assert abs(Kinematics().inverse(s.pose)[0] - x0) < 30e-6
    # 20 N is far above it: it moves.
    s.pressure[0] += 20.0 / p_tight.area_cap
    run(s, p_tight, 700)
    assert Kinematics().inverse(s.pose)[0] - x0 > 0.5e-3


def test_force_sensor_reads_foot_weight_and_preload_at_rest() -> None:
    s = model.new_state(P)
    model.seed(5)
    out = np.zeros(25)
    model.read_sensors(s, P, out)
    weight = PARAMETERS["foot_mass"].value * 9.81 + PARAMETERS["shank_preload"].value
    assert out[21] == pytest.approx(-weight * P.sensor_gain[21] + P.sensor_offset[21], abs=0.3)
    # The foot's centre of mass lies ahead of the sensor: a toe-down moment about +y.
    moment = PARAMETERS["foot_mass"].value * 9.81 * 0.05
    assert out[23] == pytest.approx(moment * P.sensor_gain[23] + P.sensor_offset[23], abs=0.02)
    assert out[12] == pytest.approx(
        P.p_supply * P.sensor_gain[12] + P.sensor_offset[12], abs=1000.0
    )
    lsb = P.leg_lsb
    assert np.allclose(np.round(out[13:19] / lsb) * lsb, out[13:19])


def test_two_substeps_agree_with_eight() -> None:
    results = []
    for n in (2, 8):
        p = build_params(PlantConfig(patient="absent", substeps=n))
        s = model.new_state(p)
        v = closed_valves()
        v[0] = 1  # fill leg 1's cap side, vent its rod side
        v[3] = 1
        run(s, p, 70, v)
        run(s, p, 700, closed_valves())
        results.append((s.pose.copy(), s.pressure.copy()))
    (pose2, p2), (pose8, p8) = results
    assert np.abs(pose2[:3] - pose8[:3]).max() < 0.05e-3  # well below the 0.024 mm sensor LSB
    assert np.abs(p2 - p8).max() < 1000.0  # 10 mbar, ten sensor noise sigmas


def test_parameter_table_is_complete_and_documented() -> None:
    table = parameter_table_markdown()
    for p in PARAMETERS.values():
        assert p.reason and p.unit
        assert f"`{p.name}`" in table
    with pytest.raises(ValueError, match="unknown plant parameter"):
        build_params(PlantConfig(overrides=(("bogus", 1.0),)))
    for bad in (("bore", -1.0), ("valve_travel", 0.0), ("leg_delay", math.nan), ("leg_delay", 1.0)):
        with pytest.raises(ValueError, match=bad[0]):
            build_params(PlantConfig(overrides=(bad,)))


def test_a_drawn_plant_stays_in_the_documented_ranges_and_repeats() -> None:
    from device.plant.params import draw_plant

    a, b = draw_plant(7), draw_plant(7)
    assert a == b and a != draw_plant(8)
    assert a.unit == 7
    drawn = dict(a.overrides)
    for p in PARAMETERS.values():
        if p.varies:
            assert p.low is not None and p.high is not None
            assert p.low <= drawn[p.name] <= p.high
            assert p.low <= p.value <= p.high, p.name  # the nominal lies in its range
        else:
            assert p.name not in drawn
    build_params(a)
    assert not math.isnan(build_params(PlantConfig(patient="resisting")).patient_k[4])


def test_docs_table_is_the_code_table() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "plant.md").read_text()
    assert parameter_table_markdown() in doc
