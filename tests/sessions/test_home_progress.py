"""The patient's own progress from session summaries with known answers."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

from sessions.home_progress import home_progress

NOW = datetime(2026, 3, 30, 12, tzinfo=UTC)


def summary(pitch: tuple[float, float], roll: tuple[float, float] | None = None) -> dict[str, Any]:
    axes = {"pitch": {"rom_min_deg": pitch[0], "rom_max_deg": pitch[1]}}
    if roll is not None:
        axes["roll"] = {"rom_min_deg": roll[0], "rom_max_deg": roll[1]}
    return {"axes": axes}


def test_the_last_week_against_the_first_for_a_left_foot() -> None:
    first = NOW - timedelta(days=20)
    sessions = [
        (first, summary((-8.0, 15.0), (-3.0, 4.0))),
        (first + timedelta(days=2), summary((-10.0, 12.0))),  # the first week's best: -10, 15
        (NOW - timedelta(days=10), summary((-30.0, 30.0))),  # neither week: left out
        (NOW - timedelta(days=3), summary((-11.5, 21.0), (-2.0, 6.0))),
        (NOW - timedelta(days=1), summary((-9.0, 19.0))),
        (NOW - timedelta(hours=1), None),  # a session without a summary still counts
    ]
    p = home_progress(sessions, "left", NOW)
    assert (p.sessions_last_7_days, p.sessions_total) == (3, 6)
    found = {d.direction: (d.first_week_deg, d.latest_deg) for d in p.directions}
    # roll > 0 lifts the platform's left edge: eversion of a left foot.
    assert found == {
        "plantarflexion": (15.0, 21.0),
        "dorsiflexion": (10.0, 11.5),
        "eversion": (4.0, 6.0),
        "inversion": (3.0, 2.0),
    }


def test_no_comparison_within_the_first_week_and_nothing_without_sessions() -> None:
    early = [(NOW - timedelta(days=2), summary((-5.0, 9.0))), (NOW, summary((-6.0, 12.0)))]
    p = home_progress(early, "right", NOW)
    assert (p.sessions_last_7_days, p.sessions_total, p.directions) == (2, 2, [])
    none = home_progress([], None, NOW)
    assert (none.sessions_last_7_days, none.sessions_total, none.directions) == (0, 0, [])


def test_a_session_that_never_got_going_is_not_counted_as_exercise() -> None:
    """A station that stopped a second into a session left it interrupted with 0
    repetitions, and the patient's page counted it: "6 exercise sessions ... Well done!"."""

    def ended(reason: str, reps: int, active_s: float) -> dict[str, Any]:
        return summary((-5.0, 9.0)) | {
            "end_reason": reason,
            "repetitions_completed": reps,
            "duration_s": active_s,
        }

    sessions = [
        (NOW - timedelta(days=1), ended("interrupted", 0, 1.2)),  # never got going
        (NOW - timedelta(days=1), ended("fault", 0, 20.0)),  # nor this one
        (NOW - timedelta(days=2), ended("completed", 0, 30.0)),  # a hold with no repetitions
        (NOW - timedelta(days=3), ended("stopped", 4, 40.0)),  # stopped after 4 repetitions
        (NOW - timedelta(days=4), ended("interrupted", 0, 300.0)),  # 5 minutes of exercise
    ]
    p = home_progress(sessions, "left", NOW)
    assert (p.sessions_last_7_days, p.sessions_total) == (3, 3)
    only_false_starts = home_progress(sessions[:2], "left", NOW)
    assert (only_false_starts.sessions_total, only_false_starts.sessions_last_7_days) == (0, 0)
