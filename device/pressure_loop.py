"""Inner loop: chamber pressures for a force differential (paper, section 5, eq. (4)-(13)).

All pressures here are gauge. With gauge pressures the piston force is exactly
``A_l P_l - A_u P_u`` (the atmosphere on the rod's end cancels), so eq. (4) holds without a
rod term: ``df = A_l (P_l - r P_u) = A_l dP`` with ``r = A_u / A_l``.

Eq. (10)-(11) split ``dP`` so that the sum of squared changes of ``P_l`` and ``r P_u`` from
their measured values is least: both move by half of the needed change. (Eq. (11) as
printed subtracts ``dP/2`` inside the bracket; the form consistent with eq. (4), used here,
is ``r P_u = (P_lm + r P_um - dP) / 2``.) Eq. (12) bounds both to
``[P_critical, P_supply]``; when one side is clamped the other takes up the rest of ``dP``
where it can, since the differential is what makes force.

The PI of eq. (13) can hold its integral (``integrate=False``): the controller integrates
only near the leg's target. There the integral's job is small and slow, to trim the pattern
of minimum-width valve pulses so that its mean pressure is the desired one; during a move
the errors are large and one-sided and integrating them only stores a trim that is wrong
once the leg arrives.
"""

from __future__ import annotations

from device._jit import njit


@njit
def distribute(
    dP: float, P_lm: float, P_um: float, r: float, p_min: float, p_max: float
) -> tuple[float, float]:
    """Desired (lower, upper) gauge pressures for differential ``dP``, eq. (10)-(12)."""
    s = P_lm + r * P_um
    P_l = 0.5 * (s + dP)
    P_u = 0.5 * (s - dP) / r
    if P_l > p_max:
        P_l = p_max
        P_u = (P_l - dP) / r
    elif P_l < p_min:
        P_l = p_min
        P_u = (P_l - dP) / r
    if P_u > p_max:
        P_u = p_max
        P_l = min(p_max, max(p_min, dP + r * P_u))
    elif P_u < p_min:
        P_u = p_min
        P_l = min(p_max, max(p_min, dP + r * P_u))
    return P_l, P_u


@njit
def ramp_common(
    P_l: float, P_u: float, dP: float, P_lm: float, P_um: float, r: float, step: float
) -> tuple[float, float]:
    """Desired pressures with their common level (``P_l + r P_u``) rising at most ``step``
    (Pa) above the measured one: eq. (10)-(12) keep the measured sum, and only the clamp
    to ``p_min`` raises it, as when a vented leg starts. Filled at once from vented, the
    cap side (a few cm3 at its stop) reached its target long before the rod side (the
    whole stroke's annulus), and the differential that made launched an empty, light
    platform into its leg-speed limit; ramped, both sides rise with the differential
    kept."""
    now = P_lm + r * P_um
    if P_l + r * P_u > now + step:
        common = now + step
        P_l = 0.5 * (common + dP)
        P_u = 0.5 * (common - dP) / r
    return P_l, P_u


@njit
def pi_step(
    error: float, integral: float, kp: float, ki: float, dt: float, integrate: bool = True
) -> tuple[float, float]:
    """PI of eq. (13) with clamping anti-windup; returns (u percent, new integral).

    The integral only moves while ``integrate`` is set and the output is unsaturated or
    the error drives it back; otherwise it is held (and still acts).
    """
    candidate = integral + error * dt if integrate else integral
    u = kp * error + ki * candidate
    if u > 100.0:
        u = 100.0
        if error > 0.0:
            candidate = integral
    elif u < -100.0:
        u = -100.0
        if error < 0.0:
            candidate = integral
    return u, candidate
