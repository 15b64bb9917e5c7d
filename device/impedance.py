"""Position-based impedance control (paper, section 6, eq. (16)-(17)).

The wrench the foot exerts, ``F``, drives a virtual compliance ``F = K X_m + B dX_m/dt``
(diagonal K and B over x, y, z, roll, pitch, yaw); the platform is commanded to
``X_c = X_d + X_m`` and inverse kinematics turns that into leg lengths. The foot therefore
feels ``F = K (X_c - X_d) + B (dX_c/dt - dX_d/dt)``: eq. (17) with the paper's sign, since
the device pushes back with ``-F``.

Each axis is integrated exactly over one control period for constant ``F`` (a first-order
lag of time constant ``B/K``), so the discrete update is stable for any K and B at 250 Hz.
That is NOT the stability of the loop: the admittance ``X_m/F`` is fed to a position loop
(about 6 Hz bandwidth, several ms of valve and filter delay) and the foot wrench it measures
depends on where the platform goes. With a small B (or B = 0) the admittance's bandwidth
``K/B`` (or its instantaneous jump ``F/K``) far exceeds what the legs can follow and the
coupled loop oscillates or trips (see ``lab_envelope.py`` and ``findings.md``). The device
therefore adds a virtual inertia J per axis (``inertial_compliance_step``):
``J ddX_m + B dX_m + K X_m = F``, which rolls the admittance off at high frequency.

The platform follows ``X_c`` some milliseconds late, and a foot feels that lag at ``w`` as
``(K - J w^2)`` times it of extra damping. The controller learns the lag per compliant axis
(``device.controller.learn_lag``) and runs this law with ``B - (K - J w^2) lag`` (``w`` at
``ControllerConfig.impedance_lag_band``) instead of ``B``, so that the foot feels the B it
was given. Above a corner of a few hertz, where a stiff or
resisting foot can make the loop ring, never below the stable envelope's least damping;
below it, where the foot feels the lag as damping, never below 0
(``ControllerConfig.impedance_lag_corner``): the law's rate, low-passed at the corner,
feeds the damping below the floor back as a force.
"""

from __future__ import annotations

import math

import numpy as np

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


@njit
def _mat3_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3x3 product written out (numba's ``@`` needs BLAS from scipy, not installed)."""
    c = np.zeros((3, 3))
    for r in range(3):
        for k in range(3):
            arc = a[r, k]
            for q in range(3):
                c[r, q] += arc * b[k, q]
    return c


@njit
def _expm3_augmented(
    j: float, b: float, k: float, dt: float
) -> tuple[float, float, float, float, float, float]:
    """exp(M dt) of M = [[0, 1, 0], [-k/j, -b/j, 1/j], [0, 0, 0]] by scaling and squaring.

    Returns (phi00, phi01, phi10, phi11, gamma0, gamma1): the exact zero-order-hold map
    ``[x, v]' = Phi [x, v] + Gamma F`` of ``j a + b v + k x = F`` over ``dt``.
    """
    m = np.zeros((3, 3))
    m[0, 1] = dt
    m[1, 0] = -k / j * dt
    m[1, 1] = -b / j * dt
    m[1, 2] = dt / j
    norm = 0.0
    for r in range(3):
        s = 0.0
        for c in range(3):
            s += abs(m[r, c])
        norm = max(norm, s)
    squarings = 0
    while norm > 0.25:
        norm *= 0.5
        squarings += 1
    scale = 0.5**squarings
    for r in range(3):
        for c in range(3):
            m[r, c] *= scale
    e = np.eye(3)
    term = np.eye(3)
    for n in range(1, 14):  # ||m|| <= 0.25: 0.25^14 / 14! is far below machine precision
        term = _mat3_mul(term, m) / n
        e = e + term
    for _ in range(squarings):
        e = _mat3_mul(e, e)
    return e[0, 0], e[0, 1], e[1, 0], e[1, 1], e[0, 2], e[1, 2]


@njit
def inertial_compliance_step(
    x_m: float, v_m: float, force: float, j: float, k: float, b: float, dt: float
) -> tuple[float, float]:
    """Advance one axis of ``j ddX_m + b dX_m + k X_m = F`` by ``dt``; returns (X_m, dX_m/dt).

    The virtual inertia ``j > 0`` is the device's, not the therapist's: it limits the
    acceleration and so the bandwidth of the admittance ``X_m / F`` to what the position
    loop can follow (see findings of the stability envelope). Exact for constant ``F`` over
    the step (zero-order hold), so any ``j, k, b >= 0`` is integrated stably: the discrete
    map has the continuous system's eigenvalues ``exp(lambda dt)``.
    """
    p00, p01, p10, p11, g0, g1 = _expm3_augmented(j, b, k, dt)
    return p00 * x_m + p01 * v_m + g0 * force, p10 * x_m + p11 * v_m + g1 * force


@njit
def step_map(
    j: float, k: float, b: float, dt: float
) -> tuple[float, float, float, float, float, float]:
    """The map of :func:`inertial_compliance_step` for ``j, k, b``: (phi00, phi01, phi10,
    phi11, gamma0, gamma1), so that X_m' = phi00 X_m + phi01 V_m + gamma0 F and
    V_m' = phi10 X_m + phi11 V_m + gamma1 F. The controller keeps it while J, K, B hold."""
    return _expm3_augmented(j, b, k, dt)
