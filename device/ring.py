"""The ring guard: a compliant axis that rings with the foot on it gets more damping.

The admittance law takes the position loop's lag out of the damping it renders, down to
the stable envelope's least damping (device.controller.pose_task), and that envelope was
measured with the patients the plant models. A patient who co-contracts on a stiff ankle
closes a stiffer loop through the force sensor: its spring sees the loop's lag as negative
damping, and the plate rings at 6-11 Hz, 0.3-0.7 deg peak to peak, where the law's damping
is too small for that foot (pitch at K = 50 with the law at 0.4 N m s/rad, or at K = 5 with
0.8, on a 30 N m/rad ankle resisting: docs/envelope.md, section 7). The foot cannot be
weighed from the wrench alone while it also pushes; its ringing can be seen.

A ring is a run of ``cycles`` half-cycles in a row of the law's rate ``dX_m/dt`` (high-passed
at ``corner``: two second-order sections), each half-cycle as long as one of a 5-25 Hz
oscillation and reaching ``rate`` (rad/s) or more, the peaks of its second half reaching on
average ``sustain`` of those of its first. Nothing a foot does voluntarily looks like that: a
patient's torque moves the law below 4 Hz, a push or a kick excites it for a few half-cycles
that die away, and a ring goes on until something changes. Measured on the rings above and on a
relaxed, resisting and absent foot pushed, driven by 5-15 N m torque sines at 0.5-3 Hz and
exercised at 0.5 Hz (8 deg) and 3 Hz (2 deg): the rings ran on at an even or growing
amplitude; the rest ran at most 8 half-cycles over 0.05 rad/s. A stiff axis pushed on an
empty plate rings down on the law's own light virtual mode (K 150-500, the virtual
frequency held at 9 Hz) for 12 half-cycles and more; where that mode is slowest to die
(yaw at K = 500 and B = 0.3 keeps about 0.7 of its amplitude over half a run) a share alone
would not tell it from a ring, so a ring must also keep ``own`` times what the law's own
damping would leave of it. And a run at a multiple (up to the fifth) of the axis's own sine
is the exercise's motion, not a ring: a 3 Hz, 2 deg pitch sine against a resisting foot at
K = 200 moves the law at 9 Hz (0.015 deg on the platform).

Each ring seen multiplies the damping the law renders on that axis by ``step``, up to
``most`` times what it would render without the guard, and starts the count anew. The
factor stays until the axis's prescribed stiffness or damping changes or the device homes
again (a new exercise; ``forget``), through the pauses between repetitions, each a segment
of its own: a foot that rang once rings again when the damping is taken back, and the
foot feels a little more damping for the rest of the exercise rather than a ring at every
repetition.

State per axis in ``ring`` (slots G_*).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from device._jit import njit_inline

G_Z = 0
"""Four slots: the two high-pass sections' states."""
G_SIGN = 4
"""Sign of the high-passed rate at the last period (0: not yet)."""
G_HALF = 5
"""Control periods since its last change of sign."""
G_PEAK = 6
"""Largest magnitude in the half-cycle under way."""
G_RUN = 7
"""Half-cycles in a row that looked like a ring."""
G_FACTOR = 8
"""What the damping the law renders is multiplied by (1: nothing seen)."""
G_RINGS = 9
"""Rings seen since the factor was last reset."""
G_K = 10
"""The prescribed stiffness the factor was found under."""
G_B = 11
"""The prescribed damping the factor was found under."""
G_HZ = 12
"""Frequency of the last ring seen (Hz, from its half-cycles)."""
G_SUM = 13
"""Control periods of the half-cycles of the run under way."""
G_EARLY = 14
"""Sum of the peaks of the run's first half (its first ``cycles // 2`` half-cycles)."""
G_LATE = 15
"""...and of its second half."""
N_RING = 16


class RingParams(NamedTuple):
    on: NDArray[np.float64]  # (6,) 1 where an axis is watched
    b: NDArray[np.float64]  # (5,) high-pass section: b0, b1, b2, a1, a2
    rate: float  # rad/s a half-cycle must reach
    cycles: int  # half-cycles in a row that make a ring
    half_min: int  # control periods (the shortest half-cycle: the highest frequency)
    half_max: int
    sustain: float  # the run's second half's peaks reach at least this share of its first's
    own: float  # ...and this many times what the law's own damping would leave of them
    harmonics: int  # a run at up to this multiple of the axis's own sine is its exercise
    harmonic_share: float  # ...within this share of the run's frequency
    step: float
    most: float
    dt: float  # s per control period


def params(
    axes: tuple[float, ...],
    corner: float,
    rate: float,
    cycles: int,
    band: tuple[float, float],
    sustain: float,
    own: float,
    harmonics: int,
    harmonic_share: float,
    step: float,
    most: float,
    dt: float,
) -> RingParams:
    """Parameters for a control period of ``dt`` s: the high-pass's ``corner`` (Hz,
    Butterworth), the ``band`` (Hz) a ring's half-cycles lie in."""
    w0 = 2.0 * math.pi * corner * dt
    alpha = math.sin(w0) / math.sqrt(2.0)  # Q = 1/sqrt(2)
    c = math.cos(w0)
    a0 = 1.0 + alpha
    b = np.array([(1.0 + c) / 2.0, -(1.0 + c), (1.0 + c) / 2.0, -2.0 * c, 1.0 - alpha]) / a0
    low, high = band
    return RingParams(
        on=np.array(axes, dtype=np.float64),
        b=b,
        rate=rate,
        cycles=int(cycles),
        half_min=max(1, round(1.0 / (2.0 * high * dt))),
        half_max=round(1.0 / (2.0 * low * dt)),
        sustain=sustain,
        own=own,
        harmonics=int(harmonics),
        harmonic_share=harmonic_share,
        step=step,
        most=most,
        dt=dt,
    )


FRESH = np.zeros(N_RING)
"""An axis's slots with nothing seen: a factor of 1 found under no prescription yet."""
FRESH[G_FACTOR] = 1.0
FRESH[G_K] = np.nan
FRESH[G_B] = np.nan


def new_ring() -> NDArray[np.float64]:
    return np.tile(FRESH, (6, 1))


@njit_inline
def forget(row: NDArray[np.float64]) -> None:
    """Nothing seen: the filter, the count and the factor start anew."""
    row[:] = FRESH


@njit_inline
def pause(row: NDArray[np.float64]) -> None:
    """The axis stopped rendering (between repetitions: each is a segment of its own): the
    watch starts anew when it renders again; the factor and what it was found under stay."""
    for i in range(G_Z, G_Z + 4):
        row[i] = 0.0
    row[G_SIGN] = 0.0
    row[G_HALF] = 0.0
    row[G_PEAK] = 0.0
    _restart(row)


@njit_inline
def factor(row: NDArray[np.float64], k: float, b: float) -> float:
    """The factor on the law's damping for an axis rendering prescribed ``k`` and ``b``;
    a new prescription forgets what the last one found."""
    if row[G_K] != k or row[G_B] != b:
        forget(row)
        row[G_K] = k
        row[G_B] = b
    return float(row[G_FACTOR])


@njit_inline
def _restart(row: NDArray[np.float64]) -> None:
    row[G_RUN] = 0.0
    row[G_SUM] = 0.0
    row[G_EARLY] = 0.0
    row[G_LATE] = 0.0


@njit_inline
def harmonic(hz: float, drive: float, q: RingParams) -> bool:
    """Whether ``hz`` is a multiple (1 to ``harmonics``) of the axis's own sine at ``drive``
    Hz (0: none), within ``harmonic_share`` of ``hz``."""
    if drive <= 0.0:
        return False
    n = round(hz / drive)
    return 1 <= n <= q.harmonics and abs(hz - n * drive) <= q.harmonic_share * hz


@njit_inline
def watch(row: NDArray[np.float64], rate: float, q: RingParams, decay: float, drive: float) -> bool:
    """One control period of the law's ``rate`` on an axis that renders, whose own virtual
    mode dies away at ``decay`` (1/s: ``B / 2J``) and whose target is a sine of ``drive``
    Hz (0: none); True when a ring was seen this period (the factor has grown)."""
    b = q.b
    # Two second-order high-pass sections (transposed direct form II).
    x = rate
    for sec in range(2):
        z = 2 * sec
        y = b[0] * x + row[G_Z + z]
        row[G_Z + z] = b[1] * x - b[3] * y + row[G_Z + z + 1]
        row[G_Z + z + 1] = b[2] * x - b[4] * y
        x = y
    sign = 1.0 if x > 0.0 else -1.0
    seen = False
    if sign != row[G_SIGN]:
        half = row[G_HALF]
        if row[G_SIGN] != 0.0:
            if row[G_PEAK] >= q.rate and q.half_min <= half <= q.half_max:
                if row[G_RUN] < q.cycles // 2:
                    row[G_EARLY] += row[G_PEAK]
                else:
                    row[G_LATE] += row[G_PEAK]
                row[G_RUN] += 1.0
                row[G_SUM] += half
            else:
                _restart(row)
            if row[G_RUN] >= q.cycles:
                early = row[G_EARLY] / (q.cycles // 2)
                late = row[G_LATE] / (q.cycles - q.cycles // 2)
                # What the law's own mode would keep of it over half the run.
                left = math.exp(-decay * 0.5 * row[G_SUM] * q.dt)
                hz = row[G_RUN] / (2.0 * row[G_SUM] * q.dt)
                if late >= max(q.sustain, q.own * left) * early and not harmonic(hz, drive, q):
                    row[G_HZ] = hz
                    row[G_FACTOR] = min(row[G_FACTOR] * q.step, q.most)
                    row[G_RINGS] += 1.0
                    seen = True
                _restart(row)
        row[G_SIGN] = sign
        row[G_HALF] = 0.0
        row[G_PEAK] = 0.0
    row[G_HALF] += 1.0
    row[G_PEAK] = max(row[G_PEAK], abs(x))
    return seen
