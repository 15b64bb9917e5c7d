"""PWM of a pair of on/off valves per chamber (paper, section 4).

One PWM period is 4 ms (250 Hz) split into 28 slots of one tick each (resolution 1/28). For
control input ``u`` (percent, -100..100): ``u > 0`` energises the intake valve for the first
``n`` slots of the period, ``u < 0`` the exhaust valve, ``u = 0`` holds (close-close). The
open-open state is never produced.

Dead-band compensation, eq. (1)-(3): a valve whose response time is ``T_v`` passes nothing
for a pulse shorter than ``T_v`` and never closes for a gap shorter than ``T_v``, so usable
duty lies in ``[d_dead, 100 - d_dead]`` with ``d_dead = 100 T_v / T_PWM``; the input is mapped
onto that range: ``d = d_dead + S_v u`` with ``|S_v| = (100 - 2 d_dead) / 100``.
"""

from __future__ import annotations

from device._jit import njit

PWM_SLOTS = 28
"""Ticks per PWM period: 4 ms / (1/7000 s)."""
PWM_PERIOD = 4e-3
"""PWM period (s): 250 Hz."""


@njit
def dead_band(valve_response_time: float, pwm_period: float) -> float:
    """Minimum usable duty ``d_dead`` (percent), eq. (1)."""
    return 100.0 * valve_response_time / pwm_period


@njit
def duty(u: float, d_dead: float, compensate: bool) -> float:
    """Signed duty (percent of the period) for control input ``u`` (percent), eq. (2)-(3).

    Without compensation the input is the duty. With it, any nonzero input lands in
    ``[d_dead, d_max]``, ``d_max = 100 - d_dead``.
    """
    u = max(-100.0, min(100.0, u))
    if u == 0.0:
        return 0.0
    if not compensate:
        return u
    slope = (100.0 - 2.0 * d_dead) / 100.0
    if u > 0.0:
        return d_dead + slope * u
    return -(d_dead - slope * u)


@njit
def duty_slots(duty_percent: float) -> int:
    """Signed number of slots (of 28) the intake (+) or exhaust (-) valve is energised."""
    n = int(abs(duty_percent) * PWM_SLOTS / 100.0 + 0.5)
    n = min(n, PWM_SLOTS)
    return n if duty_percent >= 0.0 else -n


@njit
def valve_states(slots: int, slot_index: int) -> tuple[int, int]:
    """(intake, exhaust) coil states at ``slot_index`` (0..27) of a period."""
    if slots > 0 and slot_index < slots:
        return 1, 0
    if slots < 0 and slot_index < -slots:
        return 0, 1
    return 0, 0
