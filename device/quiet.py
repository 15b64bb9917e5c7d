"""The quiet hold: a leg at rest is held by the air trapped in its chambers, not by chatter.

Wave 1's loop fires a minimum pulse on every chamber every PWM period at rest: the
dead-band compensation turns any pressure error, however small, into a pulse of at least
the valve's response time, and that pulse moves a chamber by 0.06-0.08 bar, more than the
loop asked for, so the next period answers it the other way. Every valve switched about 125
times a second all day, and the compressor fed the dither 150 NL/min.

Here a leg that has stood within ``enter`` of a still target for ``periods`` control
periods rests: both chambers close and its integrals keep what they learnt. Closed, the
chambers are an air spring (about 10 N/mm per leg at working pressures) that holds the leg
where it is against the load. The leg is corrected by single doses of air while it rests:

- a leg that will settle more than ``dose`` from its target (judged from its reading and
  from the force its shut chambers make: :func:`settles_at`) gets one pulse on the
  chamber that moves it back (the cap's intake or the rod side's exhaust to extend, the
  other two to retract: whichever chamber is further from the pressure the loop would
  want), then
  ``settle`` periods before the next (the dose's air reaches the transducer within one);
- the dose is as short as the valve allows: each valve learns it (``dose_slots``). A pulse
  shorter than a valve's opening delay passes nothing, one a slot or two longer passes a
  little air, and where that edge lies differs from valve to valve and build to build
  (0.55-1.2 ms). After each dose the chamber's pressure change says whether it was too
  large (more than twice ``quantum``: one slot less next time) or passed nothing (under
  half of it: one slot more). The widths start at the loop's own minimum pulse, which
  every build opens.

- in the first ``landing`` periods of a rest a dose is lengthened to answer what the
  valves left as they shut at once (:func:`lengthen`).

The leg wakes (the full loop, its integrals where it left them) when the reading is more
than ``wake`` from its target or the target has moved ``move`` since the rest began.

A resting leg gets at most ``blind`` doses while its reading does not change. What holds
it includes the foot's measured wrench, and the foot pushes back on a platform that moves:
with a leg's reading frozen, each dose that followed the foot's growing push extended that
leg further unseen (a held platform turned 5.4 deg, 17.5 mm in 2 s). A healthy leg that
follows a changing load without moving (its seals hold it) stops following after as many;
the load then moves it on its air, its reading changes, and it follows again.

With the valves shut a leg whose sensor stopped is held by its air as any other (a frozen
reading gets at most ``blind`` doses), and a chamber that loses air shows it at once: the
supervision's valve and air checks see a leak or an exhaust stuck open within 21 ms of
holding.

State per leg in ``rest`` (slots R_*), learnt widths per valve in ``dose``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from device._jit import njit_inline

R_ON = 0
"""1 while the leg rests."""
R_STILL = 1
"""Control periods in a row within the enter band of a still target."""
R_WAIT = 2
"""Periods left before the next dose may fire."""
R_TARGET = 3
"""The target when the rest began (m)."""
R_DOSED = 4
"""Valve (0-23) of the dose fired last period, to learn from (-1: none)."""
R_P_BEFORE = 5
"""Its chamber's pressure before that dose (Pa)."""
R_LANDING = 6
"""Control periods left in which a dose may be lengthened (see :func:`lengthen`)."""
R_BLIND = 7
"""Doses the leg has had since its reading last changed."""
R_SEEN = 8
"""Its measured error (m) when its reading last changed."""
N_REST = 9


class QuietParams(NamedTuple):
    on: bool
    enter: float
    periods: int
    dose: float
    wake: float
    move: float
    settle: int
    quantum: float
    rate: float
    polytropic: float
    share: float
    extra_max: int
    landing: int
    blind: int


def new_rest() -> NDArray[np.float64]:
    rest = np.zeros((6, N_REST))
    rest[:, R_DOSED] = -1.0
    return rest


@njit_inline
def reset(rest: NDArray[np.float64], leg: int) -> None:
    """The leg is driven by the full loop (or not at all)."""
    rest[leg, R_ON] = 0.0
    rest[leg, R_STILL] = 0.0
    rest[leg, R_WAIT] = 0.0
    rest[leg, R_DOSED] = -1.0


@njit_inline
def drifted(rest: NDArray[np.float64], leg: int, target: float, x: float, q: QuietParams) -> bool:
    """Whether a resting ``leg`` wakes this period because it drifted off a target that did
    not move (evaluate before :func:`resting`, which forgets the rest)."""
    if not q.on or rest[leg, R_ON] < 0.5:
        return False
    return abs(target - x) > q.wake and abs(target - rest[leg, R_TARGET]) <= q.move


@njit_inline
def resting(rest: NDArray[np.float64], leg: int, target: float, x: float, q: QuietParams) -> bool:
    """Whether a resting ``leg`` goes on resting this control period (else it wakes)."""
    if not q.on or rest[leg, R_ON] < 0.5:
        return False
    if abs(target - x) > q.wake or abs(target - rest[leg, R_TARGET]) > q.move:
        reset(rest, leg)
        return False
    return True


@njit_inline
def enter(
    rest: NDArray[np.float64],
    leg: int,
    target: float,
    target_rate: float,
    x: float,
    q: QuietParams,
) -> bool:
    """Whether a driven ``leg`` starts resting this period: it has stood within ``enter`` of
    a still target for ``periods`` periods."""
    if not q.on:
        return False
    if abs(target - x) < q.enter and abs(target_rate) < q.rate:
        rest[leg, R_STILL] += 1.0
    else:
        rest[leg, R_STILL] = 0.0
        return False
    if rest[leg, R_STILL] < q.periods:
        return False
    rest[leg, R_ON] = 1.0
    rest[leg, R_TARGET] = target
    rest[leg, R_WAIT] = 0.0
    rest[leg, R_DOSED] = -1.0
    rest[leg, R_LANDING] = float(q.landing)
    rest[leg, R_BLIND] = 0.0
    rest[leg, R_SEEN] = target - x
    return True


@njit_inline
def learn(
    rest: NDArray[np.float64], dose: NDArray[np.int64], leg: int, pressure: NDArray[np.float64],
    q: QuietParams, max_slots: int,
) -> None:  # fmt: skip
    """What last period's dose did to its chamber sets that valve's next width."""
    v = int(rest[leg, R_DOSED])
    if v < 0:
        return
    rest[leg, R_DOSED] = -1.0
    moved = abs(pressure[v // 2] - rest[leg, R_P_BEFORE])
    if moved > 2.0 * q.quantum and dose[v] > 1:
        dose[v] -= 1
    elif moved < 0.5 * q.quantum and dose[v] < max_slots:
        dose[v] += 1


@njit_inline
def settles_at(error: float, made: float, hold: float, stiffness: float) -> float:
    """Where the leg will settle on its trapped air, as its error from the target (m).

    ``made``: the force its chambers make (N); ``hold``: what holds it still (the load
    compensation and what the outer integral learnt; N); ``stiffness``: its shut chambers'
    (N/m, :func:`air_stiffness`): a surplus of force moves the leg by surplus over it.
    Closing the valves at an instant of the loop's pulses leaves up to 3-4 N over or under,
    which would move the leg 0.3 mm: the first dose answers that before the leg has moved.
    """
    return error - (made - hold) / stiffness


@njit_inline
def air_stiffness(
    p_lo: float, p_up: float, v_lo: float, v_up: float, a_lo: float, a_up: float, q: QuietParams
) -> float:
    """Stiffness (N/m) of a leg's two closed chambers: ``n p A^2 / V`` each."""
    return q.polytropic * (p_lo * a_lo * a_lo / v_lo + p_up * a_up * a_up / v_up)


@njit_inline
def dose_slots(
    rest: NDArray[np.float64],
    dose: NDArray[np.int64],
    leg: int,
    error: float,
    pressure: NDArray[np.float64],
    p_lo: float,
    p_up: float,
    intake_ok_lo: bool,
    intake_ok_up: bool,
    q: QuietParams,
    start: int,
    force: float,
    areas: tuple[float, float],
    per_slot: tuple[float, float, float, float],
    measured: float,
) -> tuple[int, int]:
    """Signed slots (cap, rod side) of this period's dose: (0, 0) but for one pulse when the
    resting leg has drifted ``dose`` from its target. ``p_lo``, ``p_up``: the pressures the
    loop would want (Pa gauge). ``force``: what the leg's air should push more to settle on
    its target (N, + extends); ``areas``: cap and rod side (m2); ``per_slot``: how much one
    slot more of each valve (cap intake, cap exhaust, rod intake, rod exhaust) changes its
    chamber's pressure (Pa, from its flow at the present pressures; 0 outside a landing,
    where nothing is lengthened). A dose that has more to answer than one quantum is
    lengthened by ``share`` of what is left (see :func:`lengthen`), in the first
    ``landing`` periods of the rest only: what the valves left as they shut. Later, a leg
    that has further to go gets the shortest dose: what moves it then (a leak, a changed
    load) builds up slowly, and lengthened doses would follow a force sensor's false load
    as fast as the full loop. ``measured``: the leg's
    reading's error from its target (m); after ``blind`` doses without a change of it, none
    (see the module's docstring)."""
    if measured != rest[leg, R_SEEN]:
        rest[leg, R_SEEN] = measured
        rest[leg, R_BLIND] = 0.0
    landing = rest[leg, R_LANDING] > 0.5
    if landing:
        rest[leg, R_LANDING] -= 1.0
    if rest[leg, R_WAIT] > 0.5:
        rest[leg, R_WAIT] -= 1.0
        return 0, 0
    if abs(error) <= q.dose:
        return 0, 0
    if rest[leg, R_BLIND] >= q.blind:
        return 0, 0  # its reading has not moved for the last ``blind``: see the module
    rest[leg, R_BLIND] += 1.0
    lo, up = 2 * leg, 2 * leg + 1
    if error > 0.0:  # extend: air into the cap, or out of the rod side
        cap_wants = p_lo - pressure[lo] if intake_ok_lo else -np.inf
        rod_wants = pressure[up] - p_up
        cap = cap_wants >= rod_wants
        v = 2 * lo if cap else 2 * up + 1
    else:  # retract: air out of the cap, or into the rod side
        cap_wants = pressure[lo] - p_lo
        rod_wants = p_up - pressure[up] if intake_ok_up else -np.inf
        cap = cap_wants >= rod_wants
        v = 2 * lo + 1 if cap else 2 * up
    if dose[v] == 0:
        dose[v] = start
    extra = 0
    if landing:
        extra = lengthen(abs(force) / areas[0 if v // 2 == lo else 1], per_slot[v - 2 * lo], q)
    # Only a shortest dose teaches its valve's width (learn); a lengthened one does not.
    rest[leg, R_DOSED] = float(v) if extra == 0 else -1.0
    rest[leg, R_P_BEFORE] = pressure[v // 2]
    rest[leg, R_WAIT] = float(q.settle)
    n = int(dose[v]) + extra
    if v % 2 == 1:
        n = -n
    if v // 2 == lo:
        return n, 0
    return 0, n


@njit_inline
def lengthen(wanted: float, per_slot: float, q: QuietParams) -> int:
    """Slots (0 to ``extra_max``) to add to a valve's shortest dose, which moves its chamber
    by about one ``quantum``, when the chamber should move by ``wanted`` (Pa): ``share`` of
    what is left beyond that quantum, at ``per_slot`` Pa a slot. Closing the valves at an
    instant of the loop's dither leaves 3-4 N over or under (5 quanta); answered a quantum
    at a time, the leg ran 0.3 mm on its air spring before the doses caught up, and stiff
    seals then held it there."""
    if per_slot <= 0.0 or wanted <= q.quantum:
        return 0
    extra = int(q.share * (wanted - q.quantum) / per_slot)
    return min(max(extra, 0), q.extra_max)
