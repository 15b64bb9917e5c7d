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


def closed_valves() -> np.ndarray:
    return np.zeros(24, dtype=np.uint8)


def run(s: model.PlantState, p: PlantParams, ticks: int, valves: np.ndarray | None = None) -> None:
    if valves is not None:
        model.write_valves(s, valves)
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


def test_a_pulse_shorter_than_the_valve_delay_passes_nothing() -> None:
    s = model.new_state(P)
    before = s.pressure.copy()
    v = closed_valves()
    v[0] = 1  # intake of leg 1's cap chamber
    run(s, P, 5, v)  # 0.71 ms < 0.8 ms delay
    run(s, P, 30, closed_valves())
    assert s.valve_open.max() == 0.0
    assert s.pressure[0] == pytest.approx(before[0], rel=1e-3)


def test_a_long_pulse_opens_after_delay_plus_travel_and_fills() -> None:
    s = model.new_state(P)
    v = closed_valves()
    v[0] = 1
    run(s, P, 7, v)  # 1.0 ms: delay 0.8 + travel 0.2
    assert s.valve_open[0] == pytest.approx(1.0)
    p0 = s.pressure[0]
    run(s, P, 200)
    assert s.pressure[0] > p0 + 0.5e5
    assert s.pressure[0] <= P.p_supply + 1.0


def test_a_gap_shorter_than_the_delay_never_closes_the_valve() -> None:
    s = model.new_state(P)
    on = closed_valves()
    on[0] = 1
    run(s, P, 14, on)
    run(s, P, 4, closed_valves())  # 0.57 ms off
    assert s.valve_open[0] == pytest.approx(1.0)


def test_open_open_is_refused_by_the_valve_driver() -> None:
    s = model.new_state(P)
    v = closed_valves()
    v[0] = v[1] = 1
    model.write_valves(s, v)
    assert s.valve_cmd[0] == 0.0 and s.valve_cmd[1] == 0.0


def test_static_pressures_hold_the_platform_still() -> None:
    s = model.new_state(P)
    home = s.pose.copy()
    run(s, P, 7000)
    assert np.abs(s.pose - home).max() < 1e-6


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
    s = model.new_state(P_ABSENT)
    # Add 1.0 N along leg 1 (below the 1.5 N breakaway): the piston must not slide.
    s.pressure[0] += 1.0 / P_ABSENT.area_cap
    x0 = Kinematics().inverse(s.pose)[0]
    run(s, P_ABSENT, 3500)
    assert abs(Kinematics().inverse(s.pose)[0] - x0) < 30e-6
    # 20 N is far above it: it moves.
    s.pressure[0] += 20.0 / P_ABSENT.area_cap
    run(s, P_ABSENT, 700)
    assert Kinematics().inverse(s.pose)[0] - x0 > 0.5e-3


def test_force_sensor_reads_foot_weight_and_preload_at_rest() -> None:
    s = model.new_state(P)
    model.seed(5)
    out = np.zeros(25)
    model.read_sensors(s, P, out)
    weight = PARAMETERS["foot_mass"].value * 9.81 + PARAMETERS["shank_preload"].value
    assert out[21] == pytest.approx(-weight, abs=0.3)
    # The foot's centre of mass lies ahead of the sensor: a toe-down moment about +y.
    assert out[23] == pytest.approx(PARAMETERS["foot_mass"].value * 9.81 * 0.05, abs=0.02)
    assert out[12] == pytest.approx(P.p_supply, abs=1000.0)
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
    assert not math.isnan(build_params(PlantConfig(patient="resisting")).patient_k[4])


def test_docs_table_is_the_code_table() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "plant.md").read_text()
    assert parameter_table_markdown() in doc
