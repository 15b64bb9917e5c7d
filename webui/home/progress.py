"""The patient's own progress in encouraging plain words, for their page.

The numbers come from the server (:class:`~sessions.home_progress.HomeProgress`); the words
are the page's. A change smaller than :data:`SAME_DEG` is "about the same": the patient is
not told they got worse over what a sensor and a day's stiffness make of one degree.
"""

from __future__ import annotations

from typing import Final

from sessions.anatomy import Direction
from sessions.home_progress import HomeProgress

SAME_DEG = 1.0
MOVEMENT: Final[dict[Direction, str]] = {
    "plantarflexion": "Pointing your toes down",
    "dorsiflexion": "Pulling your toes up",
    "inversion": "Turning your sole inwards",
    "eversion": "Turning your sole outwards",
    "adduction": "Turning your toes inwards",
    "abduction": "Turning your toes outwards",
    "left_edge_up": "Tilting the plate's left edge up",
    "right_edge_up": "Tilting the plate's right edge up",
    "toes_left": "Turning your toes to the left",
    "toes_right": "Turning your toes to the right",
}
"""Each direction of :mod:`sessions.anatomy` as a patient says it."""


def progress_lines(p: HomeProgress) -> list[str]:
    """A few short sentences: sessions lately, then each movement against the first week."""
    n = p.sessions_last_7_days
    if p.sessions_total == 0:
        return ["Your first exercise starts your progress here."]
    if n == 0:
        lines = ["No exercise in the last 7 days yet: today is a good day for it."]
    elif n == 1:
        lines = ["1 exercise session in the last 7 days. A good start!"]
    else:
        lines = [f"{n} exercise sessions in the last 7 days. Well done!"]
    if not p.directions:
        lines.append("After your first week, this page compares your movement with it.")
    for d in p.directions:
        what = MOVEMENT[d.direction]
        now, then = d.latest_deg, d.first_week_deg
        change = now - then
        if change >= SAME_DEG:
            lines.append(f"{what}: {now:.0f}° now, {change:.0f}° further than in your first week.")
        elif change <= -SAME_DEG:
            lines.append(
                f"{what}: {now:.0f}° this week and {then:.0f}° in your first week. "
                "Keep going: it comes with practice."
            )
        else:
            lines.append(f"{what}: {now:.0f}°, as far as in your first week.")
    return lines
