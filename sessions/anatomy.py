"""Which way the foot moves, in a clinician's words: the one table of movement directions.

The device speaks signed angles about its own axes (:mod:`device.axes`); a clinician speaks
of dorsiflexion and plantarflexion, inversion and eversion, adduction and abduction of *this
patient's* foot. Pitch reads the same on either foot; roll and yaw swap with the side, since
the platform's left edge is the medial edge of a right foot and the lateral edge of a left one.

Sign conventions (the device's task frame): pitch > 0 plantarflexion (toes down), pitch < 0
dorsiflexion; roll > 0 lifts the platform's left edge; yaw > 0 turns the toes to the left.

A patient whose affected side is unknown or "both" gets the platform's own words for roll and
yaw ("left edge up", "toes left"): naming inversion for the wrong foot would be worse than
naming none. Every page, metric, report and export names directions through
:func:`direction_name`; nothing else maps signs to anatomy.
"""

from __future__ import annotations

from typing import Final, Literal

from device.axes import ROTATION_AXES, RotationAxis

Side = Literal["left", "right", "both"]
Sign = Literal[1, -1]
Direction = Literal[
    "plantarflexion",
    "dorsiflexion",
    "inversion",
    "eversion",
    "adduction",
    "abduction",
    "left_edge_up",
    "right_edge_up",
    "toes_left",
    "toes_right",
]

_RIGHT_FOOT: Final[dict[tuple[RotationAxis, int], Direction]] = {
    ("pitch", 1): "plantarflexion",
    ("pitch", -1): "dorsiflexion",
    ("roll", 1): "inversion",  # the left edge of a right foot is its medial edge
    ("roll", -1): "eversion",
    ("yaw", 1): "adduction",  # toes to the left: towards the midline of a right foot
    ("yaw", -1): "abduction",
}
_OPPOSITE: Final[dict[Direction, Direction]] = {
    "inversion": "eversion",
    "eversion": "inversion",
    "adduction": "abduction",
    "abduction": "adduction",
}
_PLATFORM: Final[dict[tuple[RotationAxis, int], Direction]] = {
    ("pitch", 1): "plantarflexion",
    ("pitch", -1): "dorsiflexion",
    ("roll", 1): "left_edge_up",
    ("roll", -1): "right_edge_up",
    ("yaw", 1): "toes_left",
    ("yaw", -1): "toes_right",
}

LABELS: Final[dict[Direction, str]] = {
    "plantarflexion": "Plantarflexion (toes down)",
    "dorsiflexion": "Dorsiflexion (toes up)",
    "inversion": "Inversion (sole turned inwards)",
    "eversion": "Eversion (sole turned outwards)",
    "adduction": "Adduction (toes turned inwards)",
    "abduction": "Abduction (toes turned outwards)",
    "left_edge_up": "Platform's left edge up",
    "right_edge_up": "Platform's right edge up",
    "toes_left": "Toes turned left",
    "toes_right": "Toes turned right",
}
"""How a page or report labels each direction."""


def direction_name(axis: RotationAxis, sign: int, side: str | None) -> Direction:
    """The direction of a movement with ``sign`` (> 0 or < 0) about ``axis``, for a patient
    whose affected (exercised) foot is ``side``."""
    if axis not in ROTATION_AXES or sign == 0:
        raise ValueError(f"no direction for {axis!r} with sign {sign}")
    key = (axis, 1 if sign > 0 else -1)
    if side == "right":
        return _RIGHT_FOOT[key]
    if side == "left":
        name = _RIGHT_FOOT[key]
        return _OPPOSITE.get(name, name)
    return _PLATFORM[key]


def directions(axis: RotationAxis, side: str | None) -> tuple[Direction, Direction]:
    """The two directions of ``axis`` for ``side``: (the positive angle's, the negative's)."""
    return direction_name(axis, 1, side), direction_name(axis, -1, side)


def label(axis: RotationAxis, sign: int, side: str | None) -> str:
    """The label a page or report shows for a movement with ``sign`` about ``axis``."""
    return LABELS[direction_name(axis, sign, side)]


def direction_table(side: str | None) -> dict[str, dict[str, str]]:
    """For a page: each rotation axis's direction names and labels for ``side``,
    ``{"roll": {"positive": "inversion", "negative": "eversion", "positive_label": …}}``."""
    table: dict[str, dict[str, str]] = {}
    for axis in ROTATION_AXES:
        pos, neg = directions(axis, side)
        table[axis] = {
            "positive": pos,
            "negative": neg,
            "positive_label": LABELS[pos],
            "negative_label": LABELS[neg],
        }
    return table
