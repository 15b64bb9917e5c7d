"""The game's field: where its gates may be for an exercise, in degrees from home.

The game itself (a plane the foot flies through gates) runs in the page (``static/game.js``);
the station only says how far the foot is meant to go on each axis.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from sessions.prescription import PrescriptionBody

GAME_SPAN_DEG = {"pitch": 10.0, "roll": 8.0}
"""Half the game's field on each axis, degrees, when the prescription sets no range: a
comfortable movement, not the ends of the ankle's range."""
GAME_ROM_SHARE = 0.8
"""The game keeps to this share of a prescribed range: gates at the very end of it would
lead the foot into the device's range-of-motion stop."""


class GameField(BaseModel):
    """Where the game's gates may be, degrees from home; None for an axis the exercise holds
    still (the plane does not move on it)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    pitch: tuple[float, float] | None = Field(description="Toes up (low) to toes down (high).")
    roll: tuple[float, float] | None = Field(description="Left edge down to left edge up.")


def game_field(body: PrescriptionBody) -> GameField | None:
    """The game's field for an exercise; None where the platform does not yield to the foot
    (the plane could not be steered) or neither pitch nor roll is exercised."""
    if not body.compliant():
        return None
    spans: dict[str, tuple[float, float]] = {}
    for a in body.axes:
        if a.axis not in GAME_SPAN_DEG:
            continue
        lo, hi = a.limits_deg()
        if a.rom_low is None and a.rom_high is None:
            # Wide enough for where the platform's own target takes the foot (a sine).
            half = GAME_SPAN_DEG[a.axis]
            t_lo, t_hi = a.target_span_deg()
            lo, hi = max(lo, min(a.center - half, t_lo)), min(hi, max(a.center + half, t_hi))
        else:
            mid, half = (lo + hi) / 2, (hi - lo) / 2 * GAME_ROM_SHARE
            lo, hi = mid - half, mid + half
        spans[a.axis] = (round(lo, 2), round(hi, 2))
    if not spans:
        return None
    return GameField(pitch=spans.get("pitch"), roll=spans.get("roll"))
