"""Response metrics of recorded runs: step, frequency response, stiffness.

Pure functions of arrays (time in s, signals in SI units), no simulation here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

SETTLE_BAND_M = 0.3e-3
"""The settling band about a step's target (m): the paper's 0.3 mm resolution, absolute
rather than a percentage, because for a 10 mm step 2 % would be finer than the resolution
itself."""
SETTLE_HOLD_S = 0.5
"""How long a step's response must stay within the band to count as settled (s). Longer
than the slowest step's rise (45 mm, 167 ms) and than a period of the limit cycle an
uncompensated leg swings through the band in (0.3-0.4 s between its exits: it never
settles), short against the quiet hold's own slow wander (a healthy leg resting on its air
drifts 0.3 mm over 10-18 s and is then corrected), which is the hold, not the step."""


@dataclass(frozen=True)
class StepMetrics:
    rise_ms: float
    """10-90 % rise time (ms); NaN if the response never reached 90 %."""
    overshoot_pct: float
    """Peak beyond the target, in percent of the step, up to the end of the settling window
    (over the whole record when it never settled)."""
    settling_ms: float
    """When the response entered the band for good: the first time after which it stayed
    within ``band`` of the target for ``hold`` seconds (ms). NaN when the record holds no
    such window."""
    steady_error_mm: float
    """|mean response - target| over the last ``tail`` seconds of the record (mm): where the
    leg rests when the record ends, settled or not. Unlike settling it may depend on the
    record's length: a leg that the quiet hold lets wander is wherever it wandered."""

    @property
    def measured(self) -> bool:
        """Every number is finite: the step rose and settled within the record."""
        return all(
            math.isfinite(v)
            for v in (self.rise_ms, self.overshoot_pct, self.settling_ms, self.steady_error_mm)
        )


def step_metrics(
    t: NDArray[np.float64],
    y: NDArray[np.float64],
    y0: float,
    target: float,
    band: float = SETTLE_BAND_M,
    hold: float = SETTLE_HOLD_S,
    tail: float = 0.2,
) -> StepMetrics:
    """Metrics of a step from ``y0`` to ``target`` that starts at ``t[0]``.

    Settling and overshoot do not depend on how long the record goes on after the step
    settled: settling is the first entry into the band that then lasts ``hold`` seconds,
    and the overshoot is taken up to the end of that window (what the held leg does later,
    ``device.quiet``, is not the step's response). The steady-state error is where the leg
    rests at the end of the record, so a target on it is never met by construction.
    """
    t = np.asarray(t, dtype=np.float64) - float(t[0])
    y = np.asarray(y, dtype=np.float64)
    step = target - y0
    if step == 0.0:
        raise ValueError("a step needs a target different from its start")
    frac = (y - y0) / step
    i10 = np.argmax(frac >= 0.1)
    i90 = np.argmax(frac >= 0.9)
    rise = float(t[i90] - t[i10]) * 1e3 if frac[i90] >= 0.9 and frac[i10] >= 0.1 else math.nan
    inside = np.abs(y - target) <= band
    # For each sample, the first sample at or after it outside the band (len(t): none).
    outside = np.flatnonzero(~inside)
    next_out = np.append(outside, t.size)[np.searchsorted(outside, np.arange(t.size))]
    # The window is the samples within hold seconds of its first (hold / dt of them, half
    # a sample's slack against rounding); the record must hold all of it.
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    end = t + hold - 0.5 * dt
    leaves = np.append(t, math.inf)[next_out]
    stays = inside & (leaves >= end) & (t[-1] + dt >= end)
    settled = np.flatnonzero(stays)
    if settled.size:
        i = int(settled[0])
        upto = t < end[i]
        settling = float(t[i]) * 1e3
    else:
        settling = math.nan
        upto = np.ones(t.size, dtype=bool)
    steady = abs(float(np.mean(y[t >= t[-1] - tail])) - target) * 1e3
    overshoot = max(0.0, float(np.max(frac[upto])) - 1.0) * 100.0
    return StepMetrics(rise, overshoot, settling, steady)


def sine_response(
    t: NDArray[np.float64],
    reference: NDArray[np.float64],
    response: NDArray[np.float64],
    frequency: float,
) -> tuple[float, float]:
    """(gain dB, phase deg) of ``response`` relative to ``reference`` at ``frequency``.

    Both are projected on sin and cos over whole periods (a one-bin DFT), which rejects
    offsets, noise and harmonics.
    """
    t = np.asarray(t, dtype=np.float64)
    periods = math.floor((t[-1] - t[0]) * frequency)
    if periods < 1:
        raise ValueError("need at least one whole period of data")
    keep = t <= t[0] + periods / frequency
    tt = t[keep]
    basis = np.exp(-2j * math.pi * frequency * tt)

    def phasor(x: NDArray[np.float64]) -> complex:
        xx = np.asarray(x, dtype=np.float64)[keep]
        return complex(np.sum((xx - xx.mean()) * basis))

    ref, out = phasor(reference), phasor(response)
    if abs(ref) == 0.0:
        raise ValueError("reference has no component at that frequency")
    h = out / ref
    return 20.0 * math.log10(max(abs(h), 1e-12)), math.degrees(math.atan2(h.imag, h.real))


def stiffness_slope(angle: NDArray[np.float64], torque: NDArray[np.float64]) -> float:
    """Least-squares slope of torque against angle (N m/rad)."""
    a = np.asarray(angle, dtype=np.float64)
    tq = np.asarray(torque, dtype=np.float64)
    if a.size < 2 or float(np.ptp(a)) == 0.0:
        raise ValueError("the angle did not change: no stiffness to measure")
    slope, _ = np.polyfit(a, tq, 1)
    return float(slope)


Signal = NDArray[np.float64] | Sequence[NDArray[np.float64]]


def impedance_fit(
    t: Signal,
    angle: Signal,
    torque: Signal,
    frequency: float | Sequence[float],
) -> tuple[float, float, float]:
    """(K, B, c) of the least-squares fit ``torque = K angle + B rate + c``.
    See :func:`impedance_fit_inertia`."""
    k, b, _, c = _fit(t, angle, torque, frequency, inertia=False)
    return k, b, c


def impedance_fit_inertia(
    t: Signal,
    angle: Signal,
    torque: Signal,
    frequency: Sequence[float],
) -> tuple[float, float, float, float]:
    """(K, B, J, c) of ``torque = K angle + B rate + J acceleration + c`` over windows at two
    or more frequencies: at one frequency an inertia is indistinguishable from a lower
    stiffness (``K - J w^2``), so a fit without J reports the device's virtual inertia as
    a stiffness error that grows with frequency."""
    if isinstance(frequency, float | int) or len(set(frequency)) < 2:
        raise ValueError("an inertia needs windows at two or more frequencies")
    return _fit(t, angle, torque, frequency, inertia=True)


def _fit(
    t: Signal,
    angle: Signal,
    torque: Signal,
    frequency: float | Sequence[float],
    inertia: bool,
) -> tuple[float, float, float, float]:
    """The least-squares fit of :func:`impedance_fit` (J is NaN without ``inertia``).

    One window, or several (sequences of arrays, one frequency each; a separate offset per
    window, their mean returned). The angle and its rate are the fundamental of the measured
    angle at the window's frequency (a least-squares sine fit), so the sensor's quantisation
    is not differentiated into the rate.
    """
    if isinstance(frequency, float | int):
        ts, angles, torques, freqs = [t], [angle], [torque], [float(frequency)]
    else:
        ts, angles, torques, freqs = list(t), list(angle), list(torque), list(frequency)
    n = len(freqs)
    rows, rhs = [], []
    for w, (tt, a, tq, f) in enumerate(zip(ts, angles, torques, freqs, strict=True)):
        tt = np.asarray(tt, dtype=np.float64)
        a = np.asarray(a, dtype=np.float64)
        wt = 2.0 * math.pi * f * tt
        basis = np.column_stack([np.sin(wt), np.cos(wt), np.ones_like(tt)])
        (s, c, _), *_ = np.linalg.lstsq(basis, a, rcond=None)
        if math.hypot(s, c) == 0.0:
            raise ValueError("the angle did not move at that frequency: nothing to fit")
        theta = s * np.sin(wt) + c * np.cos(wt)
        rate = 2.0 * math.pi * f * (s * np.cos(wt) - c * np.sin(wt))
        offsets = np.zeros((tt.size, n))
        offsets[:, w] = 1.0
        columns = [theta, rate]
        if inertia:
            columns.append(-((2.0 * math.pi * f) ** 2) * theta)  # the angle's acceleration
        rows.append(np.column_stack([*columns, offsets]))
        rhs.append(np.asarray(tq, dtype=np.float64))
    sol, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    j = float(sol[2]) if inertia else math.nan
    first = 3 if inertia else 2
    return float(sol[0]), float(sol[1]), j, float(np.mean(sol[first:]))
