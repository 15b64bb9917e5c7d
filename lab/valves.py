"""How often the valves switch and how much air the device uses, at rest and exercising.

The plant counts every coil energisation per valve and integrates the mass of air through
the supply line (``device.plant.model``: ``valve_switches``, ``air``), so both come from the
physics, not from the controller's intentions.

Two schemes, measured in the same run: ``quiet`` (the device's: a leg at rest closes its
valves and is held by its trapped air, corrected by single doses; device.quiet) and
``wave1`` (a minimum pulse on every chamber every period, the dead-band-compensated PWM's
dither).

Air is reported in NL/min at the supply: normal litres (ISO 8778, 1.185 kg/m3), what a
compressor's rating is given in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from device.controller import ControllerConfig, Waveform
from device.hardware import SimulatedHardware
from device.rig import AxisTarget, Rig
from lab import experiments

RHO_NORMAL = 1.185
"""kg/m3 of air at ISO 8778 reference conditions (20 C, 1 bar, 65 % humidity)."""
SETTLE_S = 1.0
"""Held at home this long before the rest window (the outer integral settles)."""
WINDOW_S = 3.0
"""Length of each measured window (s)."""
EXERCISE_DEG = 10.0
"""The exercise: pitch sine of this amplitude at 0.5 Hz, a typical range-of-motion drill."""


@dataclass(frozen=True)
class Activity:
    scheme: str
    """Which valve scheme (:data:`SCHEMES`)."""
    situation: str
    """``rest`` (held at home) or ``exercise`` (pitch 10 deg at 0.5 Hz)."""
    switches_per_s_mean: float
    """Coil energisations per second per valve, mean over the 24 valves."""
    switches_per_s_max: float
    """The busiest valve's."""
    air_nl_per_min: float
    """Air through the supply line."""
    steady_error_mm: float
    """Largest distance of a leg's measured length from its target, averaged over the
    window (rest only; NaN exercising)."""
    trip: str | None


SCHEMES = ("quiet", "wave1")
"""The valve schemes the controller has: the quiet hold (the default) and wave 1's."""


def _config(scheme: str) -> ControllerConfig:
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, not {scheme!r}")
    return ControllerConfig(quiet_hold=scheme == "quiet")


def measure(scheme: str, situation: str, seed: int = 1) -> Activity:
    """One window of ``situation`` under ``scheme`` on the current plant
    (``lab.experiments.on_plant``), calibrated as the device calibrates itself."""
    choice = experiments.current_plant()
    cfg = choice.config("relaxed")
    config = _config(scheme)
    if choice.calibrate:  # first: identifying seeds the plant's random generator itself
        config = replace(config, calibration=experiments.calibration_of(cfg))
    hw = SimulatedHardware(cfg, seed=seed if choice.seed is None else choice.seed)
    rig = Rig(hw, config)
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(SETTLE_S, log_hz=0)
    if situation == "exercise":
        rig.track({"pitch": AxisTarget(Waveform.SINE, 0.0, math.radians(EXERCISE_DEG), 0.5)})
        rig.run(1.0, log_hz=0)
    elif situation != "rest":
        raise ValueError(f"situation must be rest or exercise, not {situation!r}")
    switches0 = hw.state.valve_switches.copy()
    air0 = float(hw.state.air[0])
    errors = []
    steps = 100
    for _ in range(steps):
        rig.run(WINDOW_S / steps, log_hz=0)
        errors.append(np.abs(rig.state.leg_target - rig.state.leg_x).max())
    per_valve = (hw.state.valve_switches - switches0) / WINDOW_S
    air_kg = float(hw.state.air[0]) - air0
    return Activity(
        scheme=scheme,
        situation=situation,
        switches_per_s_mean=float(per_valve.mean()),
        switches_per_s_max=float(per_valve.max()),
        air_nl_per_min=air_kg / RHO_NORMAL * 1e3 / WINDOW_S * 60.0,
        steady_error_mm=float(np.mean(errors)) * 1e3 if situation == "rest" else math.nan,
        trip=rig.trip.name if rig.trip.name != "NONE" else None,
    )


def run(seed: int = 1) -> list[Activity]:
    """Every scheme in both situations, on the same plant and seed."""
    return [
        measure(scheme, situation, seed) for situation in ("rest", "exercise") for scheme in SCHEMES
    ]
