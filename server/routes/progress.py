"""A patient's progress: per exercise type, per direction, against the baseline and the
minimal detectable change, and adherence per prescription (``sessions.progress``).

:func:`load_progress` gathers the patient's prescriptions and sessions and calls
``sessions.progress.progress``; the route and the report for the medical record both use it.
"""

from __future__ import annotations

import asyncio
import json
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query, Request
from pydantic import Field
from sqlalchemy import ColumnElement, Text, cast, select

from server.deps import Db, Id, TherapistOrAdmin, patient_for
from server.facts import SessionRow, prescription_facts, session_facts
from server.models import Patient, Prescription, Session, utcnow
from server.routes.common import NOT_FOUND, UNAUTHORIZED
from server.routes.dates import Tz, day_or_time, refuse, shown, zone
from server.routes.sessions import with_metrics
from sessions.anatomy import direction_table
from sessions.prescription import ExerciseKind
from sessions.progress import Progress, progress

router = APIRouter(prefix="/patients", tags=["patients"])


class ProgressPublic(Progress):
    """``sessions.progress.Progress`` with what a page needs to show it for this patient."""

    patient_id: int
    affected_side: str | None
    weight_kg: float | None = Field(description="For torque per kilogram; null if unknown.")
    directions: dict[str, dict[str, str]] = Field(
        description="Each axis's direction names and labels for the patient's side "
        "(sessions.anatomy.direction_table): sign 1 is 'positive', -1 'negative'."
    )


async def session_rows(
    request: Request, db: Db, where: list[ColumnElement[bool]], *, ordered: bool = False
) -> list[SessionRow]:
    """The sessions ``where`` selects (by start, then id, if ``ordered``), their summaries
    read as JSON text and parsed in a thread: parsed by the ORM on the event loop, a year of
    sessions (1,000 summaries of 14 kB) held it 0.4-0.6 s, and nothing else was answered.
    PostgreSQL's driver parses a json column as it arrives, so it is sent as text.
    Those stored before the metrics existed get them first (``with_metrics``)."""
    query = select(
        Session.id,
        Session.session_uuid,
        Session.prescription_id,
        Session.started_at,
        Session.ended_at,
        Session.end_reason,
        cast(Session.summary, Text),  # text on either store: parsed below, in the thread
    ).where(*where)
    if ordered:
        query = query.order_by(Session.started_at, Session.id)
    found = (await db.execute(query)).all()

    def parse() -> list[SessionRow]:
        return [
            SessionRow(
                id=r[0],
                session_uuid=r[1],
                prescription_id=r[2],
                started_at=r[3],
                ended_at=r[4],
                end_reason=r[5],
                summary=None if r[6] is None else json.loads(r[6]),
            )
            for r in found
        ]

    rows = await asyncio.to_thread(parse)
    stale = [r.id for r in rows if r.summary is not None and r.summary.get("metrics") is None]
    if stale:
        fixed = await with_metrics(
            request, db, list(await db.scalars(select(Session).where(Session.id.in_(stale))))
        )
        summaries = {row.id: row.summary for row in fixed}
        for r in rows:
            r.summary = summaries.get(r.id, r.summary)
    return rows


def parse_kind(text: str | None) -> ExerciseKind | None:
    if text is None or text == "":
        return None
    try:
        return ExerciseKind(text)
    except ValueError:
        kinds = ", ".join(k.value for k in ExerciseKind)
        raise refuse(
            "kind", f"kind '{shown(text)}' is not an exercise type: one of {kinds}"
        ) from None


async def load_progress(
    request: Request,
    db: Db,
    patient: Patient,
    *,
    since: datetime | None = None,
    until: datetime | None = None,
    kind: ExerciseKind | None = None,
) -> ProgressPublic:
    """The patient's progress in [since, until); the patient must already be one the caller
    may read (``server.deps.patient_for``). Sessions stored before the metrics existed get
    them from their recording first (``server.routes.sessions.with_metrics``)."""
    prescriptions = (
        await db.scalars(select(Prescription).where(Prescription.patient_id == patient.id))
    ).all()
    where = [Session.patient_id == patient.id]
    if until is not None:
        where.append(Session.started_at < until)
    rows = await session_rows(request, db, where)
    side, weight = patient.affected_side, patient.weight_kg

    def compute() -> ProgressPublic:
        result = progress(
            [prescription_facts(p) for p in prescriptions],
            [session_facts(s) for s in rows],
            now=utcnow(),
            since=since,
            until=until,
            kind=kind,
        )
        return ProgressPublic(
            **result.model_dump(),
            patient_id=patient.id,
            affected_side=side,
            weight_kg=weight,
            directions=direction_table(side),
        )

    # In a thread: reading a thousand stored summaries and the progress made of them took
    # 0.7-1.6 s of pure Python, and on the event loop nothing else was answered meanwhile.
    # The loaded rows are only read there (expire_on_commit is off: nothing loads lazily).
    return await asyncio.to_thread(compute)


@router.get(
    "/{patient_id}/progress",
    response_model=ProgressPublic,
    summary="A patient's progress and adherence",
    responses={
        **UNAUTHORIZED,
        **NOT_FOUND,
        422: {
            "description": "A date, kind or time zone not understood, or a date outside 1900..9998."
        },
    },
)
async def get_progress(
    patient_id: Id,
    request: Request,
    db: Db,
    user: TherapistOrAdmin,
    since: Annotated[
        str | None,
        Query(
            description="From this day (YYYY-MM-DD, of tz) or time (ISO 8601; tz's clock if "
            "it names no offset)."
        ),
    ] = None,
    until: Annotated[
        str | None,
        Query(
            description="Up to and including this day (YYYY-MM-DD, of tz), or before this "
            "time; days from 1900-01-01 to 9998-12-31."
        ),
    ] = None,
    kind: Annotated[
        str | None, Query(description="One exercise type (strength, rom_assessment, …).")
    ] = None,
    tz: Tz = None,
) -> ProgressPublic:
    """Per exercise type, a series per direction; the baseline (the first ROM assessment);
    MDC95 from the device's own repeated trials, with a change flagged real only beyond it;
    adherence per prescription per prescribed week, never above what was prescribed. See
    ``sessions.progress`` for how each number is made."""
    where = zone(tz)
    start = day_or_time("since", since, tz=where)
    end = day_or_time("until", until, end_of_day=True, tz=where)
    exercise = parse_kind(kind)
    if start is not None and end is not None and start >= end:
        raise refuse("since", f"since ({since}) must be before until ({until})")
    patient = await patient_for(db, user, patient_id)
    return await load_progress(request, db, patient, since=start, until=end, kind=exercise)
