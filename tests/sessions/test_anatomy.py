"""Direction names: one table, swapped for the side where anatomy says so."""

from __future__ import annotations

import pytest

from sessions.anatomy import LABELS, direction_name, direction_table, directions


def test_pitch_reads_the_same_on_either_foot() -> None:
    for side in ("left", "right", "both", None):
        assert directions("pitch", side) == ("plantarflexion", "dorsiflexion")


def test_roll_and_yaw_swap_with_the_side() -> None:
    # Lifting the platform's left edge raises the medial edge of a right foot (inversion)
    # and the lateral edge of a left foot (eversion).
    assert direction_name("roll", 1, "right") == "inversion"
    assert direction_name("roll", 1, "left") == "eversion"
    assert direction_name("roll", -1, "left") == "inversion"
    assert direction_name("yaw", 1, "right") == "adduction"
    assert direction_name("yaw", 1, "left") == "abduction"


def test_unknown_side_gets_the_platforms_words() -> None:
    assert directions("roll", "both") == ("left_edge_up", "right_edge_up")
    assert directions("yaw", None) == ("toes_left", "toes_right")


def test_zero_or_unknown_axis_has_no_direction() -> None:
    with pytest.raises(ValueError, match="no direction"):
        direction_name("pitch", 0, "right")
    with pytest.raises(ValueError, match="no direction"):
        direction_name("x", 1, "right")  # type: ignore[arg-type]


def test_table_labels_every_direction() -> None:
    table = direction_table("left")
    assert table["roll"]["positive_label"] == LABELS["eversion"]
    assert set(table) == {"roll", "pitch", "yaw"}
