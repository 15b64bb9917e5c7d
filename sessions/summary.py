"""What a clinician reads about one session: time exercised, repetitions, range, torque, work.

Everything is computed from the samples recorded while the device was ACTIVE (an exercise
segment running): homing, rests, holds and faults do not count as exercise. Units are the
clinic's, not the device's: degrees, newton metres, joules, seconds, percent.

How the numbers are made:

- Each sample stands for the time until the next one on the device clock ``t``. An interval
  longer than ``sessions.metrics.GAP_FACTOR`` times the median one is a gap in the
  telemetry (a lost link, a restarted device), not exercise: it counts as one median
  interval. The gaps are counted (``telemetry_gaps``) with the time they leave out
  (``telemetry_missing_s``), so that a session with samples missing never reads as whole.
- Range of motion is the lowest and highest measured angle; torques are the patient's, on
  the foot plate (``wrench[3:6]``: generalised forces conjugate to roll, pitch and yaw, so
  torque times angular velocity is power).
- Work: the power the patient puts into the platform is ``τ·ω``, positive when the foot
  pushes the plate the way it moves (the platform yields to the foot in the direction of its
  torque). Over each interval between two ACTIVE samples the work is the mean torque times
  the change in angle, ``½(τₖ + τₖ₊₁)(qₖ₊₁ - qₖ)`` (∫τ·ω dt with ω by finite differences on
  ``t``); ``work_j`` adds up the intervals where it is positive: the concentric work the
  patient did, not reduced by the platform pushing the foot back.
- Tracking error is measured minus commanded angle; time in target is the share of ACTIVE
  time within :data:`TARGET_TOLERANCE_DEG` of the command. Both only on axes whose target is
  a commanded trajectory (``sessions.metrics.tracked_axes``): where the command follows the
  patient through the impedance, they are null.
- ``metrics`` holds what fits the exercise: per direction, per repetition, holds, sway
  (:mod:`sessions.metrics`).
- The game on the patient's page sends its running totals as ``game_score`` events, one per
  gate, each tagged with the game it belongs to (a page reloaded mid-session starts a new
  game): the last event of each game is its result, and the games are added up.

Values that cannot be computed (no ACTIVE samples, sensors reading NaN) are left out or
null, never NaN: the summary is stored and sent as JSON.
"""

from __future__ import annotations

import math
from typing import Any, TypeGuard

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from pydantic_core import to_json

from device.protocol.messages import DeviceMode
from sessions.metrics import (
    TARGET_TOLERANCE_DEG,
    ExerciseMetrics,
    concentric_steps,
    exercise_metrics,
    finite_zeroed,
    sample_weights,
    tracked_axes,
    weighted_mean,
)
from sessions.prescription import AXIS_INDEX, ROTATION_AXES
from sessions.recording import EndReason, Recording

SAFETY_EVENT_KINDS = ("fault", "limit", "estop", "watchdog", "supply_low", "interrupted")
"""Event kinds listed one by one in :attr:`Summary.faults`."""
GAME_EVENT = "game_score"
"""Event kind of the patient's game: detail ``game``, ``score``, ``gates``, ``missed``."""
_TEXT_MAX = 160

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


class AxisSummary(BaseModel):
    """One ankle axis during exercise; null when the session has no ACTIVE samples."""

    model_config = _STRICT

    rom_min_deg: float | None = Field(description="Lowest measured angle, degrees from home.")
    rom_max_deg: float | None = Field(description="Highest measured angle, degrees from home.")
    rom_deg: float | None = Field(description="Range of motion: highest minus lowest, degrees.")
    peak_torque_nm: float | None = Field(description="Largest |torque| of the patient, N·m.")
    mean_torque_nm: float | None = Field(description="Time-averaged |torque|, N·m.")
    work_j: float | None = Field(
        description="Positive work done by the patient on the platform, J (concentric work)."
    )
    tracking_error_rms_deg: float | None = Field(
        description="RMS of measured minus commanded angle, degrees; null unless the target "
        "is a commanded trajectory (sessions.metrics.TRAJECTORY_KINDS)."
    )
    time_in_target_pct: float | None = Field(
        description=f"Share of exercise time within {TARGET_TOLERANCE_DEG:g} degrees of the "
        "commanded angle, percent."
    )


class FaultSummary(BaseModel):
    """A safety event, in a line."""

    model_config = _STRICT

    at_s: float = Field(description="Seconds after the session started (station clock).")
    kind: str = Field(
        description="fault, limit, estop, watchdog, supply_low or interrupted (held too long)."
    )
    by: str = Field(description="Who reported it: device, station, patient or therapist:<id>.")
    text: str = Field(description="What happened, shortened.")


class GameSummary(BaseModel):
    """The game steered by the foot (plane through gates) during the session."""

    model_config = _STRICT

    games: int = Field(description="Games played in the session.")
    score: int = Field(description="Gates flown through, all games.")
    gates: int = Field(description="Gates that came up, all games: flown through or missed.")
    missed: int = Field(description="Gates missed, all games.")


class Summary(BaseModel):
    """The session at a glance, for the therapist's dashboard and the downloads."""

    model_config = _STRICT

    duration_s: float = Field(description="Exercise time (device ACTIVE), s.")
    elapsed_s: float = Field(description="Station time from the first to the last sample, s.")
    samples: int = Field(description="Telemetry samples recorded, in every mode.")
    sets_completed: int = Field(description="Sets finished.")
    repetitions_completed: int = Field(description="Repetitions finished, all sets.")
    repetitions_prescribed: int | None = Field(
        description="Sets times repetitions per set; null if the prescription does not say."
    )
    end_reason: EndReason | None = Field(
        description="completed, stopped, fault or interrupted; null if the recording has no "
        "end record (still running, or cut off)."
    )
    end_text: str = Field(
        default="", description="Why it ended, in words (an interruption, a fault); or empty."
    )
    axes: dict[str, AxisSummary] = Field(
        description="The prescribed ankle axes (roll, pitch, yaw) during exercise."
    )
    events: dict[str, int] = Field(description="Number of events of each kind.")
    faults: list[FaultSummary] = Field(description="Faults, limits, emergency stops, watchdogs.")
    telemetry_gaps: int | None = Field(
        default=None,
        description="Gaps in the telemetry recorded: intervals of the device clock longer "
        "than GAP_FACTOR median intervals (samples lost: the device's link or the station "
        "stalled), or where it went back (the device restarted). Null in a summary stored "
        "before they were counted.",
    )
    telemetry_missing_s: float | None = Field(
        default=None,
        description="Time the gaps leave without samples, s (beyond one interval each): "
        "not counted as exercise. Null in a summary stored before it was counted.",
    )
    game: GameSummary | None = Field(
        default=None, description="The patient's game; null if none was played."
    )
    metrics: ExerciseMetrics | None = Field(
        default=None,
        description="The metrics that fit the exercise (sessions.metrics); null in a summary "
        "stored before they existed (the server recomputes it from the recording).",
    )


def summarize(rec: Recording) -> Summary:
    """The summary of a recording; a recording in progress or cut off summarizes what it has."""
    s = rec.samples
    t = s["t"].astype(np.float64)
    weights, contiguous = sample_weights(t)
    active = s["mode"] == int(DeviceMode.ACTIVE)

    counts: dict[str, int] = {}
    for e in rec.events:
        counts[e.kind] = counts.get(e.kind, 0) + 1
    if rec.end is not None:
        sets_done, reps_done = rec.end.sets_completed, rec.end.repetitions_completed
    else:
        sets_done, reps_done = counts.get("set_done", 0), counts.get("rep_done", 0)

    gaps, missing = telemetry_gaps(t, s["wall"].astype(np.float64), contiguous)
    wall = s["wall"][np.isfinite(s["wall"])]
    axes = prescribed_axes(rec.header.prescription)
    tracked = tracked_axes(rec.header.prescription, axes)
    return Summary(
        duration_s=float(weights[active].sum()),
        elapsed_s=float(wall.max() - wall.min()) if len(wall) else 0.0,
        samples=len(s),
        sets_completed=sets_done,
        repetitions_completed=reps_done,
        repetitions_prescribed=_prescribed_repetitions(rec.header.prescription),
        end_reason=rec.end.reason if rec.end is not None else None,
        end_text=rec.end.text if rec.end is not None else "",
        axes={
            axis: _axis_summary(rec, AXIS_INDEX[axis], active, weights, contiguous, axis in tracked)
            for axis in axes
        },
        events=dict(sorted(counts.items())),
        faults=[
            FaultSummary(
                at_s=_finite_or_zero(e.wall - rec.header.started_at),
                kind=e.kind,
                by=e.by,
                text=_short_text(e.detail),
            )
            for e in rec.events
            if e.kind in SAFETY_EVENT_KINDS
        ],
        telemetry_gaps=gaps,
        telemetry_missing_s=missing,
        game=_game_summary(rec),
        metrics=exercise_metrics(rec, axes),
    )


def telemetry_gaps(
    t: NDArray[np.float64], wall: NDArray[np.float64], contiguous: NDArray[np.bool_]
) -> tuple[int, float]:
    """How many intervals break the telemetry (measured ones that ``sample_weights`` does
    not count as unbroken) and the seconds they leave without samples beyond one median
    interval each: on the device clock, or on the station's where the device's went back
    (a restart: how long it was away is the station's to say)."""
    if len(t) < 2:
        return 0, 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        dt, dwall = np.diff(t), np.diff(wall)
        forward = np.isfinite(dt) & (dt > 0)
        typical = float(np.median(dt[forward])) if forward.any() else 0.0
        broken = np.isfinite(dt) & ~contiguous
        step = np.where(dt > 0, dt, np.where(np.isfinite(dwall), dwall, 0.0))[broken]
        missing = float(np.clip(step - typical, 0.0, None).sum())
    return int(broken.sum()), missing


def prescribed_axes(prescription: dict[str, Any]) -> list[str]:
    """The axes a prescription names, in its order; all three rotations if it names none."""
    axes = prescription.get("axes")
    names: list[str] = []
    if isinstance(axes, list):
        for a in axes:
            name = a.get("axis") if isinstance(a, dict) else None
            if isinstance(name, str) and name in AXIS_INDEX and name not in names:
                names.append(name)
    return names or list(ROTATION_AXES)


def _prescribed_repetitions(prescription: dict[str, Any]) -> int | None:
    sets, reps = prescription.get("sets"), prescription.get("repetitions")
    # bool is an int to Python, but never a count
    if type(sets) is int and type(reps) is int:
        return sets * reps
    return None


def _axis_summary(
    rec: Recording,
    i: int,
    active: NDArray[np.bool_],
    weights: NDArray[np.float64],
    contiguous: NDArray[np.bool_],
    tracked: bool,
) -> AxisSummary:
    s = rec.samples
    q, q_ok = finite_zeroed(s["pose"][:, i])
    q_cmd, q_cmd_ok = finite_zeroed(s["pose_cmd"][:, i])
    tau, tau_ok = finite_zeroed(s["wrench"][:, i])
    ok_q = active & q_ok
    ok_tau = active & tau_ok
    ok_err = ok_q & q_cmd_ok if tracked else np.zeros_like(active)
    err = np.degrees(q - q_cmd)

    q_deg = np.degrees(q[ok_q])
    lo = float(q_deg.min()) if len(q_deg) else None
    hi = float(q_deg.max()) if len(q_deg) else None
    abs_tau = np.abs(tau[ok_tau])
    work, _ = concentric_steps(q, tau, ok_q & ok_tau, contiguous)

    w_err = weights[ok_err]
    e = err[ok_err]
    mean_sq = weighted_mean(e * e, w_err)
    in_target = weighted_mean((np.abs(e) < TARGET_TOLERANCE_DEG).astype(np.float64), w_err)
    return AxisSummary(
        rom_min_deg=lo,
        rom_max_deg=hi,
        rom_deg=hi - lo if hi is not None and lo is not None else None,
        peak_torque_nm=float(abs_tau.max()) if len(abs_tau) else None,
        mean_torque_nm=weighted_mean(abs_tau, weights[ok_tau]),
        work_j=float(work.sum()) if active.any() else None,
        tracking_error_rms_deg=math.sqrt(mean_sq) if mean_sq is not None else None,
        time_in_target_pct=100.0 * in_target if in_target is not None else None,
    )


def _game_summary(rec: Recording) -> GameSummary | None:
    final: dict[str, tuple[int, int, int]] = {}
    for e in rec.events:
        if e.kind != GAME_EVENT:
            continue
        score, gates, missed = (e.detail.get(k) for k in ("score", "gates", "missed"))
        # A recording is data from elsewhere: an event without three counts is not a result.
        if _is_count(score) and _is_count(gates) and _is_count(missed):
            final[repr(e.detail.get("game"))] = (score, gates, missed)
    if not final:
        return None
    return GameSummary(
        games=len(final),
        score=sum(t[0] for t in final.values()),
        gates=sum(t[1] for t in final.values()),
        missed=sum(t[2] for t in final.values()),
    )


def _is_count(value: object) -> TypeGuard[int]:
    return type(value) is int and value >= 0  # bool is an int to Python, but never a count


def _finite_or_zero(x: float) -> float:
    return x if math.isfinite(x) else 0.0


def _short_text(detail: dict[str, Any]) -> str:
    text = detail.get("text")
    if not isinstance(text, str) or not text:
        # pydantic's encoder writes NaN as null, as in the recording's own JSON
        text = to_json(detail, fallback=str).decode()
    return text if len(text) <= _TEXT_MAX else text[: _TEXT_MAX - 1] + "…"
