"""The quiet hold's doses (device.quiet): how long a dose is, and which ones teach a valve."""

import numpy as np
import pytest

from device import quiet
from device.controller import ControllerConfig, build_params

Q = quiet.QuietParams(
    on=True,
    enter=50e-6,
    periods=12,
    dose=100e-6,
    wake=500e-6,
    move=150e-6,
    settle=1,
    quantum=1.5e3,
    rate=1e-3,
    polytropic=1.2,
    share=0.7,
    extra_max=8,
    landing=4,
    blind=4,
)
CAP, ROD = 4.9e-4, 4.4e-4
PER_SLOT = (1.5e3, 1.2e3, 1.6e3, 1.3e3)  # Pa a slot: cap in, cap out, rod in, rod out


def test_a_dose_within_one_quantum_is_the_valves_shortest() -> None:
    assert quiet.lengthen(0.0, 1.5e3, Q) == 0
    assert quiet.lengthen(Q.quantum, 1.5e3, Q) == 0
    assert quiet.lengthen(5e3, 0.0, Q) == 0  # no flow that way: nothing to size it with


def test_a_larger_one_takes_a_share_of_what_is_left_up_to_the_cap() -> None:
    # 0.7 of (6 - 1.5) kPa at 1.5 kPa a slot: 2.1 slots, rounded down.
    assert quiet.lengthen(6.0e3, 1.5e3, Q) == 2
    assert quiet.lengthen(1.0e6, 1.5e3, Q) == Q.extra_max


def _dose(
    error: float, force: float, landing: float = 4.0
) -> tuple[tuple[int, int], np.ndarray, np.ndarray]:
    """Leg 0's dose when it will settle ``error`` short, ``force`` short of its target."""
    rest = quiet.new_rest()
    rest[0, quiet.R_LANDING] = landing
    dose = np.zeros(24, dtype=np.int64)
    dose[0] = 6  # leg 0's cap intake has learnt its width
    pressure = np.full(12, 4.5e5)
    out = quiet.dose_slots(
        rest, dose, 0, error, pressure, 4.6e5, 4.5e5, True, True, Q, 7, force, (CAP, ROD),
        PER_SLOT, error,
    )  # fmt: skip
    return out, rest, dose


def test_a_leg_that_will_settle_far_short_gets_one_longer_pulse_that_teaches_nothing() -> None:
    # 4 N short on the cap (8.2 kPa): the learnt 6 slots and 0.7 of the 6.7 kPa left.
    (cap, rod), rest, dose = _dose(0.4e-3, 4.0)
    assert rod == 0 and cap == 6 + 3
    assert rest[0, quiet.R_DOSED] == -1.0  # a lengthened dose does not change the width
    assert dose[0] == 6


def test_after_its_landing_a_leg_far_short_gets_the_shortest_pulse() -> None:
    # A leak or a changed load builds up slowly; a false load on the force sensor would be
    # followed as fast as the full loop by lengthened doses.
    (cap, rod), rest, _ = _dose(0.4e-3, 4.0, landing=0.0)
    assert (cap, rod) == (6, 0) and rest[0, quiet.R_DOSED] == 0.0


def test_a_leg_a_little_short_gets_the_shortest_pulse_and_learns_from_it() -> None:
    (cap, rod), rest, _ = _dose(0.15e-3, 0.5)
    assert (cap, rod) == (6, 0)
    assert rest[0, quiet.R_DOSED] == 0.0


def test_a_leg_within_the_dose_band_gets_none() -> None:
    (cap, rod), _, _ = _dose(0.05e-3, 4.0)
    assert (cap, rod) == (0, 0)


def test_a_rest_starts_with_its_landing_and_the_error_it_rested_at() -> None:
    rest = quiet.new_rest()
    for _ in range(Q.periods - 1):
        assert not quiet.enter(rest, 2, 0.05, 0.0, 0.05 + 10e-6, Q)
    assert quiet.enter(rest, 2, 0.05, 0.0, 0.05 + 10e-6, Q)
    assert rest[2, quiet.R_LANDING] == Q.landing and rest[2, quiet.R_BLIND] == 0.0
    assert rest[2, quiet.R_SEEN] == pytest.approx(-10e-6)


def test_a_leg_whose_reading_does_not_move_gets_no_more_than_blind_doses() -> None:
    """A frozen reading: the force the leg should make keeps growing (the foot pushing back
    on a platform that moves unseen), its reading never changes."""
    rest = quiet.new_rest()
    dose = np.full(24, 6, dtype=np.int64)
    pressure = np.full(12, 4.5e5)
    fired = []
    for _ in range(20):
        cap, rod = quiet.dose_slots(
            rest, dose, 0, 0.3e-3, pressure, 4.6e5, 4.5e5, True, True, Q, 7, 0.5, (CAP, ROD),
            PER_SLOT, 0.02e-3,
        )  # fmt: skip
        fired.append(cap != 0 or rod != 0)
    assert sum(fired) == Q.blind
    # The reading moves: it is followed again.
    cap, rod = quiet.dose_slots(
        rest, dose, 0, 0.3e-3, pressure, 4.6e5, 4.5e5, True, True, Q, 7, 0.5, (CAP, ROD),
        PER_SLOT, 0.044e-3,
    )  # fmt: skip
    assert (cap, rod) != (0, 0)


@pytest.mark.parametrize(
    "change",
    [
        {"rest_dose_share": 1.5},
        {"rest_dose_share": -0.1},
        {"rest_dose_extra_max": 29},
        {"rest_landing_periods": -1},
        {"rest_blind_doses": -1},
    ],
)
def test_a_landing_or_blind_bound_no_hold_could_use_is_refused(change: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="rest_"):
        build_params(ControllerConfig(**change))  # type: ignore[arg-type]
