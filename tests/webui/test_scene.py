"""The live 3D view follows telemetry: pose, ghost, legs and wrench in a real viser server."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
import viser

from device.geometry import DEFAULT_GEOMETRY
from webui.scene import PlatformScene, leg_colours


@pytest.fixture
def scene() -> Iterator[PlatformScene]:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        yield PlatformScene(server)
    finally:
        server.stop()


def test_the_platform_and_its_ghost_follow_measured_and_commanded_pitch(
    scene: PlatformScene,
) -> None:
    pitch = math.radians(10.0)
    pose = [0.0, 0.0, 0.0, 0.0, pitch, 0.0]
    cmd = [0.0, 0.0, 0.0, 0.0, -pitch, 0.0]
    scene.update(pose, cmd, [3e5, 0.0] * 6, [0.0, 0.0, -100.0, 0.0, 5.0, 0.0])
    home = DEFAULT_GEOMETRY.home_pose
    assert np.allclose(scene.platform.position, home[:3])
    # A rotation of +10 deg about y: w = cos(5 deg), y = sin(5 deg).
    w, _, y, _ = scene.platform.wxyz
    assert w == pytest.approx(math.cos(pitch / 2)) and y == pytest.approx(math.sin(pitch / 2))
    assert scene.ghost.wxyz[2] == pytest.approx(-math.sin(pitch / 2))
    legs = np.asarray(scene.legs.points)
    assert legs.shape == (6, 2, 3)
    assert np.allclose(legs[:, 0], DEFAULT_GEOMETRY.base_joints)
    # Plantarflexion lowers the toes' side (+x) of the platform.
    toes = legs[:, 1, 0] > 0
    heel = legs[:, 1, 0] < 0
    assert legs[toes, 1, 2].mean() < legs[heel, 1, 2].mean()
    force = np.asarray(scene.wrench.points)[0]
    assert force[1, 2] - force[0, 2] == pytest.approx(-0.2, abs=1e-6)  # 100 N down, 2 mm/N
    assert scene.updates == 1


def test_legs_are_red_when_pushing_blue_when_pulling_grey_at_rest() -> None:
    c = leg_colours([3e5, 0.0, 0.0, 3e5, 1e5, 1e5, 0, 0, 6e5, 0, 0, 6e5])
    assert c[0, 0] > 200 and c[0, 2] < 60  # push: red
    assert c[1, 2] > 200 and c[1, 0] < 60  # pull: blue
    assert tuple(c[2]) == (150, 150, 150)  # balanced: grey
    assert tuple(c[4]) == tuple(c[0])  # clipped at full colour
