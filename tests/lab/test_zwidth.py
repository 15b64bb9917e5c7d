"""Z-width: a point inside the published envelope renders stably, one far below does not."""

from __future__ import annotations

from device.limits import SafetyLimits
from lab import zwidth


def test_inside_the_envelope_is_stable_and_far_below_it_is_not() -> None:
    inside = zwidth.point("pitch", 50.0, 1.0)
    assert inside["stable"] and inside["unstable_with"] == []
    below = zwidth.point("pitch", 50.0, 0.0)  # no damping: the device refuses it; the lab not
    assert not below["stable"] and below["unstable_with"]


def test_the_table_names_the_least_stable_b_and_any_point_inside_that_failed() -> None:
    points = [
        {"axis": "roll", "k": 50.0, "b": b, "stable": b >= 0.2, "unstable_with": [],
         "trips": [], "pp_det_deg_max": 0.0}
        for b in (0.1, 0.2, 0.5)
    ]  # fmt: skip
    bad = {**points[0], "b": 0.5, "stable": False, "unstable_with": ["resisting"]}
    result = {"points": points, "unstable_inside_envelope": [bad]}
    text = zwidth.table(result)
    published = SafetyLimits().damping_min_at(3, 50.0)  # roll
    assert f"| 50 | 0.2 / {published:g} |" in text
    assert "Unstable points at or above the published envelope: 1" in text
    assert "roll K = 50, B = 0.5: resisting" in text
    assert zwidth.least_b({"points": points}, "roll", 50.0) == 0.2


def test_the_map_is_of_the_loop_alone_without_the_ring_guard() -> None:
    """Roll at K = 50 with the law at 0.2 (below the published 1.0) rings with a resisting
    foot: the map marks it unstable, as the loop is; the device's ring guard, on by
    default, catches that ring and damps it."""
    from lab import envelope

    assert zwidth.point("roll", 50.0, 0.2)["stable"] is False
    floor = envelope.floor_at(0.2)
    bare = envelope.run_point("roll", "resisting", 50.0, 0.2, limits=floor, ring_guard=False)
    guarded = envelope.run_point("roll", "resisting", 50.0, 0.2, limits=floor)
    assert bare["marginal"] and bare["rings"] == 0, bare
    assert not guarded["marginal"] and guarded["rings"] >= 1, guarded
