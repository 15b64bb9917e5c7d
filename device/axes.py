"""The task-space axes: the one table the whole project names them from.

A pose, a wrench, a stiffness and a damping are six numbers in this order, about the
patient's ankle joint centre (see :mod:`device.geometry` for the frames). The three
rotations are the ankle's: a therapist prescribes them, the others hold home. Everything
else that names axes (the prescription, the recordings, the exports, the dashboard) derives
its names, indices and units from here. Plain Python: the protocol and every layer above
import it without the compiled controller.
"""

from __future__ import annotations

from typing import Final, Literal

AXES: Final[tuple[str, ...]] = ("x", "y", "z", "roll", "pitch", "yaw")
"""Task-space axis names, in pose order."""

AXIS_INDEX: Final[dict[str, int]] = {name: i for i, name in enumerate(AXES)}

TRANSLATION_AXES: Final[tuple[str, ...]] = AXES[:3]

RotationAxis = Literal["roll", "pitch", "yaw"]
ROTATION_AXES: Final[tuple[RotationAxis, ...]] = ("roll", "pitch", "yaw")
"""The ankle's rotations: roll is inversion/eversion (about x), pitch plantar- and
dorsiflexion (about y), yaw ab-/adduction (about the shank, z)."""

assert AXES[3:] == ROTATION_AXES

ROTATION_NAMES: Final[dict[str, str]] = {
    "roll": "inversion/eversion",
    "pitch": "plantar/dorsiflexion",
    "yaw": "ab-/adduction",
}


def is_rotation(axis: int | str) -> bool:
    """Whether an axis (index or name) is one of the ankle's rotations."""
    index = AXIS_INDEX[axis] if isinstance(axis, str) else axis
    return 3 <= index < 6


def unit(axis: int | str, si: bool = True) -> str:
    """The axis's unit: m or rad (``si``), or mm or deg as a clinician reads it."""
    if is_rotation(axis):
        return "rad" if si else "deg"
    return "m" if si else "mm"
