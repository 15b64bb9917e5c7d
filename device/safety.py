"""Safety supervisor of the controller: the lowest layer where limits are enforced.

Every check runs inside the interrupt handler, whatever the host, the server or a browser
has already checked. A trip latches: all 24 valves close (pressures held, the platform
stays where the trapped air holds it) and nothing moves again until an explicit re-arm
followed by a new motion command. Trip codes are stable numbers for logs and the protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from device._jit import njit


class Trip(IntEnum):
    """Why the controller stopped. 0 means no trip."""

    NONE = 0
    SENSOR_INVALID = 1
    """A sensor read NaN or infinity."""
    PRESSURE_RANGE = 2
    """A chamber or the supply read outside its physical range."""
    RANGE_OF_MOTION = 3
    """The measured pose left the range of motion (plus margin)."""
    WRENCH_LIMIT = 4
    """The foot's force or torque exceeded its limit."""
    LEG_SPEED = 5
    """A leg moved faster than the speed limit."""
    KINEMATICS = 6
    """Forward kinematics did not converge on the measured leg lengths."""
    COMMAND_INVALID = 7
    """A command reached the controller with NaN/inf or out of its limits."""
    STROKE_END = 8
    """A piston reached the end of its stroke."""
    ESTOP = 9
    """Emergency stop."""
    HOMING = 10
    """Homing did not reach the home pose in time."""


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
    pitch sine peaks at 1.5 rad/s. Checked on commands; the leg speed limit trips motion."""

    def as_array(self) -> NDArray[np.float64]:
        """(8, 6) array for the compiled controller: rows as the fields, in order."""
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
            ],
            dtype=np.float64,
        )


ROW_ROM_LOW, ROW_ROM_HIGH, ROW_ROM_MARGIN = 0, 1, 2
ROW_K_MAX, ROW_B_MAX, ROW_K_SLEW, ROW_B_SLEW, ROW_SCALARS = 3, 4, 5, 6, 7


@njit
def all_finite(values: NDArray[np.float64]) -> bool:
    for v in values.flat:
        if not math.isfinite(v):
            return False
    return True


@njit
def check_sensors(
    sensors: NDArray[np.float64], p_max: float, stroke: float, limits: NDArray[np.float64]
) -> int:
    """Trip code for a fresh sensor vector (0 if fine)."""
    if not all_finite(sensors):
        return Trip.SENSOR_INVALID
    for c in range(13):
        if sensors[c] < 0.0 or sensors[c] > p_max:
            return Trip.PRESSURE_RANGE
    margin = limits[ROW_SCALARS, 3]
    for i in range(6):
        x = sensors[13 + i]
        if x < margin or x > stroke - margin:
            return Trip.STROKE_END
    f2 = sensors[19] ** 2 + sensors[20] ** 2 + sensors[21] ** 2
    if f2 > limits[ROW_SCALARS, 0] ** 2:
        return Trip.WRENCH_LIMIT
    for k in range(3):
        if abs(sensors[22 + k]) > limits[ROW_SCALARS, 1]:
            return Trip.WRENCH_LIMIT
    return Trip.NONE


@njit
def check_leg_speed(leg_rate: NDArray[np.float64], limits: NDArray[np.float64]) -> int:
    for i in range(6):
        if abs(leg_rate[i]) > limits[ROW_SCALARS, 2]:
            return Trip.LEG_SPEED
    return Trip.NONE


@njit
def check_pose(pose: NDArray[np.float64], limits: NDArray[np.float64]) -> int:
    for k in range(6):
        m = limits[ROW_ROM_MARGIN, k]
        if pose[k] < limits[ROW_ROM_LOW, k] - m or pose[k] > limits[ROW_ROM_HIGH, k] + m:
            return Trip.RANGE_OF_MOTION
    return Trip.NONE


@njit
def slew(current: float, target: float, max_rate: float, dt: float) -> float:
    """Move ``current`` toward ``target`` by at most ``max_rate * dt``."""
    step = max_rate * dt
    if target > current + step:
        return current + step
    if target < current - step:
        return current - step
    return target
