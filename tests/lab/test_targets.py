"""The paper's headline results on the simulated plant (see ``ankle bench control``).

These run the real controller against the plant for seconds of simulated time; they check
behaviour, not speed (the real-time factor is measured by the benchmark, not asserted here).
"""

import math

import pytest

from lab import experiments as ex


@pytest.mark.parametrize(("leg", "mm"), [(1, 10.0), (4, -10.0), (2, 10.0)])
def test_leg_step_meets_rise_overshoot_and_steady_error(leg: int, mm: float) -> None:
    m = ex.step(leg=leg, mm=mm).metrics
    assert m.rise_ms <= 90.0
    assert m.overshoot_pct <= 2.0
    assert m.steady_error_mm <= 0.3


def test_deadband_compensation_is_better_than_without() -> None:
    comp = ex.step(leg=1, mm=10.0, compensate=True).metrics
    raw = ex.step(leg=1, mm=10.0, compensate=False).metrics
    worse_settling = math.isnan(raw.settling_ms) or raw.settling_ms > comp.settling_ms
    assert worse_settling or raw.steady_error_mm > 2 * comp.steady_error_mm


def test_staircase_of_0_3_mm_is_resolved() -> None:
    assert ex.staircase(leg=1, step_mm=0.3).resolution_mm <= 0.3


def test_pitch_follows_7_hz_within_3_db() -> None:
    assert ex.sine("pitch", 2.0, 7.0).gain_db >= -3.0
    assert abs(ex.sine("pitch", 2.0, 1.0).gain_db) < 1.0


@pytest.mark.parametrize("k", [20.0, 50.0, 100.0])
def test_rendered_pitch_stiffness_is_within_5_percent(k: float) -> None:
    assert ex.impedance("pitch", k=k, b=1.0, torque=min(10.0, k * 0.3)).error_pct <= 5.0
