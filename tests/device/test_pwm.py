import pytest

from device import pwm


def test_dead_band_of_the_paper() -> None:
    assert pwm.dead_band(1e-3, 4e-3) == pytest.approx(25.0)


def test_compensated_duty_spans_dead_band_to_max() -> None:
    d = pwm.dead_band(1e-3, 4e-3)
    assert pwm.duty(100.0, d, True) == pytest.approx(75.0)
    assert pwm.duty(1e-9, d, True) == pytest.approx(25.0)
    assert pwm.duty(-100.0, d, True) == pytest.approx(-75.0)
    assert pwm.duty(50.0, d, True) == pytest.approx(50.0)
    assert pwm.duty(0.0, d, True) == 0.0
    assert pwm.duty(250.0, d, True) == pytest.approx(75.0)  # input saturates


def test_uncompensated_duty_is_the_input() -> None:
    assert pwm.duty(10.0, 25.0, False) == 10.0
    assert pwm.duty(-100.0, 25.0, False) == -100.0


def test_slots_round_to_the_1_28_resolution() -> None:
    assert pwm.duty_slots(25.0) == 7
    assert pwm.duty_slots(-75.0) == -21
    assert pwm.duty_slots(100.0) == 28
    assert pwm.duty_slots(1.0) == 0


def test_valve_pair_is_never_open_open_and_on_time_matches_slots() -> None:
    for slots in range(-28, 29):
        states = [pwm.valve_states(slots, i) for i in range(pwm.PWM_SLOTS)]
        assert all(not (a and b) for a, b in states)
        assert sum(a for a, _ in states) == max(slots, 0)
        assert sum(b for _, b in states) == max(-slots, 0)
