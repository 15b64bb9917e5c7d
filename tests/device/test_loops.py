"""Inner pressure loop, outer PD and impedance laws (eq. 4-17)."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from device import impedance, position_loop, pressure_loop

R = 0.8976
P_MIN, P_MAX = 1.8e5, 6.0e5

pressures = st.floats(2.0e5, 5.8e5)


@given(st.floats(-0.5e5, 0.5e5), pressures, pressures)
def test_distribution_makes_the_differential_with_least_change(
    dP: float, pl: float, pu: float
) -> None:
    P_l, P_u = pressure_loop.distribute(dP, pl, pu, R, 0.0, 1e7)
    assert P_l - R * P_u == pytest.approx(dP, abs=1e-6)
    e_l, e_u = P_l - pl, R * (P_u - pu)
    assert e_l == pytest.approx(-e_u, abs=1e-6)  # the change is split evenly, eq. (10)-(11)
    cost = e_l**2 + e_u**2
    for shift in np.linspace(-1e4, 1e4, 21):  # any other split costs more
        a, b = P_l + shift, (P_l + shift - dP) / R
        assert (a - pl) ** 2 + (R * (b - pu)) ** 2 >= cost * (1 - 1e-12) - 1e-6


@given(st.floats(-6e5, 6e5), pressures, pressures)
def test_distribution_respects_bounds(dP: float, pl: float, pu: float) -> None:
    P_l, P_u = pressure_loop.distribute(dP, pl, pu, R, P_MIN, P_MAX)
    assert P_MIN - 1e-6 <= P_l <= P_MAX + 1e-6
    assert P_MIN - 1e-6 <= P_u <= P_MAX + 1e-6


@given(st.floats(-0.5e5, 0.5e5), st.floats(0.0, 5.8e5), st.floats(0.0, 5.8e5))
def test_the_common_level_rises_at_most_a_step_and_keeps_the_differential(
    dP: float, pl: float, pu: float
) -> None:
    step = 0.04e5
    P_l, P_u = pressure_loop.distribute(dP, pl, pu, R, P_MIN, P_MAX)
    Q_l, Q_u = pressure_loop.ramp_common(P_l, P_u, dP, pl, pu, R, step)
    now, wanted = pl + R * pu, P_l + R * P_u
    if wanted > now + step:  # a vented leg's start: both sides rise, the force stays right
        assert Q_l + R * Q_u == pytest.approx(now + step, abs=1e-6)
        assert Q_l - R * Q_u == pytest.approx(dP, abs=1e-6)
    else:  # everything else (the sum kept, or falling) is eq. (10)-(12) untouched
        assert (Q_l, Q_u) == (P_l, P_u)


def test_pi_is_p_plus_i_and_stops_winding_up() -> None:
    u, integ = pressure_loop.pi_step(1000.0, 0.0, 1e-3, 0.01, 0.004)
    assert u == pytest.approx(1.0 + 0.01 * 4.0)
    assert integ == pytest.approx(4.0)
    integ = 0.0
    for _ in range(1000):  # huge persistent error: saturated output, integral frozen
        u, integ = pressure_loop.pi_step(5e5, integ, 1e-3, 0.01, 0.004)
    assert u == 100.0
    assert integ == 0.0
    u, _ = pressure_loop.pi_step(-10.0, integ, 1e-3, 0.01, 0.004)
    assert u < 0.0  # recovers at once when the error changes sign


def test_pd_law() -> None:
    dP = position_loop.pd(0.051, 0.050, 0.0, 0.02, 1e7, 1e5, 3000.0)
    assert dP == pytest.approx(1e7 * 0.001 - 1e5 * 0.02 + 3000.0)


def test_stiffness_settles_at_force_over_k() -> None:
    x = 0.0
    for _ in range(1000):
        x, rate = impedance.compliance_step(x, 10.0, 50.0, 1.0, 0.004)
    assert x == pytest.approx(0.2)
    assert rate == pytest.approx(0.0, abs=1e-9)


def test_compliance_step_is_the_exact_first_order_solution() -> None:
    x, _ = impedance.compliance_step(0.0, 10.0, 50.0, 2.0, 0.004)
    assert x == pytest.approx(0.2 * (1 - math.exp(-50.0 * 0.004 / 2.0)))
    x, rate = impedance.compliance_step(0.1, 5.0, 0.0, 2.0, 0.004)  # pure damping
    assert rate == pytest.approx(2.5)
    assert x == pytest.approx(0.1 + 0.01)
    x, _ = impedance.compliance_step(0.0, 5.0, 50.0, 0.0, 0.004)  # pure stiffness
    assert x == pytest.approx(0.1)


def _rk4_mass_spring(
    j: float, b: float, k: float, f: float, x: float, v: float, dt: float
) -> tuple[float, float]:
    n = 2000
    h = dt / n

    def d(x: float, v: float) -> tuple[float, float]:
        return v, (f - b * v - k * x) / j

    for _ in range(n):
        a1 = d(x, v)
        a2 = d(x + h / 2 * a1[0], v + h / 2 * a1[1])
        a3 = d(x + h / 2 * a2[0], v + h / 2 * a2[1])
        a4 = d(x + h * a3[0], v + h * a3[1])
        x += h / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
        v += h / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
    return x, v


@pytest.mark.parametrize(
    ("j", "b", "k"),
    [(0.03, 0.0, 500.0), (0.03, 0.1, 0.0), (0.01, 1.0, 50.0), (0.1, 10.0, 2.0), (0.088, 0.0, 0.0)],
)
def test_inertial_compliance_step_is_exact(j: float, b: float, k: float) -> None:
    x, v = impedance.inertial_compliance_step(0.01, 0.2, 3.0, j, k, b, 0.004)
    xr, vr = _rk4_mass_spring(j, b, k, 3.0, 0.01, 0.2, 0.004)
    assert x == pytest.approx(xr, rel=1e-9, abs=1e-12)
    assert v == pytest.approx(vr, rel=1e-9, abs=1e-12)


def test_inertial_compliance_settles_at_force_over_k_and_conserves_undamped_energy() -> None:
    x, v = 0.0, 0.0
    for _ in range(2000):
        x, v = impedance.inertial_compliance_step(x, v, 10.0, 0.03, 50.0, 1.0, 0.004)
    assert x == pytest.approx(0.2)
    assert v == pytest.approx(0.0, abs=1e-9)
    x, v = 0.1, 0.0  # B = 0: the exact map neither adds nor removes energy
    for _ in range(5000):
        x, v = impedance.inertial_compliance_step(x, v, 0.0, 0.03, 500.0, 0.0, 0.004)
    assert 0.5 * 500.0 * x**2 + 0.5 * 0.03 * v**2 == pytest.approx(0.5 * 500.0 * 0.01, rel=1e-9)
