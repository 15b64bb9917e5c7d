"""Valve switches and air come from the plant's own counters, at rest and exercising."""

from __future__ import annotations

import pytest

from lab import experiments, valves


def test_at_rest_wave_1s_scheme_fires_every_valve_and_the_air_is_counted() -> None:
    rest = valves.measure("wave1", "rest")
    assert rest.trip is None
    # The compensated PWM's minimum pulse alternates intake and exhaust: each valve fires
    # every other 4 ms period, 125 times a second (what a quiet scheme must bring down).
    assert rest.switches_per_s_mean == pytest.approx(125.0, abs=10.0)
    assert rest.air_nl_per_min > 10.0  # every pulse vents air that the next refills
    assert rest.steady_error_mm < 0.3


@pytest.mark.parametrize("draw", [None, 4, 33], ids=["nominal", "draw4", "draw33"])
def test_the_quiet_hold_rests_the_valves_and_holds_the_legs_as_closely(draw: int | None) -> None:
    # Drawn builds too: each valve opens at its own delay, so the dose widths are learnt
    # (measured on draw 33: 4.4 switches a second, busiest 15, error 0.15 mm).
    with experiments.on_plant(experiments.PlantChoice(draw=draw)):
        quiet = valves.measure("quiet", "rest")
    assert quiet.trip is None
    # Single doses of air instead of a pulse every period: a few switches a second.
    assert quiet.switches_per_s_mean < 10.0
    assert quiet.switches_per_s_max < 25.0
    assert quiet.air_nl_per_min < 10.0
    assert quiet.steady_error_mm < 0.3


def test_an_unknown_scheme_or_situation_is_refused() -> None:
    with pytest.raises(ValueError, match="scheme"):
        valves.measure("silent", "rest")
    with pytest.raises(ValueError, match="situation"):
        valves.measure("wave1", "sleeping")
