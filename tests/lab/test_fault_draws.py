"""`ankle bench safety --drawn N`: faults the matrix does not name, drawn at random."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from device.plant.faults import FaultKind
from lab import faultdraws
from lab.safety import CHANNELS, FAULTS
from tests.lab.test_safety_bench import _bench


def test_the_draws_reach_every_kind_channel_size_and_moment_the_docstring_names() -> None:
    rng = np.random.default_rng(5)
    draws = [faultdraws.draw(rng) for _ in range(3000)]
    assert {d.kind for d in draws} == {k.name for k in CHANNELS}
    for d in draws:
        kind = FaultKind[d.kind]
        assert d.channel in CHANNELS[kind]
        assert faultdraws.AT_S[0] <= d.at_s <= faultdraws.AT_S[1]
        assert d.unit == -1 or 0 <= d.unit < faultdraws.BUILDS
        if kind == FaultKind.SUPPLY_DROOP:
            assert 1.0 <= d.value <= 4.0
        elif kind in faultdraws.SIZED:
            base = FAULTS[kind][1]
            if kind == FaultKind.FT_OFFSET and d.channel >= 3:
                base = 3.0
            assert any(math.isclose(d.value, base * s) for s in faultdraws.SIZES), d
    assert any(d.unit == -1 for d in draws) and len({d.unit for d in draws}) > 50
    assert {d.patient for d in draws} == {"relaxed", "resisting"}
    # One seed, one list: a draw can be run again by its seed.
    again = np.random.default_rng(5)
    assert [faultdraws.draw(again) for _ in range(20)] == draws[:20]


def test_a_fault_named_as_another_part_is_counted_as_misnamed() -> None:
    assert set(faultdraws.RIGHT_NAMES) == set(CHANNELS)
    # A transducer a little off once named the leg's length sensor or the force sensor.
    assert faultdraws.misnamed("PRESSURE_OFFSET", "LEG_SENSOR")
    assert faultdraws.misnamed("PRESSURE_OFFSET", "FORCE_SENSOR")
    assert not faultdraws.misnamed("PRESSURE_OFFSET", "FORCE_BALANCE")
    assert not faultdraws.misnamed("PRESSURE_OFFSET", "AIR_BALANCE (service)")
    assert faultdraws.misnamed("FT_OFFSET", "LEG_SENSOR")
    assert not faultdraws.misnamed("FT_OFFSET", "FOLLOWING")
    assert faultdraws.misnamed("LEG_STUCK", "STROKE_END")
    assert not faultdraws.misnamed("LEG_OFFSET", "AIR_BALANCE (service)")  # names the sensor
    assert not faultdraws.misnamed("SUPPLY_DROOP", "SUPPLY_LOW (hold)")
    assert not faultdraws.misnamed("CHAMBER_LEAK", "NONE")  # unnoticed is not misnamed


def test_a_supply_lost_mid_exercise_is_caught_and_measured_against_both_twins() -> None:
    d = faultdraws.Draw("strength", "resisting", -1, "SUPPLY_LOSS", -1, 0.0, 2.0)
    r = faultdraws.run_draw(d, after=0.3)
    assert r.valid and r.twin_trip == "NONE"
    assert r.detected and r.trip == "SUPPLY_LOSS" and r.detect_ms < 50.0
    # Before the loop let go is a part of the whole; the e-stop twin gave a little too.
    assert 0.0 <= r.while_running_deg <= r.excursion_deg
    assert 0.0 <= r.while_running_mm <= r.excursion_mm
    assert 0.0 < r.estop_deg < 2.0 and 0.0 < r.estop_mm < 3.0


def test_an_undetected_small_fault_is_reported_as_such() -> None:
    """A 0.05 mm leg offset, two counts of the sensor, is what a calibration a little off
    looks like: no check can call it a fault. Unnamed, the whole watch counts as the loop
    running, and the platform moves by about the offset, no more."""
    d = faultdraws.Draw("isometric", "relaxed", -1, "LEG_OFFSET", 1, 0.05, 3.0)
    r = faultdraws.run_draw(d, after=0.3)
    assert r.valid and not r.detected
    assert r.trip == "NONE" and math.isnan(r.detect_ms)
    assert (r.while_running_deg, r.while_running_mm) == (r.excursion_deg, r.excursion_mm)
    assert 0.0 < r.excursion_mm < 0.1


def test_drawn_faults_from_the_command_line_print_every_key_and_each_run() -> None:
    done = _bench("--drawn", "2", "--draw-seed", "7", "--after", "0.2", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    for key, _ in faultdraws.ROWS:
        assert key in result, key
    assert result["drawn_faults"] == 2 and result["drawn_seed"] == 7
    assert result["after_s"] == 0.2 and len(result["drawn"]) == 2 and result["wall_s"] > 0
    rng = np.random.default_rng(7)
    expected = [faultdraws.draw(rng) for _ in range(2)]
    assert [r["kind"] for r in result["drawn"]] == [d.kind for d in expected]
    assert [r["at_s"] for r in result["drawn"]] == [d.at_s for d in expected]
    assert set(result["targets_met"]) == {t.key for t in faultdraws.TARGETS}
    assert "drawn 2/2" in done.stderr


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("--drawn", "0"), "--drawn: 0 outside 1..100000"),
        (("--drawn", "2", "--only", "leg_stuck"), "takes neither --only nor --uncalibrated"),
        (("--drawn", "2", "--uncalibrated"), "takes neither --only nor --uncalibrated"),
        (("--drawn", "2", "--draw-seed", "-1"), "--draw-seed: -1 outside"),
    ],
)
def test_a_wrong_drawn_request_is_one_line_and_exit_2(args: tuple[str, ...], says: str) -> None:
    done = _bench(*args)
    assert done.returncode == 2 and done.stdout == ""
    assert says in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
