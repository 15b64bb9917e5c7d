"""What the medical-record exports are made of: the patient, the period, their prescriptions
and their sessions, as plain values the server reads from its store.

The PDF report (``server/report.py``) and the FHIR bundle (:mod:`sessions.fhir`) are both
made from one :class:`PatientRecord`, so they never disagree about what happened.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import date, datetime, timedelta
from typing import Any

from sessions.measures import Measure, measures

EARLY_END_REASONS = ("stopped", "fault", "interrupted")
"""How a session ended before its prescription did (``completed`` is the only other)."""


@dataclass(frozen=True)
class Patient:
    id: int
    display_name: str
    reference: str | None
    birth_year: int | None
    affected_side: str | None
    """left, right, both, or None (not recorded)."""


@dataclass(frozen=True)
class Prescription:
    id: int
    title: str
    exercise: str
    status: str
    created_at: datetime
    sessions_per_week: int | None


@dataclass(frozen=True)
class Session:
    id: int
    uuid: str
    started_at: datetime
    ended_at: datetime | None
    end_reason: str | None
    prescription_id: int | None
    exercise: str | None
    """The exercise kind the session ran (from its prescription)."""
    summary: dict[str, Any] | None


@dataclass(frozen=True)
class Adherence:
    """Sessions done against sessions prescribed, for one prescription over the period."""

    prescription_id: int
    title: str
    done: int
    prescribed: int | None
    """None when the prescription does not say how often."""
    ended_early: int


@dataclass(frozen=True)
class PatientRecord:
    """One patient over one period: what both exports are made from."""

    patient: Patient
    since: datetime
    """The period's start, included."""
    until: datetime
    """The period's end, excluded (midnight after its last day)."""
    generated_at: datetime
    prescriptions: list[Prescription]
    sessions: list[Session]
    """Oldest first."""
    adherence: list[Adherence]

    @property
    def days(self) -> tuple[date, date]:
        """The period's first and last day."""
        return self.since.date(), (self.until - timedelta(microseconds=1)).date()

    def measures(self, session: Session) -> list[Measure]:
        """The measures of one of the sessions, for this patient's side; none without a
        summary."""
        if session.summary is None:
            return []
        return measures(session.summary, self.patient.affected_side)


def ended_early(session: Session) -> bool:
    return session.end_reason in EARLY_END_REASONS


def adherence(
    prescriptions: list[Prescription],
    ends: dict[int, datetime | None],
    sessions: list[Session],
    since: datetime,
    until: datetime,
) -> list[Adherence]:
    """Per prescription: sessions done in the period against those its weekly frequency
    asked for while it was in force within the period (from its creation to ``ends[id]``,
    None while active).

    A plain count; the progress module's weekly adherence can take its place without
    changing the report, which shows whatever :class:`Adherence` rows it is given."""
    rows: list[Adherence] = []
    for p in prescriptions:
        done = [s for s in sessions if s.prescription_id == p.id]
        start = max(since, p.created_at)
        end = min(until, ends.get(p.id) or until)
        days = max(0.0, (end - start).total_seconds() / 86400)
        prescribed = (
            round(p.sessions_per_week * days / 7) if p.sessions_per_week is not None else None
        )
        rows.append(
            Adherence(
                prescription_id=p.id,
                title=p.title,
                done=len(done),
                prescribed=prescribed,
                ended_early=sum(ended_early(s) for s in done),
            )
        )
    return rows
