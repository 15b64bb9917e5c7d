"""What the clinical computations of ``sessions`` read of the stored rows: a prescription's
and a session's facts (``sessions.progress``). Used by the progress route, the report for
the medical record and the needs-attention list alike, so all three read a row the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from server.models import Prescription, Session
from sessions.prescription import PrescriptionBody
from sessions.progress import PrescriptionFacts, SessionFacts
from sessions.summary import Summary


def prescription_facts(row: Prescription) -> PrescriptionFacts:
    """The stored body read as the API shows it (``PrescriptionBody``, its defaults
    included)."""
    body = PrescriptionBody.model_validate(row.body)
    return PrescriptionFacts(
        id=row.id,
        exercise=body.exercise,
        title=body.title,
        sessions_per_week=body.sessions_per_week,
        created_at=row.created_at,
        # A withdrawn or finished prescription asked for sessions up to its change of status.
        ended_at=None if row.status == "active" else row.updated_at,
    )


@dataclass
class SessionRow:
    """A stored session as progress and the report read it, its summary parsed as the ORM
    would (``server.routes.progress.session_rows``)."""

    id: int
    session_uuid: str
    prescription_id: int | None
    started_at: datetime
    ended_at: datetime | None
    end_reason: str | None
    summary: dict[str, Any] | None


def session_facts(row: Session | SessionRow) -> SessionFacts:
    return SessionFacts(
        id=row.id,
        prescription_id=row.prescription_id,
        started_at=row.started_at,
        end_reason=row.end_reason,
        summary=Summary.model_validate(row.summary) if row.summary is not None else None,
    )
