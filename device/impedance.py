"""Position-based impedance control (paper, section 6, eq. (16)-(17)).

The wrench the foot exerts, ``F``, drives a virtual compliance ``F = K X_m + B dX_m/dt``
(diagonal K and B over x, y, z, roll, pitch, yaw); the platform is commanded to
``X_c = X_d + X_m`` and inverse kinematics turns that into leg lengths. The foot therefore
feels ``F = K (X_c - X_d) + B (dX_c/dt - dX_d/dt)``: eq. (17) with the paper's sign, since
the device pushes back with ``-F``.

Each axis is integrated exactly over one control period for constant ``F`` (a first-order
lag of time constant ``B/K``), so any K and B are stable at 250 Hz.
"""

from __future__ import annotations

import math

from device._jit import njit


@njit
def compliance_step(x_m: float, force: float, k: float, b: float, dt: float) -> tuple[float, float]:
    """Advance one axis of eq. (16) by ``dt``; returns (X_m, dX_m/dt).

    ``k = 0`` with ``b > 0`` is pure damping; ``b = 0`` with ``k > 0`` pure stiffness.
    Both zero is refused upstream (it would be no impedance at all).
    """
    if b <= 0.0:
        x_new = force / k if k > 0.0 else x_m
        return x_new, (x_new - x_m) / dt
    if k <= 0.0:
        rate = force / b
        return x_m + rate * dt, rate
    target = force / k
    x_new = target + (x_m - target) * math.exp(-k * dt / b)
    return x_new, (force - k * x_new) / b
