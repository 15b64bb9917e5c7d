"""The live 3D view of the platform in viser: what the therapist sees moving.

One :class:`PlatformScene` draws one station's platform from its telemetry: the base, the
moving platform with the foot on it at the measured pose, a translucent ghost at the
commanded pose, the six legs coloured by their chamber pressure difference (red pushes the
platform up, blue pulls it down), and the patient's force and torque on the foot plate as
arrows at the ankle. Each update is one ``server.atomic()`` group; callers decimate to
30–60 Hz because every property set costs about 35 µs.

Poses are relative to home in telemetry (m, rad); the scene adds the home pose of the
device's geometry. Units in the scene are metres; z is up.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import viser
import viser.transforms as vtf
from numpy.typing import NDArray

from device.geometry import DEFAULT_GEOMETRY, Geometry

PRESSURE_SPAN_PA = 3e5
"""Pressure difference drawn at full colour (Pa): about half the supply."""
FORCE_SCALE = 0.002
"""Arrow length per newton (m/N): 100 N is 20 cm."""
TORQUE_SCALE = 0.01
"""Arrow length per newton metre (m/(N m)): 10 N m is 10 cm."""
NEUTRAL = np.array([150.0, 150.0, 150.0])
CAMERA_POSITION = (0.36, -0.44, 0.32)
"""Where a view's camera starts (m, z up): ahead of the toes (+x), to the side, above; close
enough that the platform, not the floor grid, fills the view."""
CAMERA_LOOK_AT = (0.0, 0.0, 0.15)


def leg_colours(pressures: Sequence[float]) -> NDArray[np.uint8]:
    """(6, 3) RGB per leg from cap minus rod chamber pressure: red pushes, blue pulls."""
    p = np.asarray(pressures, dtype=np.float64).reshape(6, 2)
    x = np.clip((p[:, 0] - p[:, 1]) / PRESSURE_SPAN_PA, -1.0, 1.0)[:, None]
    red, blue = np.array([220.0, 40.0, 40.0]), np.array([40.0, 90.0, 220.0])
    out = np.where(x >= 0, NEUTRAL + x * (red - NEUTRAL), NEUTRAL - x * (blue - NEUTRAL))
    colours: NDArray[np.uint8] = out.astype(np.uint8)
    return colours


def world_pose(
    geometry: Geometry, relative: Sequence[float] | NDArray[np.float64]
) -> tuple[NDArray[np.float64], vtf.SO3]:
    """Position and rotation of the ankle frame for a pose relative to home."""
    pose = geometry.home_pose + np.asarray(relative, dtype=np.float64)
    rot = vtf.SO3.from_rpy_radians(float(pose[3]), float(pose[4]), float(pose[5]))
    return pose[:3], rot


class PlatformScene:
    """One platform in one viser server's scene."""

    def __init__(self, server: viser.ViserServer, geometry: Geometry = DEFAULT_GEOMETRY) -> None:
        self.server = server
        self.geometry = geometry
        scene = server.scene
        scene.set_up_direction("+z")
        g = geometry
        server.initial_camera.position = CAMERA_POSITION
        server.initial_camera.look_at = CAMERA_LOOK_AT
        plate_z = -g.ankle_height  # the platform joint plane, below the ankle
        scene.add_grid("/floor", width=0.6, height=0.6, cell_size=0.05, position=(0, 0, -0.01))
        scene.add_cylinder(
            "/base",
            radius=g.base_radius + 0.02,
            height=0.01,
            color=(90, 90, 90),
            wxyz=(1.0, 0.0, 0.0, 0.0),
            position=(0.0, 0.0, -0.005),
        )
        self.platform = scene.add_frame(
            "/platform", show_axes=True, axes_length=0.06, axes_radius=0.003
        )
        scene.add_cylinder(
            "/platform/plate",
            radius=g.platform_radius + 0.02,
            height=0.012,
            color=(200, 200, 205),
            position=(0.0, 0.0, plate_z),
        )
        scene.add_box(
            "/platform/foot",
            color=(230, 190, 160),
            dimensions=(0.26, 0.10, 0.05),
            position=(0.03, 0.0, plate_z + 0.04),
        )
        self.ghost = scene.add_frame("/ghost", show_axes=False)
        scene.add_cylinder(
            "/ghost/plate",
            radius=g.platform_radius + 0.02,
            height=0.012,
            color=(80, 200, 120),
            opacity=0.35,
            position=(0.0, 0.0, plate_z),
        )
        home_joints = self._platform_joints(np.zeros(6))
        self.legs = scene.add_line_segments(
            "/legs",
            points=np.stack([g.base_joints, home_joints], axis=1).astype(np.float32),
            colors=np.repeat(NEUTRAL[None, None, :], 6, axis=0).repeat(2, axis=1).astype(np.uint8),
            thickness=0.012,
        )
        self.wrench = scene.add_arrows(
            "/wrench",
            points=np.zeros((2, 2, 3), dtype=np.float32),
            colors=np.array([[230, 120, 20], [150, 60, 200]], dtype=np.uint8),  # force, torque
            shaft_radius=0.004,
            head_radius=0.01,
            head_length=0.02,
        )
        self.updates = 0

    def _platform_joints(self, relative: NDArray[np.float64]) -> NDArray[np.float64]:
        position, rot = world_pose(self.geometry, relative)
        joints: NDArray[np.float64] = self.geometry.platform_joints @ rot.as_matrix().T + position
        return joints

    def update(
        self,
        pose: Sequence[float],
        pose_cmd: Sequence[float],
        pressures: Sequence[float],
        wrench: Sequence[float],
    ) -> None:
        """Draw one telemetry sample (poses relative to home, m and rad; Pa; N and N m)."""
        relative = np.asarray(pose, dtype=np.float64)
        position, rot = world_pose(self.geometry, relative)
        ghost_position, ghost_rot = world_pose(self.geometry, pose_cmd)
        joints = self._platform_joints(relative)
        colours = leg_colours(pressures)
        w = np.asarray(wrench, dtype=np.float64)
        arrows = np.array(
            [
                [position, position + FORCE_SCALE * w[:3]],
                [position, position + TORQUE_SCALE * w[3:]],
            ],
            dtype=np.float32,
        )
        with self.server.atomic():
            self.platform.position = position
            self.platform.wxyz = rot.wxyz
            self.ghost.position = ghost_position
            self.ghost.wxyz = ghost_rot.wxyz
            self.legs.points = np.stack([self.geometry.base_joints, joints], axis=1).astype(
                np.float32
            )
            self.legs.colors = np.repeat(colours[:, None, :], 2, axis=1)
            self.wrench.points = arrows
        self.updates += 1
