"""Outer loop: PD position control of one leg with load compensation (eq. (14)-(15)).

``dP = Kp (L_c - L_m) + Kd (dL_c/dt - dL_m/dt) + G_p``. The derivative acts on the error
through the commanded velocity from the trajectory (a feedforward) and the measured velocity,
so a step target gives no derivative kick. ``G_p`` is the differential that holds the static
load: the paper's gravity compensation of the platform and leg masses, plus the wrench the
foot force sensor measures. Without the second term a PD loop (no integral) would sag by
several millimetres under a patient's torque and the rendered stiffness would be wrong.
"""

from __future__ import annotations

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
) -> float:
    """Desired pressure differential (Pa) for one leg, eq. (14)-(15)."""
    return kp * (target - measured) + kd * (target_rate - measured_rate) + compensation
