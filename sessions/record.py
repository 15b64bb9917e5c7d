"""What the medical-record exports are made of: the patient, the period, their prescriptions
and their sessions, as plain values the server reads from its store.

The PDF report (``server/report.py``) and the FHIR bundle (:mod:`sessions.fhir`) are both
made from one :class:`PatientRecord`, so they never disagree about what happened.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import date, datetime, timedelta
from typing import Any
from zoneinfo import ZoneInfo

from sessions.measures import Measure, measures
from sessions.progress import Progress

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
class PatientRecord:
    """One patient over one period: what both exports are made from."""

    patient: Patient
    since: datetime
    """The period's start, included."""
    until: datetime
    """The period's end, excluded (midnight after its last day)."""
    zone: ZoneInfo
    """Whose days the period's are (``since`` and ``until`` are its midnights), and whose
    clock the report prints times on."""
    generated_at: datetime
    prescriptions: list[Prescription]
    sessions: list[Session]
    """Oldest first."""
    progress: Progress
    """Adherence per prescribed week, the baseline and the MDC95 (:mod:`sessions.progress`,
    the same computation the patient's page shows)."""

    @property
    def days(self) -> tuple[date, date]:
        """The period's first and last day, in :attr:`zone`."""
        last = self.until.astimezone(self.zone) - timedelta(microseconds=1)
        return self.since.astimezone(self.zone).date(), last.date()

    def measures(self, session: Session) -> list[Measure]:
        """The measures of one of the sessions, for this patient's side; none without a
        summary."""
        if session.summary is None:
            return []
        return measures(session.summary, self.patient.affected_side)


def ended_early(session: Session) -> bool:
    return session.end_reason in EARLY_END_REASONS


DATA_MISSING_MIN_S = 1.0
"""Seconds of telemetry missing from a session worth a therapist's look: less is a few
frames lost on the wire, counted in the summary but no reason to doubt its numbers."""


def data_missing(summary: dict[str, Any]) -> str:
    """The gaps in a session's telemetry in words ("Telemetry missing for 40 s (1 gap): …"),
    or "" when they leave out less than :data:`DATA_MISSING_MIN_S` (or its summary was
    stored before they were counted)."""
    gaps, missing = summary.get("telemetry_gaps"), summary.get("telemetry_missing_s")
    if not isinstance(gaps, int) or not isinstance(missing, int | float) or gaps <= 0:
        return ""
    seconds = float(missing)
    if not seconds >= DATA_MISSING_MIN_S:
        return ""
    return (
        f"Telemetry missing for {seconds:.0f} s ({gaps} gap{'s' if gaps != 1 else ''}): "
        "the session's numbers leave that time out"
    )
