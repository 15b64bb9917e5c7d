"""Release (slow vent) after a stop: exhaust pulses only, gentle sinking, no trips."""

import numpy as np
import pytest
from numpy.typing import NDArray

from device import controller as ctl
from device import pwm
from device.controller import ControllerConfig, Mode
from device.hardware import SimulatedHardware
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
