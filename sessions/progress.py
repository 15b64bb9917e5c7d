"""A patient's progress over sessions, judged the way a clinician can trust.

:func:`progress` is pure: it is given the patient's prescriptions and sessions (with their
summaries, ``sessions.summary.Summary``) and answers a :class:`Progress`. The server's
``GET /api/v1/patients/{id}/progress`` and the report for the medical record both call it.

**Per exercise type.** Each exercise kind has its own measures, one series per direction
(axis and sign, named for the patient's side only when shown, ``sessions.anatomy``):

================  ==========================================================================
kind              measure per session (``Measure.quantity``)
================  ==========================================================================
rom_assessment    ``peak_angle``: active range per direction, the mean of the session's trials
flexibility,      ``peak_angle``: furthest angle per direction over the session
passive_rom
strength          ``peak_torque``: largest torque per direction, N·m
isometric         ``torque_held``: mean over the repetitions of the torque held, per direction
balance           ``sway_rms``: RMS of the angle about level per axis (sign 0; lower is better)
================  ==========================================================================

**Baseline.** The patient's first ROM assessment (the first ever, even before ``since``): per
direction, the mean of its trials. Every point of a ROM assessment measure carries its change
from that baseline.

**Minimal detectable change.** The device's own test–retest: the trials (repetitions) of one
ROM assessment are repeated measurements of one unchanged ankle, so their scatter is the
measurement error. Per direction, the standard error of measurement is the within-session
standard deviation pooled over every assessment with two or more trials,

    SEM = sqrt( Σ_sessions Σ_trials (x − x̄_session)² / Σ_sessions (n_session − 1) ),

and ``MDC95 = 1.96 · √2 · SEM`` (the smallest change between two measurements that error
alone would not give in 95 % of cases). With fewer than :data:`MDC_MIN_TRIALS` trials from at
least :data:`MDC_MIN_ASSESSMENTS` assessments, MDC95 is null and the text says "not enough
repeated trials yet": nothing is flagged. When every trial measured the same (a direction the
patient never moved: every trial 0°), the scatter is zero, which measures no reliability at
all: MDC95 is null too, "not measurable", and nothing is flagged against it (``Mdc.reason``
says which). A change is flagged real (``real_change``) only when its size exceeds MDC95;
MDC95 is that of a single trial, so flagging a session's mean of several trials against it is
conservative.

**Adherence.** Per prescription, per prescribed week: week 1 starts when it was prescribed,
and weeks run until it was withdrawn or completed (``ended_at``), or until ``now``. A week
asks for ``sessions_per_week`` (pro rata, rounded, in a week the prescription ended part-way
through). Sessions of the prescription that completed count up to what was asked
(``completed``); any more are ``extra``, never above 100 %. Sessions that ended otherwise
(stopped, fault, interrupted) are ``ended_early``. In a week that is over, what is left of the
asked sessions is ``missed``; the week in progress misses nothing yet and is left out of
``percent``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from sessions.metrics import ExerciseMetrics
from sessions.prescription import AXIS_INDEX, ExerciseKind
from sessions.summary import Summary

MDC_MIN_TRIALS = 6
"""Fewest repeated trials (in assessments of two or more) an MDC95 rests on."""
MDC_MIN_ASSESSMENTS = 2
"""Fewest ROM assessments with two or more trials an MDC95 rests on."""
Z95_SQRT2 = 1.96 * math.sqrt(2.0)
WEEK = timedelta(days=7)

Quantity = Literal["peak_angle", "peak_torque", "torque_held", "sway_rms"]
UNITS: dict[Quantity, str] = {
    "peak_angle": "deg",
    "peak_torque": "N.m",
    "torque_held": "N.m",
    "sway_rms": "deg",
}
"""UCUM units of each quantity."""
ANGLE_KINDS = (ExerciseKind.ROM_ASSESSMENT, ExerciseKind.FLEXIBILITY, ExerciseKind.PASSIVE_ROM)

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


# ---- what progress() is given ---------------------------------------------------------------


class PrescriptionFacts(BaseModel):
    """A prescription as progress needs it."""

    id: int
    exercise: ExerciseKind
    title: str = ""
    sessions_per_week: int = Field(ge=1)
    created_at: datetime = Field(description="When it was prescribed (aware).")
    ended_at: datetime | None = Field(
        default=None, description="When it was withdrawn or completed; null while active."
    )


class SessionFacts(BaseModel):
    """A recorded session as progress needs it."""

    id: int
    prescription_id: int | None
    started_at: datetime = Field(description="Aware.")
    end_reason: str | None = Field(description="completed, stopped, fault or interrupted.")
    exercise: ExerciseKind | None = Field(
        default=None, description="The kind it ran; from the summary's metrics if left out."
    )
    summary: Summary | None


# ---- what it answers ------------------------------------------------------------------------


class Point(BaseModel):
    model_config = _STRICT

    session_id: int
    at: datetime = Field(description="When the session started.")
    value: float = Field(description="In the measure's unit.")
    trials: int = Field(description="Repetitions the value rests on (1 for a whole session).")
    change: float | None = Field(
        description="Value minus the baseline (ROM assessment only); null without a baseline."
    )
    real_change: bool | None = Field(
        description="True when |change| exceeds MDC95, false when it does not; null when "
        "there is no baseline or not enough repeated trials for an MDC95."
    )


class Measure(BaseModel):
    """One series: a quantity in one direction (axis and sign) over the sessions in range."""

    model_config = _STRICT

    axis: str = Field(description="roll, pitch or yaw.")
    sign: int = Field(description="1 (angle or torque > 0), -1, or 0 (no direction: sway).")
    quantity: Quantity
    unit: str = Field(description="UCUM: deg or N.m.")
    points: list[Point] = Field(description="Oldest first.")
    baseline: float | None = Field(
        default=None, description="ROM assessment only: the first assessment's value."
    )


class ExerciseProgress(BaseModel):
    model_config = _STRICT

    exercise: ExerciseKind
    sessions: int = Field(description="Sessions of this kind in range.")
    measures: list[Measure]


MdcMissing = Literal["too_few_trials", "no_scatter"]


class Mdc(BaseModel):
    """The minimal detectable change of one direction's active range (see the module)."""

    model_config = _STRICT

    axis: str
    sign: int
    mdc95_deg: float | None = Field(description="Null when it cannot be measured (``reason``).")
    sem_deg: float | None
    reason: MdcMissing | None = Field(
        default=None,
        description="Why mdc95_deg is null: too_few_trials (not enough repeated trials yet) "
        "or no_scatter (every trial measured the same, e.g. a direction never moved, so the "
        "trials show no measurement error to judge a change against); null when measured.",
    )
    trials: int = Field(description="Trials in assessments of two or more trials.")
    assessments: int = Field(description="Assessments with two or more trials.")
    text: str = Field(description="In words, for a page or report.")


class Baseline(BaseModel):
    model_config = _STRICT

    session_id: int
    at: datetime
    values: dict[str, float] = Field(
        description='Per direction, keyed "axis:sign" (e.g. "pitch:-1"), degrees.'
    )


class AdherenceCounts(BaseModel):
    """Sessions of one prescription: in a week, or summed over the weeks that are over."""

    model_config = _STRICT

    prescribed: int = Field(description="Sessions asked for.")
    completed: int = Field(description="Completed sessions counted, at most prescribed.")
    extra: int = Field(description="Completed sessions beyond what was prescribed.")
    ended_early: int = Field(description="Sessions that were stopped, faulted or interrupted.")
    missed: int = Field(description="Prescribed sessions not done, in a week that is over.")


class AdherenceWeek(AdherenceCounts):
    week: int = Field(description="1-based week of the prescription.")
    start: datetime
    end: datetime
    in_progress: bool = Field(description="The week has not ended yet (it misses nothing yet).")


class PrescriptionAdherence(AdherenceCounts):
    """The counts are sums over the weeks that are over; the week in progress is in
    ``weeks`` only."""

    prescription_id: int
    exercise: ExerciseKind
    title: str
    sessions_per_week: int
    weeks: list[AdherenceWeek] = Field(description="Prescribed weeks in range, oldest first.")
    percent: float | None = Field(
        description="completed / prescribed over the weeks that are over, ≤ 100; null if none."
    )


class Progress(BaseModel):
    """What :func:`progress` answers; every list is oldest first, or in a fixed order."""

    model_config = _STRICT

    since: datetime | None
    until: datetime | None
    exercises: list[ExerciseProgress] = Field(description="Kinds with sessions in range.")
    baseline: Baseline | None = Field(description="The first ROM assessment; null if none.")
    mdc: list[Mdc] = Field(description="Per direction assessed so far.")
    adherence: list[PrescriptionAdherence] = Field(
        description="Per prescription with a prescribed week in range."
    )


# ---- the computation ------------------------------------------------------------------------


def _kind(s: SessionFacts, rx: dict[int, PrescriptionFacts]) -> ExerciseKind | None:
    if s.exercise is not None:
        return s.exercise
    m = s.summary.metrics if s.summary is not None else None
    if m is not None and m.kind:
        return ExerciseKind(m.kind)
    p = rx.get(s.prescription_id) if s.prescription_id is not None else None
    return p.exercise if p is not None else None


def _key(axis: str, sign: int) -> str:
    return f"{axis}:{sign}"


def _values(kind: ExerciseKind, m: ExerciseMetrics) -> dict[tuple[str, int, Quantity], list[float]]:
    """Per (axis, sign, quantity): the values a session gives (one per trial, or one)."""
    out: dict[tuple[str, int, Quantity], list[float]] = {}

    def add(axis: str, sign: int, q: Quantity, v: float | None) -> None:
        if v is not None:
            out.setdefault((axis, sign, q), []).append(v)

    if kind == ExerciseKind.ROM_ASSESSMENT:
        for r in m.repetitions:
            for axis, a in r.axes.items():
                add(axis, 1, "peak_angle", a.positive.peak_angle_deg)
                add(axis, -1, "peak_angle", a.negative.peak_angle_deg)
    elif kind in ANGLE_KINDS:
        for axis, a in m.axes.items():
            add(axis, 1, "peak_angle", a.positive.peak_angle_deg)
            add(axis, -1, "peak_angle", a.negative.peak_angle_deg)
    elif kind == ExerciseKind.STRENGTH:
        for axis, a in m.axes.items():
            add(axis, 1, "peak_torque", a.positive.peak_torque_nm)
            add(axis, -1, "peak_torque", a.negative.peak_torque_nm)
    elif kind == ExerciseKind.ISOMETRIC:
        for r in m.repetitions:
            for axis, h in r.holds.items():
                add(axis, h.sign, "torque_held", h.torque_nm)
    elif kind == ExerciseKind.BALANCE and m.sway is not None:
        for axis, sway in m.sway.axes.items():
            add(axis, 0, "sway_rms", sway.rms_deg)
    return out


def _assessments(
    sessions: Sequence[SessionFacts], rx: dict[int, PrescriptionFacts]
) -> list[tuple[SessionFacts, dict[tuple[str, int, Quantity], list[float]]]]:
    out = []
    for s in sessions:
        m = s.summary.metrics if s.summary is not None else None
        if m is not None and _kind(s, rx) == ExerciseKind.ROM_ASSESSMENT:
            values = _values(ExerciseKind.ROM_ASSESSMENT, m)
            if values:
                out.append((s, values))
    return out


def minimal_detectable_change(trials_per_session: Sequence[Sequence[float]]) -> Mdc:
    """MDC95 of one direction from the trials of each assessment (see the module's text);
    ``axis`` and ``sign`` are left empty for the caller to fill."""
    repeated = [list(t) for t in trials_per_session if len(t) >= 2]
    n = sum(len(t) for t in repeated)
    df = n - len(repeated)

    def unmeasured(reason: MdcMissing, text: str) -> Mdc:
        return Mdc(
            axis="",
            sign=0,
            mdc95_deg=None,
            sem_deg=None,
            reason=reason,
            trials=n,
            assessments=len(repeated),
            text=text,
        )

    if n < MDC_MIN_TRIALS or len(repeated) < MDC_MIN_ASSESSMENTS:
        return unmeasured(
            "too_few_trials",
            f"not enough repeated trials yet ({n} trials in {len(repeated)} assessments; "
            f"at least {MDC_MIN_TRIALS} in {MDC_MIN_ASSESSMENTS} are needed)",
        )
    if all(x == t[0] for t in repeated for x in t):
        return unmeasured(
            "no_scatter",
            f"not measurable: never moved this way in {n} trials"
            if all(x == 0 for t in repeated for x in t)
            else f"not measurable: each assessment's trials measured the same ({n} trials)",
        )
    ss = sum(sum((x - sum(t) / len(t)) ** 2 for x in t) for t in repeated)
    sem = math.sqrt(ss / df)
    mdc = Z95_SQRT2 * sem
    return Mdc(
        axis="",
        sign=0,
        mdc95_deg=mdc,
        sem_deg=sem,
        trials=n,
        assessments=len(repeated),
        text=f"MDC95 {mdc:.1f} deg, from {n} trials in {len(repeated)} assessments",
    )


def _week_count(p: PrescriptionFacts, start: datetime, end: datetime) -> int:
    """Sessions asked for in the week [start, end): pro rata if the prescription ended in it."""
    if p.ended_at is None or p.ended_at >= end:
        return p.sessions_per_week
    return round(p.sessions_per_week * (p.ended_at - start) / WEEK)


def adherence(
    p: PrescriptionFacts,
    sessions: Sequence[SessionFacts],
    now: datetime,
    since: datetime | None = None,
    until: datetime | None = None,
) -> PrescriptionAdherence:
    """One prescription's adherence per prescribed week (see the module's text); ``sessions``
    may hold any of the patient's, those of other prescriptions are ignored."""
    stop = min(p.ended_at or now, now)
    mine = sorted((s for s in sessions if s.prescription_id == p.id), key=lambda s: s.started_at)
    weeks: list[AdherenceWeek] = []
    start, k = p.created_at, 1
    while start < stop:
        end = start + WEEK
        in_range = (since is None or end > since) and (until is None or start < until)
        if in_range:
            here = [s for s in mine if start <= s.started_at < end]
            asked = _week_count(p, start, end)
            done = sum(1 for s in here if s.end_reason == "completed")
            early = len(here) - done
            counted = min(done, asked)
            in_progress = end > now and (p.ended_at is None or p.ended_at > now)
            weeks.append(
                AdherenceWeek(
                    week=k,
                    start=start,
                    end=end,
                    prescribed=asked,
                    completed=counted,
                    extra=done - counted,
                    ended_early=early,
                    missed=0 if in_progress else max(0, asked - counted - early),
                    in_progress=in_progress,
                )
            )
        start, k = end, k + 1
    over = [w for w in weeks if not w.in_progress]
    prescribed = sum(w.prescribed for w in over)
    completed = sum(w.completed for w in over)
    return PrescriptionAdherence(
        prescription_id=p.id,
        exercise=p.exercise,
        title=p.title,
        sessions_per_week=p.sessions_per_week,
        weeks=weeks,
        prescribed=prescribed,
        completed=completed,
        extra=sum(w.extra for w in over),
        ended_early=sum(w.ended_early for w in over),
        missed=sum(w.missed for w in over),
        percent=100.0 * completed / prescribed if prescribed else None,
    )


def missed_weeks(
    p: PrescriptionFacts, sessions: Sequence[SessionFacts], now: datetime, since: datetime
) -> list[AdherenceWeek]:
    """The prescribed weeks of ``p`` that ended between ``since`` and ``now`` with sessions
    missed, oldest first. They are :func:`adherence`'s weeks and counts, the one definition
    of a missed session: the week in progress misses nothing yet."""
    return [w for w in adherence(p, sessions, now, since).weeks if not w.in_progress and w.missed]


def progress(
    prescriptions: Sequence[PrescriptionFacts],
    sessions: Sequence[SessionFacts],
    *,
    now: datetime,
    since: datetime | None = None,
    until: datetime | None = None,
    kind: ExerciseKind | None = None,
) -> Progress:
    """A patient's progress between ``since`` (inclusive) and ``until`` (exclusive).

    ``prescriptions`` and ``sessions`` are all of the patient's (any order): the baseline
    and MDC95 use every ROM assessment before ``until``, even those before ``since``. ``kind``
    keeps one exercise kind (its measures and its prescriptions' adherence). ``now`` (aware)
    ends the weeks of active prescriptions. Sessions without a summary are left out of the
    measures but count for adherence."""
    rx = {p.id: p for p in prescriptions}
    ordered = sorted(sessions, key=lambda s: s.started_at)
    upto = [s for s in ordered if until is None or s.started_at < until]
    shown = [s for s in upto if since is None or s.started_at >= since]

    assessments = _assessments(upto, rx)
    baseline: Baseline | None = None
    if assessments:
        first, values = assessments[0]
        baseline = Baseline(
            session_id=first.id,
            at=first.started_at,
            values={_key(a, sg): sum(v) / len(v) for (a, sg, _), v in values.items()},
        )
    trials: dict[tuple[str, int], list[list[float]]] = {}
    for _, values in assessments:
        for (axis, sign, _), v in values.items():
            trials.setdefault((axis, sign), []).append(v)
    mdc = {
        d: minimal_detectable_change(t).model_copy(update={"axis": d[0], "sign": d[1]})
        for d, t in sorted(trials.items())
    }

    by_kind: dict[ExerciseKind, list[SessionFacts]] = {}
    for s in shown:
        k = _kind(s, rx)
        if k is not None and (kind is None or k == kind):
            by_kind.setdefault(k, []).append(s)
    exercises = [_exercise(k, by_kind[k], baseline, mdc) for k in ExerciseKind if k in by_kind]
    return Progress(
        since=since,
        until=until,
        exercises=exercises,
        baseline=baseline,
        mdc=list(mdc.values()),
        adherence=[
            adherence(p, sessions, now, since, until)
            for p in sorted(prescriptions, key=lambda p: (p.created_at, p.id))
            if (kind is None or p.exercise == kind)
            and (until is None or p.created_at < until)
            and (since is None or p.ended_at is None or p.ended_at > since)
        ],
    )


def _exercise(
    kind: ExerciseKind,
    sessions: list[SessionFacts],
    baseline: Baseline | None,
    mdc: dict[tuple[str, int], Mdc],
) -> ExerciseProgress:
    series: dict[tuple[str, int, Quantity], list[Point]] = {}
    for s in sessions:
        m = s.summary.metrics if s.summary is not None else None
        if m is None:
            continue
        for (axis, sign, q), v in _values(kind, m).items():
            value = sum(v) / len(v)
            change = real = None
            if kind == ExerciseKind.ROM_ASSESSMENT and baseline is not None:
                base = baseline.values.get(_key(axis, sign))
                if base is not None:
                    change = value - base
                    limit = mdc[(axis, sign)].mdc95_deg if (axis, sign) in mdc else None
                    real = abs(change) > limit if limit is not None else None
            series.setdefault((axis, sign, q), []).append(
                Point(
                    session_id=s.id,
                    at=s.started_at,
                    value=value,
                    trials=len(v),
                    change=change,
                    real_change=real,
                )
            )
    measures = [
        Measure(
            axis=axis,
            sign=sign,
            quantity=q,
            unit=UNITS[q],
            points=points,
            baseline=baseline.values.get(_key(axis, sign))
            if baseline is not None and kind == ExerciseKind.ROM_ASSESSMENT
            else None,
        )
        for (axis, sign, q), points in sorted(
            series.items(), key=lambda kv: (AXIS_INDEX.get(kv[0][0], 9), -kv[0][1])
        )
    ]
    return ExerciseProgress(exercise=kind, sessions=len(sessions), measures=measures)
