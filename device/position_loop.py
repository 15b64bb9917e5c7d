"""Outer loop: PD position control of one leg with load compensation (eq. (14)-(15)).

``dP = Kp (L_c - L_m) + Kd (dL_c/dt - dL_m/dt) + G_p``. The derivative acts on the error
through the commanded velocity from the trajectory (a feedforward) and the measured velocity,
so a step target gives no derivative kick. ``G_p`` is the differential that holds the static
load: the paper's gravity compensation of the platform and leg masses, plus the wrench the
foot force sensor measures. Without the second term a PD loop (no integral) would sag by
several millimetres under a patient's torque and the rendered stiffness would be wrong.

The position error is clamped to ``max_error`` before the gain (an extension of the paper).
Far from the target the loop then cruises where the clamped proportional term balances the
derivative term, at about ``kp max_error / kd``: the controller sets ``max_error`` so that
this is a chosen approach speed below the device's speed limit. A plain PD accelerates in
proportion to the step, and steps of 20 mm and more tripped the speed limit. The clamp also
bounds the force that a large position error (a blocked leg) can command.
"""

from __future__ import annotations

import math

from device._jit import njit


@njit
def pd(
    target: float,
    measured: float,
    target_rate: float,
    measured_rate: float,
    kp: float,
    kd: float,
    compensation: float,
    max_error: float = math.inf,
) -> float:
    """Desired pressure differential (Pa) for one leg, eq. (14)-(15).

    The position error is clamped to ``max_error`` (m) before the gain: see the module
    docstring.
    """
    error = min(max_error, max(-max_error, target - measured))
    return kp * error + kd * (target_rate - measured_rate) + compensation


@njit
def integrate(
    integral: float,
    error: float,
    rate_error: float,
    ki: float,
    dt: float,
    zone: float,
    speed: float,
    bound: float,
) -> float:
    """The outer loop's integral (Pa) after one control period: it runs only while the
    error is within ``zone`` (m) and the rate error within ``speed`` (m/s), and stays within
    +-``bound`` (an extension of the paper; see ControllerConfig.position_ki)."""
    if abs(error) < zone and abs(rate_error) < speed:
        integral += ki * error * dt
    return min(bound, max(-bound, integral))
