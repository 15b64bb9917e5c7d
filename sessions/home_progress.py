"""The patient's own progress, for their page at home: sessions lately, and how far the foot
moves now against the first week.

One small function over stored session summaries (:class:`~sessions.summary.Summary` as
JSON). It is deliberately plain: the clinician's progress (baselines, the minimal detectable
change, adherence per prescription) is another computation; this one only encourages.
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime, timedelta
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from device.axes import ROTATION_AXES
from sessions.anatomy import Direction, direction_name

WEEK = timedelta(days=7)
_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


class DirectionProgress(BaseModel):
    model_config = _STRICT
    direction: Direction = Field(description="Named for the patient's side (sessions.anatomy).")
    first_week_deg: float = Field(description="Furthest in the first week's sessions, degrees.")
    latest_deg: float = Field(description="Furthest in the last 7 days' sessions, degrees.")


class HomeProgress(BaseModel):
    """What the patient's page shows of their progress."""

    model_config = _STRICT
    sessions_last_7_days: int = Field(ge=0)
    sessions_total: int = Field(ge=0)
    directions: list[DirectionProgress] = Field(
        description="Each direction moved both in the first week and in the last 7 days, once "
        "the first week is over; empty before."
    )


def home_progress(
    sessions: Iterable[tuple[datetime, dict[str, Any] | None]], side: str | None, now: datetime
) -> HomeProgress:
    """``sessions``: each one's start and stored summary; ``side``: the affected foot."""
    rows = sorted((s for s in sessions if exercised(s[1])), key=lambda s: s[0])
    recent = [summary for started, summary in rows if now - started <= WEEK]
    if not rows:
        return HomeProgress(sessions_last_7_days=0, sessions_total=0, directions=[])
    first_end = rows[0][0] + WEEK
    first = [summary for started, summary in rows if started < first_end]
    later = [summary for started, summary in rows if started >= first_end and now - started <= WEEK]
    directions: list[DirectionProgress] = []
    then, lately = _furthest(first), _furthest(later)
    for axis in ROTATION_AXES:
        for sign in (1, -1):
            key = (axis, sign)
            if key in then and key in lately:
                directions.append(
                    DirectionProgress(
                        direction=direction_name(axis, sign, side),
                        first_week_deg=round(then[key], 1),
                        latest_deg=round(lately[key], 1),
                    )
                )
    return HomeProgress(
        sessions_last_7_days=len(recent), sessions_total=len(rows), directions=directions
    )


EXERCISED_S = 60.0
"""A session that neither completed nor finished a repetition counts as exercise from this
much exercise time (device ACTIVE) on."""


def exercised(summary: dict[str, Any] | None) -> bool:
    """Whether a session counts as exercise for the patient's page: it completed, or finished
    a repetition, or exercised for :data:`EXERCISED_S`. A station that stopped a second into
    a session left one interrupted with 0 repetitions, and the page said "6 exercise sessions
    in the last 7 days. Well done!" for it. A summary stored without those fields counts."""
    if summary is None:
        return True
    return bool(
        summary.get("end_reason", "completed") == "completed"
        or summary.get("repetitions_completed", 1) > 0
        or summary.get("duration_s", EXERCISED_S) >= EXERCISED_S
    )


def _furthest(summaries: Iterable[dict[str, Any] | None]) -> dict[tuple[str, int], float]:
    """The furthest angle reached each way about each axis, degrees (> 0)."""
    best: dict[tuple[str, int], float] = {}
    for summary in summaries:
        axes = (summary or {}).get("axes") or {}
        for axis, values in axes.items():
            for sign, field in ((1, "rom_max_deg"), (-1, "rom_min_deg")):
                value = (values or {}).get(field)
                if isinstance(value, int | float) and value * sign > 0:
                    best[(axis, sign)] = max(best.get((axis, sign), 0.0), value * sign)
    return best
