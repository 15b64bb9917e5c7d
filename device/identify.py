"""Start-up identification: what the controller may not assume about this unit.

A device built to the drawing still differs from it: each leg sensor's zero moves with its
mounting, each pressure transducer's zero is off by a fraction of a percent of its range,
and the force sensor's zero drifts between uses. The controller's model cannot know these;
the unit can measure them, with nobody on the plate, before it is armed:

1. **Down to the stops.** Each leg's rod side fills and its cap side vents, in short pulses
   first (the controller's release pattern, so the platform comes down slowly and level),
   then fully: every piston is pulled onto its lower end stop, where its displacement is
   zero. Gravity alone is not enough: on a build with stiff seals the legs' breakaway
   friction together exceeds the platform's weight, and a platform left to sink stops
   tilted and twisted with some legs in mid-stroke.
2. **Vent.** Every exhaust opens, every intake stays shut: the chambers fall to the
   atmosphere, and the end stops' bumpers relax until friction holds them (microns).
3. **Read at rest.** The average of :data:`READS` readings of every channel: each leg
   sensor's reading at its end stop is its zero; each chamber transducer's reading less
   the atmosphere is its zero; the force sensor's reading with nothing on the plate is
   its zero.

The result is a :class:`~device.calibration.Calibration`: saved as JSON, loaded by the device
(``ankle device --calibration FILE``), applied by the controller to every reading
(``ControllerConfig.calibration``) and reported in ``DeviceHello``. It runs through the
:class:`~device.hardware.Hardware` interface only (sensors in, valves out), so it is the
same routine on the simulation and on an I/O board.

What it does not identify (yet): the valves' own dead times, the platform's mass and centre
of mass (the outer loop's integral takes up their static part), the sensors' span errors.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import UTC, datetime

import numpy as np
from numpy.typing import NDArray

from device import signals
from device.calibration import Calibration, IdentificationError
from device.controller import ControllerConfig
from device.hardware import Hardware
from device.plant.params import TICK_HZ

READS = 200
"""Readings averaged at rest (0.2 s at 1 kHz): the noise of the mean is 1/14 of one
reading's (5 um on a leg, 7 Pa on a chamber)."""
SENSOR_PERIOD_TICKS = 7
DOWN_PULSE_S = 2.5
"""Pull down in pulses first: each rod-side intake and cap-side exhaust open in the
controller's release pattern (``ControllerConfig.vent_pulse_slots`` of 28 slots, once every
``vent_every_periods`` PWM periods): the legs come down slowly."""
DOWN_OPEN_S = 0.5
"""Then fully open: every piston pressed onto its stop."""
VENT_OPEN_S = 1.0
"""Then every exhaust open: the chambers reach the atmosphere."""
SETTLED_SPEED = 2.0e-3
"""The legs count as resting on their stops when none moved faster than this (m/s) over
the last 0.1 s of the vent; otherwise the identification fails."""


def identify(
    hardware: Hardware,
    atmosphere: float = 1.01325e5,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Vent the unit and read its zeros (see the module docstring). Nobody may stand on
    the plate: the platform sinks to its stops. Leaves every valve closed."""
    sensors = np.zeros(signals.N_SENSORS)
    valves = np.zeros(signals.N_VALVES, dtype=np.uint8)
    history: list[NDArray[np.float64]] = []
    tick = 0
    slots = 28

    def step(pattern: NDArray[np.uint8]) -> None:
        nonlocal tick
        if tick % SENSOR_PERIOD_TICKS == 0:
            hardware.read_sensors(sensors)
            history.append(sensors.copy())
        hardware.write_valves(pattern)
        hardware.wait_tick()
        tick += 1

    down = np.zeros(signals.N_VALVES, dtype=np.uint8)
    down[1::4] = 1  # each cap side's exhaust (chamber 2i: valves 4i, 4i + 1)
    down[2::4] = 1  # each rod side's intake (chamber 2i + 1: valves 4i + 2, 4i + 3)
    if progress:
        progress("identification: legs down to their end stops")
    try:
        pulse, every = ControllerConfig.vent_pulse_slots, ControllerConfig.vent_every_periods
        for _ in range(int(DOWN_PULSE_S * TICK_HZ)):
            slot, period = tick % slots, tick // slots
            step(down if slot < pulse and period % every == 0 else valves)
        for _ in range(int(DOWN_OPEN_S * TICK_HZ)):
            step(down)
        valves[1::2] = 1
        for _ in range(int(VENT_OPEN_S * TICK_HZ)):
            step(valves)
        legs = np.array([h[signals.SENSOR_LEG : signals.SENSOR_LEG + 6] for h in history[-101:]])
        speed = np.abs(legs[-1] - legs[0]) / 0.1
        if np.any(speed > SETTLED_SPEED):
            worst = int(np.argmax(speed))
            raise IdentificationError(
                f"leg {worst + 1} still moves at {speed[worst] * 1e3:.1f} mm/s after venting: "
                "is something on the plate or holding the platform?"
            )
        if progress:
            progress("identification: reading the zeros")
        history.clear()
        while len(history) < READS:
            step(valves)
    finally:
        hardware.write_valves(np.zeros(signals.N_VALVES, dtype=np.uint8))
    mean = np.mean(np.array(history), axis=0)
    cal = Calibration(
        leg_zero=tuple(float(v) for v in mean[signals.SENSOR_LEG : signals.SENSOR_LEG + 6]),
        pressure_zero=tuple(float(v - atmosphere) for v in mean[:12]),
        ft_zero=tuple(float(v) for v in mean[signals.SENSOR_FORCE : signals.SENSOR_FORCE + 6]),
        identified_at=datetime.now(UTC).isoformat(timespec="seconds"),
    )
    cal.check()
    return cal
