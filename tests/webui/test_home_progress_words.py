"""The patient's progress in words: encouraging, and never worse over a degree's noise."""

from __future__ import annotations

from sessions.home_progress import DirectionProgress, HomeProgress
from webui.home.progress import MOVEMENT, progress_lines


def test_sessions_and_each_movement_against_the_first_week() -> None:
    lines = progress_lines(
        HomeProgress(
            sessions_last_7_days=3,
            sessions_total=9,
            directions=[
                DirectionProgress(direction="plantarflexion", first_week_deg=15, latest_deg=21.4),
                DirectionProgress(direction="dorsiflexion", first_week_deg=10, latest_deg=10.6),
                DirectionProgress(direction="eversion", first_week_deg=6, latest_deg=4),
            ],
        )
    )
    assert lines == [
        "3 exercise sessions in the last 7 days. Well done!",
        "Pointing your toes down: 21° now, 6° further than in your first week.",
        "Pulling your toes up: 11°, as far as in your first week.",
        "Turning your sole outwards: 4° this week and 6° in your first week. "
        "Keep going: it comes with practice.",
    ]


def test_before_any_session_and_in_the_first_week() -> None:
    none = HomeProgress(sessions_last_7_days=0, sessions_total=0, directions=[])
    assert progress_lines(none) == ["Your first exercise starts your progress here."]
    one = HomeProgress(sessions_last_7_days=1, sessions_total=1, directions=[])
    assert progress_lines(one) == [
        "1 exercise session in the last 7 days. A good start!",
        "After your first week, this page compares your movement with it.",
    ]
    idle = HomeProgress(sessions_last_7_days=0, sessions_total=4, directions=[])
    assert progress_lines(idle)[0].startswith("No exercise in the last 7 days yet")


def test_every_direction_has_words() -> None:
    from typing import get_args

    from sessions.anatomy import Direction

    assert set(MOVEMENT) == set(get_args(Direction))
