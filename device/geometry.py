"""Geometry of the Stewart platform: the one place its dimensions live.

The paper does not publish the Rutgers Ankle's dimensions, so these are a placeholder of the
right size for a foot (base radius 0.15 m, platform radius 0.10 m, 0.20 m high, 100 mm
stroke), documented here so that a real device's measured values replace them in one place.

Frames (right-handed, z up):
- base frame: origin at the centre of the base joint circle; x points to the patient's toes,
  y to the patient's left.
- task frame: rigidly attached to the platform with its origin at the patient's ankle joint
  centre, ``ankle_height`` above the platform joint plane. Poses, stiffness and wrenches are
  all expressed about this point, because the therapist prescribes ankle angles and torques.

A pose is ``(x, y, z, roll, pitch, yaw)`` in metres and radians: the task-frame origin in the
base frame and Z-Y-X Euler angles, ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. Pitch is plantar-
and dorsiflexion (about y), roll is inversion/eversion (about x), yaw is ab-/adduction.

Leg ``i`` runs from base joint ``i`` to platform joint ``i``; its length is measured between
joint centres. The cylinder's piston displacement (what the leg sensor reads, 0..stroke) is
``length - min_length``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from device.axes import AXES as AXES  # re-exported: older callers name the axes from here
from device.axes import AXIS_INDEX as AXIS_INDEX

N_LEGS = 6


def _joint_circle(radius: float, angles_deg: list[float], z: float) -> NDArray[np.float64]:
    a = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    return np.column_stack([radius * np.cos(a), radius * np.sin(a), np.full(a.shape, z)])


@dataclass(frozen=True)
class Geometry:
    """Dimensions of the platform (metres, degrees)."""

    base_radius: float = 0.15
    """Radius of the base joint circle (m)."""
    platform_radius: float = 0.10
    """Radius of the platform joint circle (m)."""
    base_pair_half_angle_deg: float = 10.0
    """Half the angle between the two base joints of a pair (deg)."""
    platform_pair_half_angle_deg: float = 10.0
    """Half the angle between the two platform joints of a pair (deg)."""
    home_height: float = 0.20
    """Height of the platform joint plane above the base joint plane at home (m)."""
    ankle_height: float = 0.10
    """Ankle joint centre above the platform joint plane: foot plate, sensor, sole (m)."""
    stroke: float = 0.100
    """Cylinder stroke (m). Home is mid-stroke on every leg."""
    base_joints: NDArray[np.float64] = field(init=False, repr=False)
    """(6, 3) base joint centres in the base frame (m)."""
    platform_joints: NDArray[np.float64] = field(init=False, repr=False)
    """(6, 3) platform joint centres in the task frame (m)."""

    def __post_init__(self) -> None:
        for name in ("base_radius", "platform_radius", "home_height", "stroke"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"geometry: {name} must be positive")
        hb, hp = self.base_pair_half_angle_deg, self.platform_pair_half_angle_deg
        # Leg pairs leave each base pair and reach the two neighbouring platform pairs: the
        # usual 6-6 arrangement, well conditioned about home.
        base_deg: list[float] = []
        plat_deg: list[float] = []
        for k in range(3):
            c = 120.0 * k
            base_deg += [c - hb, c + hb]
            plat_deg += [c - 60.0 + hp, c + 60.0 - hp]
        base = _joint_circle(self.base_radius, base_deg, 0.0)
        plat = _joint_circle(self.platform_radius, plat_deg, -self.ankle_height)
        base.setflags(write=False)
        plat.setflags(write=False)
        object.__setattr__(self, "base_joints", base)
        object.__setattr__(self, "platform_joints", plat)

    @property
    def home_pose(self) -> NDArray[np.float64]:
        """Pose with the platform level and every leg at mid-stroke."""
        return np.array([0.0, 0.0, self.home_height + self.ankle_height, 0.0, 0.0, 0.0])

    @property
    def home_length(self) -> float:
        """Leg length at home (all six are equal by symmetry) (m)."""
        p = self.platform_joints[0] + self.home_pose[:3]
        return float(np.linalg.norm(p - self.base_joints[0]))

    @property
    def min_length(self) -> float:
        """Leg length with the piston fully retracted (m)."""
        return self.home_length - 0.5 * self.stroke

    @property
    def max_length(self) -> float:
        """Leg length with the piston fully extended (m)."""
        return self.home_length + 0.5 * self.stroke


DEFAULT_GEOMETRY = Geometry()
