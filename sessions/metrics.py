"""Metrics that fit the exercise: what a clinician measures in each kind of session.

:mod:`sessions.summary` gives every session the same numbers per axis; this module gives the
numbers that mean something for the exercise that was prescribed (``ExerciseKind``):

- **strength**: peak and mean torque and the work per direction, and a table per repetition;
- **flexibility** and **passive ROM**: the furthest angle reached per direction
  (plantarflexion and dorsiflexion apart), and tracking of the commanded trajectory;
- **isometric**: per repetition, the torque held and for how long;
- **balance**: sway of the pose (RMS and range of each axis, path length, mean speed);
- **ROM assessment**: per repetition (a *trial*), the active range reached per direction, so
  that repeated trials give the device's own test–retest data (``sessions.progress``).

Directions are stored by axis and sign (``"positive"``: angle or torque > 0), never by
anatomical name: which is plantarflexion or eversion depends on the patient's side, and a page
or report names them through :mod:`sessions.anatomy` when it shows them.

How the numbers are made (all over ACTIVE samples only, as in :mod:`sessions.summary`):

- A repetition is the run of ACTIVE samples that the station tagged with one (set, rep):
  one device segment.
- Peak angle in a direction: the largest excursion from home that way, ``max(q)`` for the
  positive direction and ``max(-q)`` for the negative one, 0 if the foot never went that way.
- Peak torque in a direction: the same on the patient's torque; mean torque in a direction:
  the time-average of ``|τ|`` over the time the torque pointed that way.
- Work in a direction: the concentric work (``sessions.summary``) of the intervals in which the
  foot moved that way; the two directions add up to the axis's ``work_j`` in the summary.
- Isometric hold: the time the torque stayed in the repetition's main direction at or above
  :data:`HOLD_FRACTION` of the repetition's peak (and above :data:`HOLD_FLOOR_NM`); the torque
  held is the time-average of ``|τ|`` over that time.
- Sway: RMS of the angle about level (home), its range, and the path of (roll, pitch) in
  degrees summed over unbroken intervals.
- Tracking error and time in target only where the target is a commanded trajectory
  (:data:`TRAJECTORY_KINDS`, on axes whose waveform moves). In strength, isometric, balance and
  ROM assessment the commanded pose follows the patient through the impedance, so "on target"
  would say nothing.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from device.protocol.messages import DeviceMode
from sessions.prescription import AXIS_INDEX, ROTATION_AXES, ExerciseKind
from sessions.recording import Recording

GAP_FACTOR = 5.0
"""A sample interval longer than this many median intervals is a gap in the telemetry."""
TARGET_TOLERANCE_DEG = 2.0
"""Degrees: a sample is on target when measured and commanded angle differ by less."""
HOLD_FRACTION = 0.5
"""An isometric push is held while its torque is at least this share of the repetition's peak."""
HOLD_FLOOR_NM = 1.0
"""N·m: below this the patient is not pushing (the torque sensor's noise and the foot's weight)."""
TRAJECTORY_KINDS = frozenset({ExerciseKind.FLEXIBILITY, ExerciseKind.PASSIVE_ROM})
"""Exercises whose target is a commanded trajectory: tracking metrics mean something only there."""

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


class DirectionMetrics(BaseModel):
    """One direction of one axis (angle or torque of one sign); null when not measured."""

    model_config = _STRICT

    peak_angle_deg: float | None = Field(
        description="Furthest angle from home this way, degrees (≥ 0; 0 if never this way)."
    )
    peak_torque_nm: float | None = Field(description="Largest torque this way, N·m (≥ 0).")
    mean_torque_nm: float | None = Field(
        description="Time-averaged |torque| while the torque pointed this way, N·m; null if "
        "it never did."
    )
    work_j: float | None = Field(
        description="Concentric work while the foot moved this way, J (≥ 0)."
    )


class AxisMetrics(BaseModel):
    """One ankle axis, by sign: ``positive`` (angle or torque > 0) and ``negative``."""

    model_config = _STRICT

    positive: DirectionMetrics
    negative: DirectionMetrics
    range_deg: float | None = Field(description="Highest minus lowest angle, degrees.")


class HoldMetrics(BaseModel):
    """An isometric push on one axis in one repetition."""

    model_config = _STRICT

    sign: int = Field(description="1 or -1: the direction of the torque held (as the angle's).")
    torque_nm: float = Field(description="Time-averaged |torque| while held, N·m.")
    held_s: float = Field(description="Time the torque was held, s.")
    peak_torque_nm: float = Field(description="Largest |torque| in the repetition, N·m.")


class RepetitionMetrics(BaseModel):
    """One repetition (one device segment; a trial of a ROM assessment)."""

    model_config = _STRICT

    set: int = Field(description="1-based set.")
    rep: int = Field(description="1-based repetition within the set.")
    duration_s: float = Field(description="ACTIVE time of the repetition, s.")
    axes: dict[str, AxisMetrics] = Field(description="Per prescribed axis.")
    holds: dict[str, HoldMetrics] = Field(
        default_factory=dict,
        description="Isometric only: the push held per axis (absent where none was held).",
    )


class SwayAxis(BaseModel):
    model_config = _STRICT

    rms_deg: float = Field(description="RMS of the angle about level (home), degrees.")
    range_deg: float = Field(description="Highest minus lowest angle, degrees.")


class Sway(BaseModel):
    """Balance: how much the platform moved while the patient kept it level."""

    model_config = _STRICT

    axes: dict[str, SwayAxis] = Field(description="Roll and pitch (those prescribed).")
    path_deg: float = Field(
        description="Length of the path of (roll, pitch) in degrees, over unbroken telemetry."
    )
    mean_speed_deg_s: float | None = Field(description="Path length per second of exercise.")


class Tracking(BaseModel):
    """One axis whose target moves: how closely the foot followed it."""

    model_config = _STRICT

    error_rms_deg: float = Field(description="RMS of measured minus commanded angle, degrees.")
    time_in_target_pct: float = Field(
        description=f"Share of exercise time within {TARGET_TOLERANCE_DEG:g} degrees of the "
        "commanded angle, percent."
    )


class ExerciseMetrics(BaseModel):
    """The metrics that fit the session's exercise (see the module's text for each kind)."""

    model_config = _STRICT

    kind: str = Field(description="The prescription's exercise kind, or empty if unknown.")
    axes: dict[str, AxisMetrics] = Field(description="Whole session, per prescribed axis.")
    repetitions: list[RepetitionMetrics] = Field(description="Per repetition, in order.")
    sway: Sway | None = Field(default=None, description="Balance only.")
    tracking: dict[str, Tracking] = Field(
        default_factory=dict,
        description="Only on axes whose target is a commanded trajectory (flexibility and "
        "passive ROM with a sine or ramp); empty otherwise.",
    )


# ---- shared with sessions.summary ---------------------------------------------------------


def sample_weights(t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Seconds each sample stands for, and which intervals k→k+1 are unbroken telemetry."""
    n = len(t)
    if n == 0:
        return np.zeros(0), np.zeros(0, dtype=bool)
    dt = np.diff(t)
    forward = np.isfinite(dt) & (dt > 0)
    typical = float(np.median(dt[forward])) if forward.any() else 0.0
    contiguous = forward & (dt <= GAP_FACTOR * typical)
    # One sample, or a clock that never moved, gives zero weights: no exercise time, and
    # the averages count each sample the same (see weighted_mean).
    return np.append(np.where(contiguous, dt, typical), typical), contiguous


def weighted_mean(values: NDArray[np.float64], w: NDArray[np.float64]) -> float | None:
    total = float(w.sum())
    if len(values) == 0:
        return None
    if total <= 0:
        return float(values.mean())
    return float((values * w).sum() / total)


def finite_zeroed(x: NDArray[Any]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """A column as float64 with unmeasured values zeroed, and where it was measured.

    Zeroing first keeps inf - inf and inf * 0 from making NaN (and warnings) in arithmetic
    on whole columns; the mask keeps the zeros out of every result."""
    x = np.asarray(x, dtype=np.float64)
    ok = np.isfinite(x)
    return np.where(ok, x, 0.0), ok


def concentric_steps(
    q: NDArray[np.float64], tau: NDArray[np.float64], both: NDArray[np.bool_], contiguous: Any
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per interval k→k+1: the concentric work done (≥ 0) and the change of angle.

    An interval counts only when both ends are measured (``both``) and the telemetry is
    unbroken between them: a gap's change of angle says nothing about the torque in it."""
    if len(q) < 2:
        return np.zeros(0), np.zeros(0)
    dq = np.diff(q)
    dw = 0.5 * (tau[:-1] + tau[1:]) * dq
    step = both[:-1] & both[1:] & contiguous
    return np.where(step, np.maximum(dw, 0.0), 0.0), np.where(step, dq, 0.0)


# ---- the metrics ----------------------------------------------------------------------------


def exercise_kind(prescription: dict[str, Any]) -> ExerciseKind | None:
    kind = prescription.get("exercise")
    try:
        return ExerciseKind(kind) if isinstance(kind, str) else None
    except ValueError:
        return None


def tracked_axes(prescription: dict[str, Any], axes: list[str]) -> list[str]:
    """The axes whose target is a commanded trajectory: a moving waveform in a kind that
    commands one (:data:`TRAJECTORY_KINDS`)."""
    if exercise_kind(prescription) not in TRAJECTORY_KINDS:
        return []
    moving: set[str] = set()
    for a in prescription.get("axes") or []:
        if isinstance(a, dict) and a.get("waveform") in ("sine", "ramp"):
            moving.add(str(a.get("axis")))
    return [a for a in axes if a in moving]


class _Columns:
    """The recording's columns the metrics read, in clinic units, computed once."""

    def __init__(self, rec: Recording) -> None:
        s = rec.samples
        self.weights, self.contiguous = sample_weights(s["t"].astype(np.float64))
        self.active = s["mode"] == int(DeviceMode.ACTIVE)
        self.set = s["set"].astype(np.int64)
        self.rep = s["rep"].astype(np.int64)
        self.q: dict[str, NDArray[np.float64]] = {}
        self.q_ok: dict[str, NDArray[np.bool_]] = {}
        self.q_cmd: dict[str, NDArray[np.float64]] = {}
        self.q_cmd_ok: dict[str, NDArray[np.bool_]] = {}
        self.tau: dict[str, NDArray[np.float64]] = {}
        self.tau_ok: dict[str, NDArray[np.bool_]] = {}
        for axis in ROTATION_AXES:
            i = AXIS_INDEX[axis]
            q, self.q_ok[axis] = finite_zeroed(s["pose"][:, i])
            self.q[axis] = np.degrees(q)
            q_cmd, self.q_cmd_ok[axis] = finite_zeroed(s["pose_cmd"][:, i])
            self.q_cmd[axis] = np.degrees(q_cmd)
            self.tau[axis], self.tau_ok[axis] = finite_zeroed(s["wrench"][:, i])

    def samples(self, index: NDArray[np.intp]) -> _Columns:
        """These samples alone (``index`` ascending), as columns of their own. An interval
        between two of them is unbroken only where they were neighbours in the recording
        and unbroken there, so every figure made over a mask of the recording is made the
        same, value for value and in the same order, over the samples the mask held."""
        sub = object.__new__(_Columns)
        sub.weights = self.weights[index]
        sub.contiguous = self.contiguous[index[:-1]] & (np.diff(index) == 1)
        sub.active, sub.set, sub.rep = self.active[index], self.set[index], self.rep[index]
        for name in ("q", "q_ok", "q_cmd", "q_cmd_ok", "tau", "tau_ok"):
            columns: dict[str, NDArray[Any]] = getattr(self, name)
            setattr(sub, name, {axis: x[index] for axis, x in columns.items()})
        return sub


def repetitions(c: _Columns) -> list[NDArray[np.intp]]:
    """The ACTIVE samples of each (set, rep) the station tagged, in (set, rep) order, each
    repetition's in time order. Sorted once: a mask of the whole recording per repetition
    made a long session's metrics cost repetitions × samples (a 6.4 h session at 100 Hz
    with 3,820 repetitions: a minute of CPU at each upload)."""
    tagged = np.flatnonzero(c.active & (c.rep > 0))
    if not len(tagged):
        return []
    # lexsort is stable: within a repetition, the samples stay in the order they came.
    ranked = tagged[np.lexsort((c.rep[tagged], c.set[tagged]))]
    s, r = c.set[ranked], c.rep[ranked]
    starts = np.flatnonzero((np.diff(s) != 0) | (np.diff(r) != 0)) + 1
    return np.split(ranked, starts)


def _peak(x: NDArray[np.float64]) -> float | None:
    return max(float(x.max()), 0.0) if len(x) else None


def _axis_metrics(c: _Columns, axis: str, mask: NDArray[np.bool_]) -> AxisMetrics:
    ok_q = mask & c.q_ok[axis]
    ok_tau = mask & c.tau_ok[axis]
    q_deg, tau = c.q[axis], c.tau[axis]
    work, dq = concentric_steps(np.radians(q_deg), tau, ok_q & ok_tau, c.contiguous)
    measured = bool(mask.any())

    def direction(sign: int) -> DirectionMetrics:
        torque = sign * tau[ok_tau]
        this_way = torque > 0
        return DirectionMetrics(
            peak_angle_deg=_peak(sign * q_deg[ok_q]),
            peak_torque_nm=_peak(torque),
            mean_torque_nm=weighted_mean(torque[this_way], c.weights[ok_tau][this_way]),
            work_j=float(work[sign * dq > 0].sum()) if measured else None,
        )

    q = q_deg[ok_q]
    return AxisMetrics(
        positive=direction(1),
        negative=direction(-1),
        range_deg=float(q.max() - q.min()) if len(q) else None,
    )


def _hold(c: _Columns, axis: str, mask: NDArray[np.bool_]) -> HoldMetrics | None:
    ok = mask & c.tau_ok[axis]
    tau, w = c.tau[axis][ok], c.weights[ok]
    if not len(tau):
        return None
    k = int(np.argmax(np.abs(tau)))
    peak = abs(float(tau[k]))
    if peak < HOLD_FLOOR_NM:
        return None
    sign = 1 if tau[k] > 0 else -1
    held = sign * tau >= max(HOLD_FRACTION * peak, HOLD_FLOOR_NM)
    return HoldMetrics(
        sign=sign,
        torque_nm=float(weighted_mean(np.abs(tau[held]), w[held]) or 0.0),
        held_s=float(w[held].sum()),
        peak_torque_nm=peak,
    )


def _sway(c: _Columns, axes: list[str]) -> Sway:
    mask = c.active
    out: dict[str, SwayAxis] = {}
    path = np.zeros(max(len(mask) - 1, 0))
    step_ok = mask[:-1] & mask[1:] & c.contiguous
    for axis in axes:
        ok = mask & c.q_ok[axis]
        q = c.q[axis][ok]
        if not len(q):
            continue
        mean_sq = weighted_mean(q * q, c.weights[ok]) or 0.0
        out[axis] = SwayAxis(rms_deg=math.sqrt(mean_sq), range_deg=float(q.max() - q.min()))
        step_ok = step_ok & ok[:-1] & ok[1:]
        path = path + np.diff(c.q[axis]) ** 2 if len(path) else path
    length = float(np.sqrt(path[step_ok]).sum()) if len(path) else 0.0
    duration = float(c.weights[mask].sum())
    return Sway(
        axes=out,
        path_deg=length,
        mean_speed_deg_s=length / duration if duration > 0 else None,
    )


def _tracking(c: _Columns, axis: str) -> Tracking | None:
    ok = c.active & c.q_ok[axis] & c.q_cmd_ok[axis]
    err = (c.q[axis] - c.q_cmd[axis])[ok]
    w = c.weights[ok]
    mean_sq = weighted_mean(err * err, w)
    in_target = weighted_mean((np.abs(err) < TARGET_TOLERANCE_DEG).astype(np.float64), w)
    if mean_sq is None or in_target is None:
        return None
    return Tracking(error_rms_deg=math.sqrt(mean_sq), time_in_target_pct=100.0 * in_target)


def exercise_metrics(rec: Recording, axes: list[str]) -> ExerciseMetrics:
    """The metrics of a recording for the exercise its header's prescription names, on
    ``axes`` (the prescribed ones, ``sessions.summary.prescribed_axes``)."""
    c = _Columns(rec)
    kind = exercise_kind(rec.header.prescription)
    reps: list[RepetitionMetrics] = []
    for index in repetitions(c):
        one = c.samples(index)
        mask = np.ones(len(index), dtype=bool)
        holds: dict[str, HoldMetrics] = {}
        if kind == ExerciseKind.ISOMETRIC:
            for axis in axes:
                hold = _hold(one, axis, mask)
                if hold is not None:
                    holds[axis] = hold
        reps.append(
            RepetitionMetrics(
                set=int(one.set[0]),
                rep=int(one.rep[0]),
                duration_s=float(one.weights.sum()),
                axes={axis: _axis_metrics(one, axis, mask) for axis in axes},
                holds=holds,
            )
        )
    tracking: dict[str, Tracking] = {}
    for axis in tracked_axes(rec.header.prescription, axes):
        t = _tracking(c, axis)
        if t is not None:
            tracking[axis] = t
    return ExerciseMetrics(
        kind=kind.value if kind is not None else "",
        axes={axis: _axis_metrics(c, axis, c.active) for axis in axes},
        repetitions=reps,
        sway=_sway(c, [a for a in axes if a in ("roll", "pitch")])
        if kind == ExerciseKind.BALANCE
        else None,
        tracking=tracking,
    )
