"""Progress over sessions against histories whose answers are worked out by hand."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import pytest

from sessions.metrics import (
    AxisMetrics,
    DirectionMetrics,
    ExerciseMetrics,
    HoldMetrics,
    RepetitionMetrics,
    Sway,
    SwayAxis,
)
from sessions.prescription import ExerciseKind
from sessions.progress import (
    MDC_MIN_TRIALS,
    PrescriptionFacts,
    SessionFacts,
    minimal_detectable_change,
    missed_weeks,
    progress,
)
from sessions.summary import Summary

MONDAY = datetime(2026, 3, 2, 9, 0, tzinfo=UTC)
DAY = timedelta(days=1)


def direction(angle: float = 0.0, torque: float = 0.0) -> DirectionMetrics:
    return DirectionMetrics(
        peak_angle_deg=angle, peak_torque_nm=torque, mean_torque_nm=torque / 2, work_j=0.0
    )


def axis(up: float = 0.0, down: float = 0.0, t_up: float = 0.0, t_down: float = 0.0) -> AxisMetrics:
    return AxisMetrics(
        positive=direction(up, t_up), negative=direction(down, t_down), range_deg=up + down
    )


def rep(k: int, **axes: AxisMetrics) -> RepetitionMetrics:
    return RepetitionMetrics(set=1, rep=k, duration_s=10.0, axes=axes)


def summary(metrics: ExerciseMetrics) -> Summary:
    return Summary(
        duration_s=60.0,
        elapsed_s=70.0,
        samples=6000,
        sets_completed=1,
        repetitions_completed=len(metrics.repetitions),
        repetitions_prescribed=None,
        end_reason="completed",
        axes={},
        events={},
        faults=[],
        metrics=metrics,
    )


def assessment(sid: int, at: datetime, trials: list[tuple[float, float]]) -> SessionFacts:
    """A ROM assessment of pitch whose trials reached (plantarflexion, dorsiflexion)."""
    reps = [rep(k + 1, pitch=axis(up, down)) for k, (up, down) in enumerate(trials)]
    m = ExerciseMetrics(kind="rom_assessment", axes={"pitch": axis()}, repetitions=reps)
    return SessionFacts(
        id=sid, prescription_id=1, started_at=at, end_reason="completed", summary=summary(m)
    )


ASSESS = PrescriptionFacts(
    id=1, exercise=ExerciseKind.ROM_ASSESSMENT, sessions_per_week=1, created_at=MONDAY
)


def test_mdc95_from_the_scatter_of_repeated_trials() -> None:
    # Each assessment's trials differ by 2 degrees: deviations of ±1 about its mean,
    # 6 squared deviations of 1 over 3 degrees of freedom: SEM √2, MDC95 1.96·√2·√2.
    mdc = minimal_detectable_change([[20, 22], [21, 23], [19, 21]])
    assert mdc.trials == 6 and mdc.assessments == 3
    assert mdc.sem_deg == pytest.approx(math.sqrt(2))
    assert mdc.mdc95_deg == pytest.approx(1.96 * 2)
    assert "6 trials in 3 assessments" in mdc.text


def test_a_direction_never_moved_has_no_mdc_and_flags_nothing() -> None:
    """Every trial of dorsiflexion at 0°: a zero scatter is no measure of reliability, so
    there is no MDC95 (not "0.0°") and no change is judged against it."""
    never = minimal_detectable_change([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    assert (never.mdc95_deg, never.sem_deg, never.reason) == (None, None, "no_scatter")
    assert never.text == "not measurable: never moved this way in 6 trials"
    same = minimal_detectable_change([[5.0, 5.0], [7.0, 7.0, 7.0, 7.0]])
    assert same.mdc95_deg is None and same.reason == "no_scatter"
    assert same.text.startswith("not measurable: each assessment's trials measured the same")
    assert minimal_detectable_change([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]]).mdc95_deg is not None

    history = [
        assessment(1, MONDAY, [(20, 0), (22, 0)]),
        assessment(2, MONDAY + 7 * DAY, [(21, 0), (23, 0)]),
        assessment(3, MONDAY + 14 * DAY, [(25, 0), (27, 0)]),
        assessment(4, MONDAY + 21 * DAY, [(25, 3)]),  # one trial: not in the MDC
    ]
    p = progress([ASSESS], history, now=MONDAY + 30 * DAY)
    mdc = {m.sign: m for m in p.mdc}
    assert mdc[1].reason is None and mdc[1].mdc95_deg == pytest.approx(1.96 * 2)
    assert mdc[-1].mdc95_deg is None and mdc[-1].reason == "no_scatter"
    dorsi = next(m for m in p.exercises[0].measures if m.sign == -1)
    assert [pt.change for pt in dorsi.points] == [0.0, 0.0, 0.0, 3.0]
    assert [pt.real_change for pt in dorsi.points] == [None, None, None, None]


def test_too_few_trials_flag_nothing() -> None:
    history = [
        assessment(1, MONDAY, [(20, 10), (22, 10)]),
        assessment(2, MONDAY + 8 * DAY, [(35, 10), (35, 10)]),
    ]
    assert MDC_MIN_TRIALS > 4
    p = progress([ASSESS], history, now=MONDAY + 20 * DAY)
    up = next(m for m in p.mdc if (m.axis, m.sign) == ("pitch", 1))
    assert up.mdc95_deg is None and up.reason == "too_few_trials"
    assert up.text.startswith("not enough repeated trials yet")
    (rom,) = p.exercises
    plantar = next(m for m in rom.measures if m.sign == 1)
    assert [pt.change for pt in plantar.points] == [0.0, 14.0]
    assert [pt.real_change for pt in plantar.points] == [None, None]


def test_baseline_and_changes_beyond_mdc() -> None:
    history = [
        assessment(1, MONDAY, [(20, 10), (22, 12)]),  # baseline: 21 and 11
        assessment(2, MONDAY + 7 * DAY, [(21, 11), (23, 13)]),  # +2: within 3.92
        assessment(3, MONDAY + 14 * DAY, [(25, 10), (27, 12)]),  # +5: beyond
    ]
    p = progress([ASSESS], history, now=MONDAY + 20 * DAY)
    assert p.baseline is not None and p.baseline.session_id == 1
    assert p.baseline.values == {"pitch:1": 21.0, "pitch:-1": 11.0}
    up = next(m for m in p.mdc if (m.axis, m.sign) == ("pitch", 1))
    assert up.mdc95_deg == pytest.approx(1.96 * 2)
    (rom,) = p.exercises
    assert rom.exercise == "rom_assessment" and rom.sessions == 3
    assert [(m.axis, m.sign, m.quantity, m.unit) for m in rom.measures] == [
        ("pitch", 1, "peak_angle", "deg"),
        ("pitch", -1, "peak_angle", "deg"),
    ]
    plantar, dorsi = rom.measures
    assert plantar.baseline == 21.0
    assert [pt.value for pt in plantar.points] == [21.0, 22.0, 26.0]
    assert [pt.trials for pt in plantar.points] == [2, 2, 2]
    assert [pt.real_change for pt in plantar.points] == [False, False, True]
    assert [pt.real_change for pt in dorsi.points] == [False, False, False]

    # A later date range still measures against the first assessment.
    later = progress([ASSESS], history, now=MONDAY + 20 * DAY, since=MONDAY + 10 * DAY)
    assert later.baseline is not None and later.baseline.session_id == 1
    assert [pt.session_id for pt in later.exercises[0].measures[0].points] == [3]


def session(
    sid: int, rx: int, at: datetime, reason: str = "completed", m: ExerciseMetrics | None = None
) -> SessionFacts:
    return SessionFacts(
        id=sid,
        prescription_id=rx,
        started_at=at,
        end_reason=reason,
        summary=summary(m) if m is not None else None,
    )


def test_adherence_never_above_what_was_prescribed() -> None:
    rx = PrescriptionFacts(
        id=7, exercise=ExerciseKind.STRENGTH, sessions_per_week=5, created_at=MONDAY
    )
    week1 = [session(i, 7, MONDAY + i * timedelta(hours=6)) for i in range(15)]
    week2 = [
        session(20, 7, MONDAY + 8 * DAY),
        session(21, 7, MONDAY + 9 * DAY),
        session(22, 7, MONDAY + 10 * DAY, reason="stopped"),
    ]
    week3 = [session(30, 7, MONDAY + 15 * DAY)]
    other = [session(40, 8, MONDAY + DAY)]  # another prescription's
    p = progress([rx], week1 + week2 + week3 + other, now=MONDAY + 16 * DAY)
    (a,) = p.adherence
    assert [
        (w.week, w.prescribed, w.completed, w.extra, w.ended_early, w.missed) for w in a.weeks
    ] == [
        (1, 5, 5, 10, 0, 0),
        (2, 5, 2, 0, 1, 2),
        (3, 5, 1, 0, 0, 0),
    ]
    assert [w.in_progress for w in a.weeks] == [False, False, True]
    assert (a.prescribed, a.completed, a.extra, a.ended_early, a.missed) == (10, 7, 10, 1, 2)
    assert a.percent == pytest.approx(70.0)


def test_each_prescription_is_measured_against_itself() -> None:
    """Six prescriptions: not "0 of 30" but each its own weeks and sessions."""
    rxs = [
        PrescriptionFacts(
            id=i,
            exercise=ExerciseKind.STRENGTH,
            sessions_per_week=5,
            created_at=MONDAY + i * DAY,
            ended_at=MONDAY + (i + 7) * DAY if i < 5 else None,
        )
        for i in range(6)
    ]
    history = [session(100 + i, i, MONDAY + (i + 1) * DAY) for i in range(6)]
    p = progress(rxs, history, now=MONDAY + 30 * DAY)
    assert [a.prescription_id for a in p.adherence] == list(range(6))
    for a in p.adherence[:5]:
        assert [(w.prescribed, w.completed, w.missed) for w in a.weeks] == [(5, 1, 4)]
    assert p.adherence[5].weeks[0].completed == 1
    assert len(p.adherence[5].weeks) == 4  # still active: 24 days, 4 weeks begun


def test_missed_weeks_are_the_adherence_weeks_over_with_sessions_missed() -> None:
    rx = PrescriptionFacts(
        id=7, exercise=ExerciseKind.STRENGTH, sessions_per_week=3, created_at=MONDAY
    )
    history = [
        session(1, 7, MONDAY + DAY),  # week 1: 1 of 3, 2 missed
        *(session(10 + i, 7, MONDAY + 7 * DAY + i * DAY) for i in range(3)),  # week 2: all
        session(20, 7, MONDAY + 14 * DAY, reason="stopped"),  # week 3: 1 ended early, 2 missed
    ]
    now = MONDAY + 22 * DAY  # week 4 in progress, nothing done: nothing missed yet
    weeks = missed_weeks(rx, history, now, since=MONDAY)
    assert [(w.week, w.completed, w.ended_early, w.missed) for w in weeks] == [
        (1, 1, 0, 2),
        (3, 0, 1, 2),
    ]
    assert [w.week for w in missed_weeks(rx, history, now, since=now - 7 * DAY)] == [3]
    assert missed_weeks(rx, history, MONDAY + 6 * DAY, since=MONDAY) == []


def test_a_prescription_ended_part_way_asks_pro_rata() -> None:
    rx = PrescriptionFacts(
        id=1,
        exercise=ExerciseKind.STRENGTH,
        sessions_per_week=4,
        created_at=MONDAY,
        ended_at=MONDAY + 7 * DAY + 3.5 * DAY,
    )
    a = progress([rx], [], now=MONDAY + 30 * DAY).adherence[0]
    assert [w.prescribed for w in a.weeks] == [4, 2]
    assert a.missed == 6


def test_measures_fit_each_exercise() -> None:
    strength = ExerciseMetrics(
        kind="strength", axes={"pitch": axis(10, 5, t_up=30.0, t_down=12.0)}, repetitions=[]
    )
    hold = RepetitionMetrics(
        set=1,
        rep=1,
        duration_s=5,
        axes={"pitch": axis()},
        holds={"pitch": HoldMetrics(sign=-1, torque_nm=18.0, held_s=3.0, peak_torque_nm=20.0)},
    )
    isometric = ExerciseMetrics(kind="isometric", axes={}, repetitions=[hold, hold])
    balance = ExerciseMetrics(
        kind="balance",
        axes={},
        repetitions=[],
        sway=Sway(
            axes={"roll": SwayAxis(rms_deg=1.5, range_deg=4.0)}, path_deg=30.0, mean_speed_deg_s=1.0
        ),
    )
    history = [
        session(1, 0, MONDAY, m=strength),
        session(2, 0, MONDAY + DAY, m=isometric),
        session(3, 0, MONDAY + 2 * DAY, m=balance),
        session(4, 0, MONDAY + 3 * DAY),  # no summary: nothing to measure
    ]
    p = progress([], history, now=MONDAY + 4 * DAY)
    got = {
        e.exercise: [
            (m.axis, m.sign, m.quantity, [pt.value for pt in m.points]) for m in e.measures
        ]
        for e in p.exercises
    }
    assert got == {
        "strength": [("pitch", 1, "peak_torque", [30.0]), ("pitch", -1, "peak_torque", [12.0])],
        "isometric": [("pitch", -1, "torque_held", [18.0])],
        "balance": [("roll", 0, "sway_rms", [1.5])],
    }
    only = progress([], history, now=MONDAY + 4 * DAY, kind=ExerciseKind.BALANCE)
    assert [e.exercise for e in only.exercises] == ["balance"]
    assert p.baseline is None and p.mdc == []
