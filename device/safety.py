"""Safety supervisor of the controller: the lowest layer where limits are enforced.

Every check runs inside the interrupt handler, whatever the host, the server or a browser
has already checked. A trip latches: all 24 valves close (pressures held, the platform
stays where the trapped air holds it) and nothing moves again until an explicit re-arm
followed by a new motion command. Trip codes are stable numbers for logs and the protocol.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from device._jit import njit, njit_inline
from device.limits import (
    ROW_B_MAX,
    ROW_B_MIN,
    ROW_B_SLEW,
    ROW_ENVELOPE_K,
    ROW_K_MAX,
    ROW_K_SLEW,
    ROW_ROM_HIGH,
    ROW_ROM_LOW,
    ROW_ROM_MARGIN,
    ROW_SCALARS,
    SafetyLimits,
)
from device.trips import Trip

__all__ = [  # the limits' rows and types, for the compiled controller that reads them here
    "ROW_B_MAX",
    "ROW_B_MIN",
    "ROW_B_SLEW",
    "ROW_ENVELOPE_K",
    "ROW_K_MAX",
    "ROW_K_SLEW",
    "ROW_ROM_HIGH",
    "ROW_ROM_LOW",
    "ROW_ROM_MARGIN",
    "ROW_SCALARS",
    "SafetyLimits",
    "Trip",
    "all_finite",
    "check_leg_speed",
    "check_pose",
    "check_sensors",
    "damping_min",
    "slew",
    "still_outside",
]


@njit
def all_finite(values: NDArray[np.float64]) -> bool:
    for v in values.flat:
        if not math.isfinite(v):
            return False
    return True


OUTSIDE_POSE = 1 << 6
"""Bit of :func:`outside_at_start`'s mask for the pose (bits 0-5 are the legs)."""
ARM_DEPTH = 2.0e-3
"""A leg that started outside its stroke's margin is judged once it stands this far (m)
inside it: legs leaving their stops hover 0.5-0.7 mm about a homing target that is still
near the margin. At 1 mm one of fifty drawn builds (21) armed a leg at 3 mm and tripped it
at 2; at 2 mm none did."""


@njit
def check_sensors(
    sensors: NDArray[np.float64], stroke: float, limits: NDArray[np.float64], exempt: int
) -> tuple[int, int]:
    """(trip code, part) for a fresh sensor vector ((0, -1) if fine); the part as
    :func:`device.trips.where` names it: the leg at its stroke's end, the force/torque
    channel over its limit (for the force, the axis it pushes along most). A leg whose bit
    is set in ``exempt`` started its motion outside its stroke's margin and is not judged
    until it is inside."""
    if not all_finite(sensors):
        return Trip.SENSOR_INVALID, -1
    margin = limits[ROW_SCALARS, 3]
    for i in range(6):
        x = sensors[13 + i]
        if (x < margin or x > stroke - margin) and not exempt & (1 << i):
            return Trip.STROKE_END, i
    f2 = sensors[19] ** 2 + sensors[20] ** 2 + sensors[21] ** 2
    if f2 > limits[ROW_SCALARS, 0] ** 2:
        most = 0
        for k in range(1, 3):
            if abs(sensors[19 + k]) > abs(sensors[19 + most]):
                most = k
        return Trip.WRENCH_LIMIT, most
    for k in range(3):
        if abs(sensors[22 + k]) > limits[ROW_SCALARS, 1]:
            return Trip.WRENCH_LIMIT, 3 + k
    return Trip.NONE, -1


@njit
def check_leg_speed(leg_rate: NDArray[np.float64], limits: NDArray[np.float64]) -> tuple[int, int]:
    """(LEG_SPEED, the leg) for the first leg over the speed limit, (0, -1) if none."""
    for i in range(6):
        if abs(leg_rate[i]) > limits[ROW_SCALARS, 2]:
            return Trip.LEG_SPEED, i
    return Trip.NONE, -1


@njit
def check_pose(pose: NDArray[np.float64], limits: NDArray[np.float64]) -> tuple[int, int]:
    """(RANGE_OF_MOTION, the axis) for the first axis past its range and margin, (0, -1)
    if none."""
    for k in range(6):
        m = limits[ROW_ROM_MARGIN, k]
        if pose[k] < limits[ROW_ROM_LOW, k] - m or pose[k] > limits[ROW_ROM_HIGH, k] + m:
            return Trip.RANGE_OF_MOTION, k
    return Trip.NONE, -1


@njit
def still_outside(
    sensors: NDArray[np.float64],
    pose: NDArray[np.float64],
    home: NDArray[np.float64],
    stroke: float,
    limits: NDArray[np.float64],
    mask: int,
) -> int:
    """``mask`` less the legs now :data:`ARM_DEPTH` inside their stroke's margin and, for
    :data:`OUTSIDE_POSE`, less the pose once inside its range of motion (the trip's margin
    beyond it is the hysteresis): from then on each is judged as any other
    (:func:`check_sensors`, :func:`check_pose`)."""
    margin = limits[ROW_SCALARS, 3] + ARM_DEPTH
    for i in range(6):
        x = sensors[13 + i]
        if mask & (1 << i) and margin <= x <= stroke - margin:
            mask &= ~(1 << i)
    if mask & OUTSIDE_POSE:
        inside = True
        for k in range(6):
            rel = pose[k] - home[k]
            if rel < limits[ROW_ROM_LOW, k] or rel > limits[ROW_ROM_HIGH, k]:
                inside = False
        if inside:
            mask &= ~OUTSIDE_POSE
    return mask


def outside_at_start(
    legs: NDArray[np.float64],
    pose: NDArray[np.float64],
    home: NDArray[np.float64],
    stroke: float,
    limits: NDArray[np.float64],
) -> int:
    """At the start of a joint-mode motion (homing): which legs stand outside their stroke's
    margin and whether the pose is outside its range (bit :data:`OUTSIDE_POSE`). A platform
    resting on its end stops (vented, as the start-up identification and every power-off
    leave it) is below its range of motion with its legs within the margin: judged as a
    moving one, it tripped STROKE_END the moment homing began. Those limits are there to
    stop motion leaving the allowed region; what starts outside may move into it (the
    homing's slow joint move, whose timeout catches a leg that never arrives), and each is
    judged from the moment it is inside."""
    margin = limits[ROW_SCALARS, 3]
    mask = 0
    for i in range(6):
        if not margin <= legs[i] <= stroke - margin:
            mask |= 1 << i
    if check_pose(pose - home, limits)[0] != Trip.NONE:
        mask |= OUTSIDE_POSE
    return mask


@njit
def slew(current: float, target: float, max_rate: float, dt: float) -> float:
    """Move ``current`` toward ``target`` by at most ``max_rate * dt``."""
    step = max_rate * dt
    if target > current + step:
        return current + step
    if target < current - step:
        return current - step
    return target


@njit_inline
def damping_min(limits: NDArray[np.float64], axis: int, stiffness: float) -> float:
    """The least damping the envelope allows on ``axis`` at ``stiffness``."""
    band = 0
    for i in range(3):
        if stiffness >= limits[ROW_ENVELOPE_K, i]:
            band = i
    return float(limits[ROW_B_MIN + band, axis])
