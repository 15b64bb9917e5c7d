"""The device's own limits: what it refuses to be asked and what trips it when exceeded.

Plain Python and numpy: the protocol publishes these in ``DeviceHello`` and every layer above
(the prescription model, the station, the dashboard) reads them from there or from here,
without the compiled controller. The device runs on exactly the values it publishes:
:meth:`SafetyLimits.published` rounds every limit to the float32 the wire carries, and the
controller, the command checks (:mod:`device.commands`) and ``DeviceHello`` all use that one
copy, so a host that asks for exactly a published limit is never refused by a rounding.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

LEG_HEADROOM = 0.003
"""Commanded piston positions keep this far inside the stroke-end trip band (m): the
tracking error of a sine (under 1 mm) and a step's overshoot (under 5 % of 10 mm) fit in
it, so a target the device accepted never drives a piston into its end stop, and a patient
who pushes a compliant axis into a corner of the workspace meets a soft wall, not a trip."""

APPROACH_SPEED: tuple[float, ...] = (0.01, 0.01, 0.01, 0.2, 0.2, 0.2)
"""Speed of the moves into and out of a segment (m/s, rad/s): 0.2 rad/s is 11 deg/s. The
range of motion in force during the approach closes in on the segment's own at this speed
too (device.modes), and a compliance that fell behind the foot (a hold while it pushed)
catches up with it no faster (device.controller, ``ControllerState.catch_up``)."""


def to_float32(value: float) -> float:
    """``value`` as the wire's float32 carries it, back as a Python float."""
    return float(np.float32(value))


@dataclass(frozen=True)
class SafetyLimits:
    """The device's own limits. Commands asking for more are refused; motion beyond trips.

    Angles in radians, lengths in metres. The range of motion fits inside the stroke of the
    placeholder geometry for every single-axis excursion and stays within normal adult ankle
    ranges (dorsiflexion about 20 deg, plantarflexion about 45 deg, inversion 30 deg,
    eversion 20 deg): the narrower of the two wins.
    """

    # Ranges are relative to the home pose.
    rom_low: tuple[float, ...] = (-0.03, -0.03, -0.025, -0.35, -0.40, -0.30)
    rom_high: tuple[float, ...] = (0.03, 0.03, 0.025, 0.35, 0.40, 0.30)
    rom_trip_margin: tuple[float, ...] = (0.005, 0.005, 0.005, 0.05, 0.05, 0.05)
    """How far past the range of motion the measured pose may go before a trip (commands are
    clamped to the range; the margin covers tracking error)."""
    force_limit: float = 400.0
    """Largest force magnitude on the foot plate (N)."""
    torque_limit: float = 60.0
    """Largest torque on the foot plate about any axis (N m)."""
    leg_speed_limit: float = 0.40
    """Largest piston speed (m/s): well above a 7 Hz, 2 deg pitch sine (0.1 m/s)."""
    stroke_margin: float = 0.002
    """A piston this close to either end of its stroke trips (m)."""
    stiffness_max: tuple[float, ...] = (20000.0, 20000.0, 20000.0, 500.0, 500.0, 500.0)
    """Largest K per axis (N/m, N m/rad)."""
    damping_max: tuple[float, ...] = (2000.0, 2000.0, 2000.0, 50.0, 50.0, 50.0)
    """Largest B per axis (N s/m, N m s/rad)."""
    stiffness_slew: tuple[float, ...] = (20000.0, 20000.0, 20000.0, 200.0, 200.0, 200.0)
    """Largest rate of change of K in force per axis (per second): a live change from 20 to
    100 N m/rad takes 0.4 s, so the patient never feels a jump."""
    damping_slew: tuple[float, ...] = (2000.0, 2000.0, 2000.0, 20.0, 20.0, 20.0)
    """Largest rate of change of B per axis (per second)."""

    axis_speed_max: tuple[float, ...] = (0.10, 0.10, 0.10, 2.0, 2.0, 2.0)
    """Fastest target waveform a command may ask for per axis (m/s, rad/s): a 7 Hz, 2 deg
    pitch sine peaks at 1.5 rad/s. Checked on commands; the leg speed limit trips motion.
    The sine's 0.1 s fade-in (``device.controller.waveform``) commands more than this for a
    moment below about 2 Hz: up to 1.62 times a sine's steady peak speed (3.23 against
    2.00 rad/s in pitch at 0.8 Hz), which the legs' combined check leaves room for
    (``device.commands.LEG_SPEED_SHARE``)."""

    envelope_stiffness: tuple[float, ...] = (0.0, 5.0, 50.0)
    """The stable stiffness-damping envelope, in three bands of K: the lower edge of each
    (N/m, N m/rad). Band i holds for ``envelope_stiffness[i] <= K`` up to the next edge."""
    damping_min: tuple[float, ...] = (
        0.0, 0.0, 0.0,
        0.0, 0.0, 0.0,
        0.0, 0.0, 0.0,
        1.9, 1.3, 1.0,
        1.0, 0.8, 0.4,
        0.6, 0.6, 0.3,
    )  # fmt: skip
    """Least damping B per axis and K band (axis-major, 3 bands each; N s/m, N m s/rad): a
    compliant axis renders K and B only with B at least this, and the admittance law never
    renders less (device.controller). First measured on the nominal plant over a grid of K
    0-500 N m/rad and B 0-10 N m s/rad with a relaxed, a resisting and no foot (twice the
    worst boundary); then on the nominal unit and twenty drawn builds, each identified and
    run with its calibration (``python -m lab.envelope --builds 20``, docs/envelope.md
    section 6): 1.25 times the worst least damping over the builds, and never less than the
    first figure. The builds that set it: a resisting foot on light, long-tubed builds (15,
    18, 19) rings at 6-11 Hz in roll below it, 0.4-1.1 deg. Below it the loop oscillates
    with a foot, or a push on an empty plate asks the legs for more than their speed limit.
    Translations are not measured (no exercise renders them): the device refuses a compliant
    translation (``device.commands.COMPLIANT_AXES``), so their zeros are never used."""

    def damping_min_at(self, axis: int, stiffness: float) -> float:
        """The least damping the device renders stably on ``axis`` at ``stiffness``."""
        band = 0
        for i, edge in enumerate(self.envelope_stiffness):
            if stiffness >= edge:
                band = i
        return self.damping_min[3 * axis + band]

    def as_array(self) -> NDArray[np.float64]:
        """(12, 6) array for the compiled controller: the fields in order, then the least
        damping of each K band (3 rows) and the bands' lower edges."""
        return np.array(
            [
                self.rom_low,
                self.rom_high,
                self.rom_trip_margin,
                self.stiffness_max,
                self.damping_max,
                self.stiffness_slew,
                self.damping_slew,
                (
                    self.force_limit,
                    self.torque_limit,
                    self.leg_speed_limit,
                    self.stroke_margin,
                    0.0,
                    0.0,
                ),
                self.damping_min[0::3],
                self.damping_min[1::3],
                self.damping_min[2::3],
                (*self.envelope_stiffness, 0.0, 0.0, 0.0),
            ],
            dtype=np.float64,
        )

    def published(self) -> SafetyLimits:
        """These limits rounded to float32, exactly as ``DeviceHello`` carries them."""
        values: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            values[f.name] = (
                tuple(to_float32(x) for x in v) if isinstance(v, tuple) else to_float32(v)
            )
        return SafetyLimits(**values)


ROW_ROM_LOW, ROW_ROM_HIGH, ROW_ROM_MARGIN = 0, 1, 2
ROW_K_MAX, ROW_B_MAX, ROW_K_SLEW, ROW_B_SLEW, ROW_SCALARS = 3, 4, 5, 6, 7
ROW_B_MIN, ROW_ENVELOPE_K = 8, 11
"""Rows 8-10: least damping per axis of K bands 0-2; row 11: the bands' lower edges."""
"""Rows of :meth:`SafetyLimits.as_array`, the compiled controller's copy."""


def implausible_legs(
    legs: Sequence[float] | NDArray[np.float64], stroke: float, limits: SafetyLimits
) -> list[int]:
    """The legs (0-5) whose displacement reading no piston of a ``stroke`` long cylinder
    gives: not finite, or more than the stroke margin beyond either end of the stroke.

    What homing needs of where it starts, and all it needs: a platform resting on its end
    stops (vented by a release, the start-up identification or a power-off) reads its legs
    at 0..2 mm, inside the stroke-end trip band, and homing takes it from there (a leg that
    starts outside the band is judged once inside it: ``device.safety.outside_at_start``).
    A sensor reads a little past its stops (its measuring range and zero errors); one that
    reads farther is broken or mis-calibrated, and the controller would chase it."""
    m = limits.stroke_margin
    bad = []
    for i, x in enumerate(legs):
        if not (math.isfinite(float(x)) and -m <= x <= stroke + m):
            bad.append(i)
    return bad
